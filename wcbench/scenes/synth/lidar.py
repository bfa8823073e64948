"""The synthetic scenes' lidar: a spinning roof sensor's rays (:class:`~.layout.LidarSpec`) cast
against the ground, the boxes and the tree canopies, written as drivestudio's Waymo sweep columns
(docs/design.md §3)."""

from __future__ import annotations

import math

import numpy as np

from wcbench.scenes.synth.content import Boxes, Content, boxes_at
from wcbench.scenes.synth.geometry import Street
from wcbench.scenes.synth.layout import CURB_M, ROAD_HALF_M
from wcbench.scenes.synth.raycast import box_entry, sphere_entry

__all__ = ["lidar_sweep"]


def _ray_window(center: np.ndarray, radius: float, elevation: np.ndarray, azimuth: np.ndarray, range_m: float
                ) -> tuple[slice, slice] | None:
    """The rectangle of a sweep's (elevation, azimuth) ray grid that can meet a sphere.

    ``center`` [3] is the sphere's centre relative to the sensor in the vehicle frame (m); the grid
    axes ``elevation`` [B] and ``azimuth`` [C] (rad) are increasing; ``range_m`` is the sensor's
    reach (m). ``None`` when no ray can reach it.
    """
    dist = float(np.linalg.norm(center))
    if dist - radius > range_m:
        return None
    if dist <= radius * 1.05:  # around the sensor: every ray
        return slice(0, len(elevation)), slice(0, len(azimuth))
    alpha = math.asin(radius / dist) * 1.05
    el = math.asin(center[2] / dist)
    lo, hi = el - alpha, el + alpha
    widest = max(abs(lo), abs(hi))
    if widest >= math.pi / 2 - 1e-6:
        az_lo, az_hi = -math.pi, math.pi
    else:
        az = math.atan2(center[1], center[0])
        half = min(math.asin(min(math.sin(alpha) / math.cos(widest), 1.0)) * 1.05, math.pi)
        az_lo, az_hi = az - half, az + half
    rows = slice(int(np.searchsorted(elevation, lo)), int(np.searchsorted(elevation, hi, side="right")))
    cols = slice(int(np.searchsorted(azimuth, az_lo)), int(np.searchsorted(azimuth, az_hi, side="right")))
    if rows.start >= rows.stop or cols.start >= cols.stop:
        return None
    return rows, cols


def _cast(origin: np.ndarray, ego_R: np.ndarray, elevation: np.ndarray, azimuth: np.ndarray, boxes: Boxes,
          spheres: np.ndarray, street: Street, range_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First hits of a sweep's rays (street coordinates).

    Parameters
    ----------
    origin : ndarray [3]
        Sensor position (m).
    ego_R : ndarray [3, 3]
        Vehicle-to-world rotation.
    elevation, azimuth : ndarray [B], [C]
        The ray grid in the vehicle frame (rad, increasing).
    boxes : Boxes
    spheres : ndarray [K, 4]
        Canopy spheres (centre, radius; m).
    street : Street
    range_m : float
        The sensor's reach (m): shapes beyond it are not tested.

    Returns
    -------
    dirs_vehicle : ndarray [B, C, 3]
        Unit ray directions in the vehicle frame.
    distance : ndarray [B, C]
        To the first hit (m); inf without one.
    what : ndarray [B, C] int
        -2 road, -3 sidewalk, -4 canopy, the index of a box, or -1 (no hit).
    """
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    dirs_v = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    dirs = dirs_v @ ego_R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        # the ground: the sidewalk top (CURB_M high) outside the road, else the road (z = 0)
        dz = dirs[..., 2]
        down = dz < -1e-9
        t_walk = np.where(down, (CURB_M - origin[2]) / dz, np.inf)
        p = origin + np.where(np.isfinite(t_walk), t_walk, 0.0)[..., None] * dirs
        on_walk = down & (np.abs(street.coords(p[..., 0], p[..., 1])[1]) >= ROAD_HALF_M)
        best = np.where(on_walk, t_walk, np.where(down, -origin[2] / dz, np.inf))
        what = np.where(np.isfinite(best), np.where(on_walk, -3, -2), -1)
        for m in range(len(boxes.center)):
            window = _ray_window(ego_R.T @ (boxes.center[m] - origin), float(np.linalg.norm(boxes.half[m])),
                                 elevation, azimuth, range_m)
            if window is None:
                continue
            R = boxes.R[m]
            # the sensor and the rays in the box frame
            t = box_entry(R.T @ (origin - boxes.center[m]), dirs[window] @ R, boxes.half[m])
            better = t < best[window]
            best[window] = np.where(better, t, best[window])
            what[window] = np.where(better, m, what[window])
        for c in spheres:
            window = _ray_window(ego_R.T @ (c[:3] - origin), float(c[3]), elevation, azimuth, range_m)
            if window is None:
                continue
            t = sphere_entry(c[:3] - origin, dirs[window], float(c[3]))
            better = t < best[window]
            best[window] = np.where(better, t, best[window])
            what[window] = np.where(better, -4, what[window])
    return dirs_v, best, what


def lidar_sweep(content: Content, k: int) -> np.ndarray:
    """The sweep of frame ``k`` by the scene's lidar (its profile's :class:`~.layout.LidarSpec`).

    Every moving object is seen, tracked or not, with its velocity in the flow columns as a real
    sensor's processing writes them; with ``range_noise_m`` each range gets seeded Gaussian noise.

    Parameters
    ----------
    content : Content
    k : int
        Frame.

    Returns
    -------
    ndarray [N, 14] float32
        In the vehicle frame of frame ``k`` (drivestudio Waymo columns: ray origin 3, point 3 (m),
        flow 3 (m/s), flow class, ground, intensity, elongation, laser id).
    """
    spec = content.spec.profile.lidar
    ego = content.ego[k]
    elevation, azimuth = spec.elevations(), spec.azimuths()
    origin_v = np.array(spec.mount_m)
    boxes = boxes_at(content, k)
    dirs_v, t, what = _cast(ego[:3, :3] @ origin_v + ego[:3, 3], ego[:3, :3], elevation, azimuth, boxes,
                            content.spheres, content.street, spec.range_m)
    hit = np.isfinite(t) & (t <= spec.range_m)
    t, what, dirs_v = t[hit], what[hit], dirs_v[hit]
    if spec.range_noise_m > 0:
        # a stream of its own per frame: the sweeps do not depend on which frames were generated
        t = t + spec.range_noise_m * np.random.default_rng([content.spec.seed, 7, k]).standard_normal(len(t))
    points_v = origin_v + t[:, None] * dirs_v
    box = np.maximum(what, 0)
    is_box = what >= 0
    mover = np.where(is_box, boxes.mover[box], -1)
    velocity = np.zeros((len(t), 3))
    for i in np.unique(mover[mover >= 0]):
        velocity[mover == i] = ego[:3, :3].T @ content.movers[int(i)].velocity[k]
    intensity = np.select([what == -2, what == -3, what == -4], [0.08, 0.15, 0.12],
                          np.where(is_box, boxes.intensity[box], 0.0))
    out = np.zeros((len(t), 14), np.float32)
    out[:, 0:3] = origin_v
    out[:, 3:6] = points_v
    out[:, 6:9] = velocity
    out[:, 9] = np.where(is_box, boxes.flow_class[box], 0)
    out[:, 10] = (what == -2) | (what == -3)
    out[:, 11] = intensity
    return out
