"""The synthetic scenes' lidar: a spinning roof sensor's rays cast against the ground, the boxes
and the tree canopies, written as drivestudio's Waymo sweep columns (docs/design.md §3)."""

from __future__ import annotations

import math

import numpy as np

from wcbench.scenes.synth.content import Boxes, Content, boxes_at
from wcbench.scenes.synth.geometry import Street
from wcbench.scenes.synth.layout import (
    CURB_M,
    LIDAR_AZIMUTH_DEG,
    LIDAR_BEAMS,
    LIDAR_COLUMNS,
    LIDAR_ELEVATION_DEG,
    LIDAR_MOUNT_M,
    LIDAR_RANGE_M,
    ROAD_HALF_M,
)

__all__ = ["lidar_sweep"]


def _ray_window(center: np.ndarray, radius: float, elevation: np.ndarray, azimuth: np.ndarray
                ) -> tuple[slice, slice] | None:
    """The rectangle of a sweep's (elevation, azimuth) ray grid that can meet a sphere.

    ``center`` [3] is the sphere's centre relative to the sensor in the vehicle frame (m); the grid
    axes ``elevation`` [B] and ``azimuth`` [C] (rad) are increasing. ``None`` when no ray can reach it.
    """
    dist = float(np.linalg.norm(center))
    if dist - radius > LIDAR_RANGE_M:
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
          spheres: np.ndarray, street: Street) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
                                 elevation, azimuth)
            if window is None:
                continue
            R, h = boxes.R[m], boxes.half[m]
            o = R.T @ (origin - boxes.center[m])  # the sensor in the box frame
            d = dirs[window] @ R
            t1, t2 = (-h - o) / d, (h - o) / d
            t_near = np.fmax(np.fmax(np.fmin(t1[..., 0], t2[..., 0]), np.fmin(t1[..., 1], t2[..., 1])),
                             np.fmin(t1[..., 2], t2[..., 2]))
            t_far = np.fmin(np.fmin(np.fmax(t1[..., 0], t2[..., 0]), np.fmax(t1[..., 1], t2[..., 1])),
                            np.fmax(t1[..., 2], t2[..., 2]))
            t = np.where((t_far >= t_near) & (t_near > 0), t_near, np.inf)
            better = t < best[window]
            best[window] = np.where(better, t, best[window])
            what[window] = np.where(better, m, what[window])
        for c in spheres:
            window = _ray_window(ego_R.T @ (c[:3] - origin), float(c[3]), elevation, azimuth)
            if window is None:
                continue
            oc = c[:3] - origin
            b = dirs[window] @ oc
            disc = b * b - (oc @ oc - c[3] ** 2)
            t = np.where(disc >= 0, b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
            t = np.where(t > 0, t, np.inf)
            better = t < best[window]
            best[window] = np.where(better, t, best[window])
            what[window] = np.where(better, -4, what[window])
    return dirs_v, best, what


def lidar_sweep(content: Content, k: int) -> np.ndarray:
    """The sweep of frame ``k``: float32 [N, 14] in the vehicle frame of frame k (drivestudio Waymo
    columns: ray origin 3, point 3, flow 3, flow class, ground, intensity, elongation, laser id)."""
    ego = content.ego[k]
    elevation = np.radians(np.linspace(*LIDAR_ELEVATION_DEG, LIDAR_BEAMS))
    azimuth = np.radians(np.linspace(-LIDAR_AZIMUTH_DEG, LIDAR_AZIMUTH_DEG, LIDAR_COLUMNS))
    origin_v = np.array(LIDAR_MOUNT_M)
    boxes = boxes_at(content, k)
    dirs_v, t, what = _cast(ego[:3, :3] @ origin_v + ego[:3, 3], ego[:3, :3], elevation, azimuth, boxes,
                            content.spheres, content.street)
    hit = np.isfinite(t) & (t <= LIDAR_RANGE_M)
    t, what, dirs_v = t[hit], what[hit], dirs_v[hit]
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
