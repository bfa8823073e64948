"""Procedural driving scenes with ground-truth weather: the ``synth_1`` and ``synth_3`` scene sets.

No public dataset shows the same street under true rain, snow and fog, so these scenes are built
from known content (docs/design.md §3): a street of 3D Gaussians (road with lane markings, raised
sidewalks, building facades with windows, trees, parked cars, moving cars and, in some scenes, a
walking pedestrian) seen by a camera driving at 8 m/s. Every frame, clear and each weather, is
rendered by the reference model's :class:`~wcbench.reference_model.weather.renderer.WeatherRenderer`
(docs/design.md §7). A weather first changes the materials (wet asphalt with a sky sheen and
puddles under rain, snow cover on upward-facing Gaussians, dimmer overcast light), then the rain
and snow particles and the fog come from the model's physics.

Each scene is written in drivestudio's Waymo layout, exactly as
:func:`wcbench.scenes.loaders.load_waymo_layout` reads it, with the truth beside it
(``truth/{weather}/{t:03d}_0.png`` and ``truth/weather.json``). Scenes are generated on first use
into the cache folder (``scenes/synth-v{VERSION}/synth_{k:03d}``), built in a temporary folder and
renamed into place; generation is seeded and byte-for-byte deterministic (PNG images, fixed text
formats).

Rendering needs the reference model (torch and numba, the ``[model]`` extra); a scene already in the
cache loads without it.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.image_io import to_uint8
from wcbench.core.paths import cache_dir
from wcbench.core.progress import announce
from wcbench.core.storage import dumps_json
from wcbench.reference_model.transforms import quat_from_matrices, quat_multiply, quat_to_matrix
from wcbench.scenes.loaders import OPENCV_TO_WAYMO
from wcbench.scenes.scene import Camera

__all__ = [
    "MATERIALS",
    "SCENES",
    "TRUTH_WEATHERS",
    "VERSION",
    "SynthSpec",
    "build_content",
    "ensure_synth_1",
    "ensure_synth_3",
    "ensure_synth_scenes",
    "gaussian_normals",
    "scene_folder",
    "write_synth_scene",
]

VERSION = 1  # bump when the generated content changes: the cache folder is keyed by it
WIDTH, HEIGHT, FOCAL = 480, 270, 300.0  # pixels; horizontal field of view 77 degrees
N_FRAMES, FPS, SPEED = 30, 10.0, 8.0  # frames, Hz, m/s
MARKER = "synth.json"  # written last: a scene folder holding it is complete
#: Where the street's origin sits in the "global" frame written to disk: far from 0, so the
#: loaders' re-basing (docs/design.md §2) is exercised as on real data.
GLOBAL_ORIGIN = np.array([1520.0, -830.0, 12.0])
#: Camera 0 (FRONT) on the vehicle: position (m, vehicle frame x forward, y left, z up; origin on the
#: ground under the rear axle as in Waymo) and a small downward pitch.
CAMERA_MOUNT_M = (1.5, 0.0, 1.65)
CAMERA_PITCH_DEG = 2.0
#: A spinning roof lidar: 32 beams over the front half (the camera sees 77 degrees of it).
LIDAR_MOUNT_M = (1.4, 0.0, 2.1)
LIDAR_BEAMS, LIDAR_COLUMNS = 32, 480
LIDAR_ELEVATION_DEG = (-24.0, 3.0)
LIDAR_AZIMUTH_DEG = 80.0  # +- about the vehicle's x axis
LIDAR_RANGE_M = 75.0  # Waymo's top lidar range
#: Street cross-section (m): two lanes, a parking lane each side, raised sidewalks, facades.
LANE_M, PARKING_M, SIDEWALK_M, CURB_M = 3.5, 2.2, 3.5, 0.15
ROAD_HALF_M = LANE_M + PARKING_M
BUILDING_LINE_M = ROAD_HALF_M + SIDEWALK_M
STREET_START_M, STREET_END_M = -2.0, 185.0  # arc length of the ground; a building closes the street
EGO_LATERAL_M = -LANE_M / 2  # right-hand traffic: the camera car drives in the right lane
SIGMA_OF_SPACING = 0.7  # in-plane standard deviation of a surface Gaussian / its grid spacing
THIN_M = 0.01  # thickness (smallest scale) of a surface Gaussian: its normal axis
OPACITY = 0.98
SURFACE_SPACING_PER_M = 0.012  # grid spacing (m) per metre of distance: ~3.6 px at f = 300 px
#: A street is seen at grazing angles: its ground (camera 1.65 m above it) and facades (~11 m to the
#: side) are foreshortened along the street, so their Gaussians are spaced that much wider along it.
GROUND_STRETCH, FACADE_STRETCH = 3.0, 2.0

#: The weathers rendered as truth: :class:`~wcbench.reference_model.weather.conditions.Weather`
#: fields (presets in reference_model/weather/presets.toml; the scene's seed is added). Heavy rain
#: (25 mm/h) and heavy snow (2.5 mm/h), fog of 150 m visibility. Heavy snow has ~29,000 flakes in
#: the particle box: drawn one by one (instead of the preset's 16,000 of higher opacity) it reads as
#: heavy at 480x270.
TRUTH_WEATHERS: dict[str, dict[str, Any]] = {
    "rain": {"preset": "heavy"},
    "snow": {"preset": "heavy", "max_particles": 30000},
    "fog": {"preset": "moderate"},
}

#: How each weather changes the materials before rendering (docs/design.md §3). ``light`` scales the
#: albedo (overcast days are dimmer than the clear sun); under rain a wet surface keeps ``wet`` of
#: its albedo (a water film darkens asphalt to about half) and adds a Fresnel reflection of the sky
#: (Schlick's approximation, ``fresnel_f0`` of water) weighted by the Gaussian's sheen; under snow a
#: Gaussian whose normal (its smallest-scale axis) points up is covered by snow of ``snow_albedo``.
MATERIALS: dict[str, dict[str, Any]] = {
    "clear": {"ambient": 0.55, "sun": 0.5, "sun_direction": [-0.35, -0.45, 0.82]},
    "rain": {"light": 0.68, "sky_light": 0.15, "fresnel_f0": 0.02, "asphalt_wet": 0.55, "puddle_wet": 0.3,
             "asphalt_sheen": 0.3, "puddle_sheen": 1.0, "overcast_sky": [0.60, 0.62, 0.66]},
    "snow": {"light": 0.82, "sky_light": 0.15, "snow_albedo": [0.93, 0.94, 0.97], "normal_up_from": 0.55,
             "normal_up_full": 0.9, "wet": 0.85, "overcast_sky": [0.80, 0.81, 0.85]},
    "fog": {"light": 0.78, "sky_light": 0.15, "wet": 0.95, "overcast_sky": [0.78, 0.78, 0.81]},
}


@dataclass(frozen=True)
class SynthSpec:
    """What one synthetic scene contains.

    Attributes
    ----------
    index : int
        Scene number k; the folder is ``synth_{k:03d}``.
    seed : int
        Seeds the layout (buildings, trees, parked cars, colours) and the weather particles.
    curvature : float
        Street curvature (1/m): 0 straight, positive bending left.
    pedestrian : {"right", "left"} or None
        Sidewalk a pedestrian walks on (``"right"``: along the driving direction, ``"left"``:
        towards the camera), or no pedestrian.
    movers : tuple of str
        Moving cars: ``"oncoming"`` (left lane, towards the camera) and/or ``"lead"`` (ahead in the
        camera's lane, slower).
    """

    index: int
    seed: int
    curvature: float
    pedestrian: str | None
    movers: tuple[str, ...]


#: The scenes of the synth sets: ``synth_1`` is scene 0, ``synth_3`` scenes 0-2.
SCENES: tuple[SynthSpec, ...] = (
    SynthSpec(index=0, seed=1000, curvature=0.0, pedestrian=None, movers=("oncoming",)),
    SynthSpec(index=1, seed=1001, curvature=1.0 / 300.0, pedestrian="right", movers=("oncoming", "lead")),
    SynthSpec(index=2, seed=1002, curvature=-1.0 / 400.0, pedestrian="left", movers=("lead", "oncoming")),
)


def scene_folder(index: int) -> str:
    """Folder name of synthetic scene ``index`` (``"synth_000"``), also its scene id."""
    return f"synth_{index:03d}"


# --------------------------------------------------------------------------------------------
# Geometry helpers


def _rot_z(angle: np.ndarray | float) -> np.ndarray:
    """[..., 3, 3] rotations about +z by ``angle`` (rad)."""
    a = np.asarray(angle, np.float64)
    c, s = np.cos(a), np.sin(a)
    out = np.zeros((*a.shape, 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1], out[..., 2, 2] = c, -s, s, c, 1.0
    return out


def _rot_y(angle: float) -> np.ndarray:
    """[3, 3] rotation about +y by ``angle`` (rad); positive turns +x towards -z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[4, 4] rigid transform from a rotation [3, 3] and a translation [3]."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def gaussian_normals(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Normals of flat Gaussians: the rotated axis of each Gaussian's smallest scale.

    Parameters
    ----------
    quats : ndarray [N, 4]
        Rotations (w, x, y, z).
    scales : ndarray [N, 3]
        Standard deviations along the local axes (m).

    Returns
    -------
    ndarray [N, 3] float64
        Unit normals in world axes. The sign is the rotated local axis' own: the surfaces of this
        module put that axis outwards.
    """
    R = quat_to_matrix(quats)
    axis = np.argmin(np.asarray(scales), axis=1)
    return R[np.arange(len(R)), :, axis]


@dataclass(frozen=True)
class _Street:
    """A street centreline of constant curvature through the origin along +x, z up.

    A point at arc length ``s`` and lateral offset ``d`` (m, positive to the left) sits at
    c(s) + d n(s), where n is the left normal.
    """

    curvature: float

    def heading(self, s: np.ndarray | float) -> np.ndarray:
        """Heading angle (rad, counter-clockwise from +x) at arc length ``s``."""
        return self.curvature * np.asarray(s, np.float64)

    def point(self, s: Any, d: Any, z: Any = 0.0) -> np.ndarray:
        """[..., 3] world point at arc length ``s``, lateral offset ``d`` and height ``z`` (m)."""
        s, d, z = np.broadcast_arrays(np.asarray(s, np.float64), np.asarray(d, np.float64),
                                      np.asarray(z, np.float64))
        th = self.heading(s)
        if self.curvature == 0.0:
            cx, cy = s, np.zeros_like(s)
        else:
            cx, cy = np.sin(th) / self.curvature, (1.0 - np.cos(th)) / self.curvature
        return np.stack([cx - d * np.sin(th), cy + d * np.cos(th), z], -1)

    def frame(self, s: Any) -> np.ndarray:
        """[..., 3, 3] rotations whose columns are the tangent, the left normal and up at ``s``."""
        return _rot_z(self.heading(s))

    def coords(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(s, d) street coordinates of world points (x, y) (m)."""
        if self.curvature == 0.0:
            return np.asarray(x, np.float64), np.asarray(y, np.float64)
        k = self.curvature
        px, py = np.asarray(x, np.float64), np.asarray(y, np.float64) - 1.0 / k  # from the centre of curvature
        d = 1.0 / k - np.sign(k) * np.hypot(px, py)
        scale = d - 1.0 / k
        return np.arctan2(-px / scale, py / scale) / k, d


# --------------------------------------------------------------------------------------------
# Gaussians with materials


@dataclass
class _Cloud:
    """Surface Gaussians with the material attributes the weathers act on.

    means [N, 3] (m), quats [N, 4] (w, x, y, z), scales [N, 3] (m), opacities [N], albedo [N, 3]
    (RGB in [0, 1]), snow [N] (how much settling snow a Gaussian facing up takes, 0-1), wet [N]
    (albedo factor of the wet surface), sheen [N] (weight of the wet sky reflection, 0-1).
    """

    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    albedo: np.ndarray
    snow: np.ndarray
    wet: np.ndarray
    sheen: np.ndarray

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @staticmethod
    def make(means: np.ndarray, quats: np.ndarray, scales: np.ndarray, albedo: np.ndarray, *,
             snow: Any = 1.0, wet: Any = 0.85, sheen: Any = 0.0, opacity: Any = OPACITY) -> _Cloud:
        n = len(means)

        def col(v: Any) -> np.ndarray:
            return np.broadcast_to(np.asarray(v, np.float64), (n,)).copy()

        return _Cloud(np.asarray(means, np.float64), np.broadcast_to(quats, (n, 4)).copy(),
                      np.broadcast_to(scales, (n, 3)).copy(), col(opacity),
                      np.clip(np.broadcast_to(albedo, (n, 3)), 0.0, 1.0).astype(np.float64),
                      col(snow), col(wet), col(sheen))

    @staticmethod
    def concat(clouds: list[_Cloud]) -> _Cloud:
        return _Cloud(**{f.name: np.concatenate([getattr(c, f.name) for c in clouds]) for f in fields(_Cloud)})

    def posed(self, T: np.ndarray) -> _Cloud:
        """The cloud moved by the rigid transform ``T`` [4, 4]."""
        q = quat_from_matrices(T[:3, :3])[0]
        return _Cloud(self.means @ T[:3, :3].T + T[:3, 3], quat_multiply(q, self.quats), self.scales, self.opacities,
                      self.albedo, self.snow, self.wet, self.sheen)


def _grid(half_u: float, half_v: float, spacing_u: float, spacing_v: float
          ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Cell centres (u, v) [M] of a grid over [-half_u, half_u] x [-half_v, half_v] and the cell sizes."""
    nu = max(1, math.ceil(2 * half_u / spacing_u - 1e-9))
    nv = max(1, math.ceil(2 * half_v / spacing_v - 1e-9))
    du, dv = 2 * half_u / nu, 2 * half_v / nv
    u, v = np.meshgrid(-half_u + (np.arange(nu) + 0.5) * du, -half_v + (np.arange(nv) + 0.5) * dv, indexing="ij")
    return u.ravel(), v.ravel(), du, dv


#: ``albedo(face, local, cell)``: RGB [M, 3] of the Gaussians of a box face from their box-frame
#: positions ``local`` [M, 3] (m) and the grid cell size along each box axis ``cell`` [3] (m, 0 along
#: the face normal), so that stripes can be box-filtered over a cell.
AlbedoFn = Callable[[str, np.ndarray, np.ndarray], np.ndarray]
#: A solid part of an object for the lidar: box centre [3], rotation [3, 3] and half size [3] (m).
Part = tuple[np.ndarray, np.ndarray, np.ndarray]


def _solid(color: Any) -> AlbedoFn:
    """An albedo function of one colour."""
    rgb = np.asarray(color, np.float64)
    return lambda face, local, cell: np.tile(rgb, (len(local), 1))


def _box(center: np.ndarray, R: np.ndarray, half: np.ndarray, faces: tuple[str, ...], spacing: float,
         albedo: AlbedoFn, *, stretch_x: float = 1.0, **material: Any) -> _Cloud:
    """Flat Gaussians tiling faces of a box.

    ``faces`` names outward normals of the box frame (``"+x"``, ``"-z"``...); ``albedo`` colours them
    (:data:`AlbedoFn`). Along the box's
    x axis the spacing is ``stretch_x`` times larger (a facade seen at a grazing angle along it).
    """
    clouds = []
    for face in faces:
        k, sign = "xyz".index(face[1]), (1.0 if face[0] == "+" else -1.0)
        i, j = (a for a in range(3) if a != k)
        F = np.zeros((3, 3))
        F[i, 0], F[j, 1], F[k, 2] = 1.0, 1.0, sign
        if np.linalg.det(F) < 0:  # keep a right-handed frame: swap the in-plane axes
            F[:, [0, 1]] = F[:, [1, 0]]
            i, j = j, i
        u, v, du, dv = _grid(half[i], half[j], spacing * (stretch_x if i == 0 else 1.0),
                             spacing * (stretch_x if j == 0 else 1.0))
        local = u[:, None] * F[:, 0] + v[:, None] * F[:, 1] + half[k] * F[:, 2]
        frame = R @ F
        cell = np.zeros(3)
        cell[i], cell[j] = du, dv
        clouds.append(_Cloud.make(center + local @ R.T, quat_from_matrices(frame),
                                  np.array([SIGMA_OF_SPACING * du, SIGMA_OF_SPACING * dv, THIN_M]),
                                  albedo(face, local, cell), **material))
    return _Cloud.concat(clouds)


def _band(x: np.ndarray, cell: float, lo: float, hi: float) -> np.ndarray:
    """Fraction of each cell [x - cell/2, x + cell/2] inside [lo, hi] (a box-filtered stripe: no aliasing)."""
    return np.clip((np.minimum(x + cell / 2, hi) - np.maximum(x - cell / 2, lo)) / cell, 0.0, 1.0)


def _pulses(x: np.ndarray, cell: float, period: float, start: float, width: float) -> np.ndarray:
    """Fraction of each cell covered by the pulses [start + i period, start + i period + width)."""

    def integral(y: np.ndarray) -> np.ndarray:
        return np.floor(y / period) * width + np.minimum(np.mod(y, period), width)

    y = np.asarray(x, np.float64) - start
    return (integral(y + cell / 2) - integral(y - cell / 2)) / cell


def _hash01(*keys: np.ndarray) -> np.ndarray:
    """A deterministic pseudo-random number in [0, 1) per integer key tuple (window colours)."""
    acc = np.zeros(np.broadcast(*keys).shape, np.uint64)
    for k in keys:
        acc = (acc ^ np.asarray(k).astype(np.int64).astype(np.uint64)) * np.uint64(0x9E3779B97F4A7C15)
        acc ^= acc >> np.uint64(31)
    return (acc >> np.uint64(11)).astype(np.float64) / float(1 << 53)


# --------------------------------------------------------------------------------------------
# The scene content


@dataclass
class _Boxes:
    """Oriented boxes the lidar is cast against: centre [M, 3], rotation [M, 3, 3], half size [M, 3],
    and per box the lidar intensity, Waymo flow class (0 background, 1 vehicle, 2 pedestrian) and
    the index of its moving object (-1: static)."""

    center: np.ndarray
    R: np.ndarray
    half: np.ndarray
    intensity: np.ndarray
    flow_class: np.ndarray
    mover: np.ndarray

    @staticmethod
    def of(items: list[tuple[np.ndarray, np.ndarray, np.ndarray, float, int, int]]) -> _Boxes:
        if not items:
            return _Boxes(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0),
                          np.zeros(0, np.int64), np.zeros(0, np.int64))
        c, R, h, i, f, m = zip(*items)
        return _Boxes(np.array(c, np.float64), np.array(R, np.float64), np.array(h, np.float64),
                      np.array(i, np.float64), np.array(f, np.int64), np.array(m, np.int64))

    @staticmethod
    def concat(parts: list[_Boxes]) -> _Boxes:
        return _Boxes(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(_Boxes)})


@dataclass
class _Mover:
    """A tracked object: its class, box size [l, w, h] (m), per-frame pose [F, 4, 4] (box centre,
    x along the length, z up) and velocity [F, 3] (m/s), and its parts per frame."""

    id: str
    class_name: str
    size: np.ndarray
    poses: np.ndarray
    velocity: np.ndarray
    parts: Callable[[int], tuple[_Cloud, list[Part]]]
    moving: bool = True


@dataclass
class _Content:
    """Everything of one scene, in street coordinates (z up, road at z = 0)."""

    spec: SynthSpec
    street: _Street
    static: _Cloud
    boxes: _Boxes
    spheres: np.ndarray  # [K, 4]: centre (m) and radius (m) of the tree canopies
    movers: list[_Mover]
    ego: np.ndarray  # [F, 4, 4] vehicle-to-world
    camera_to_vehicle: np.ndarray  # [4, 4] Waymo camera axes
    puddles: np.ndarray  # [P, 4]: s, d, half-length, half-width (m)


_FACADE_PALETTE = np.array([[0.62, 0.36, 0.28], [0.78, 0.72, 0.60], [0.55, 0.56, 0.58], [0.70, 0.66, 0.55],
                            [0.48, 0.52, 0.58], [0.82, 0.80, 0.76], [0.58, 0.44, 0.36]])
_CAR_PALETTE = np.array([[0.85, 0.85, 0.85], [0.62, 0.63, 0.65], [0.08, 0.08, 0.09], [0.60, 0.08, 0.07],
                         [0.10, 0.20, 0.50], [0.10, 0.30, 0.18], [0.72, 0.66, 0.52]])
_GLASS = np.array([0.10, 0.12, 0.15])


def _camera_to_vehicle() -> np.ndarray:
    """[4, 4] camera-to-vehicle pose in Waymo camera axes (x forward, y left, z up)."""
    return _pose(_rot_y(math.radians(CAMERA_PITCH_DEG)), np.array(CAMERA_MOUNT_M))


def _spacing(dist: float, lo: float, hi: float) -> float:
    """Grid spacing (m) of a surface ``dist`` metres from the nearest camera: a constant on screen."""
    return float(np.clip(dist * SURFACE_SPACING_PER_M, lo, hi))


def _distance(points: np.ndarray, cameras: np.ndarray, radius: float) -> float:
    """Distance (m) from the nearest camera sample to a surface around ``points``, at least 1 m."""
    d = np.linalg.norm(np.asarray(points, np.float64).reshape(-1, 1, 3) - cameras[None], axis=-1).min()
    return max(float(d) - radius, 1.0)


def _ground(street: _Street, cameras: np.ndarray, rng: np.random.Generator, puddles: np.ndarray) -> _Cloud:
    """Road (asphalt, lane markings, puddle areas), curbs and raised sidewalks, in 5 m strips whose
    spacing grows with the distance from the camera path."""
    tracks = np.array([-LANE_M / 2 - 0.85, -LANE_M / 2 + 0.85, LANE_M / 2 - 0.85, LANE_M / 2 + 0.85])
    clouds = []
    edges = np.arange(STREET_START_M, STREET_END_M + 1e-9, 5.0)
    for s0, s1 in itertools.pairwise(edges):
        sm = 0.5 * (s0 + s1)
        dist = _distance(street.point(sm, np.array([-ROAD_HALF_M, 0.0, ROAD_HALF_M])), cameras, 2.5)
        dd = _spacing(dist, 0.22, 1.2)
        # road: cells longer along the street, which the camera sees at a grazing angle
        u, v, ds, dv = _grid((s1 - s0) / 2, ROAD_HALF_M, GROUND_STRETCH * dd, dd)
        s, d = sm + u, v
        mark = np.maximum(_band(d, dv, -0.075, 0.075) * _pulses(s, ds, 9.0, 0.0, 3.0),
                          _band(np.abs(d), dv, LANE_M - 0.06, LANE_M + 0.06))
        grey = 0.27 + 0.025 * rng.standard_normal(len(s))
        albedo = (grey * (1 - mark) + 0.82 * mark)[:, None] * np.array([1.0, 1.0, 1.03])
        puddle = np.zeros(len(s))
        for ps, pd, hl, hw in puddles:
            r2 = ((s - ps) / hl) ** 2 + ((d - pd) / hw) ** 2
            puddle = np.maximum(puddle, np.clip((1.0 - r2) * 3.0, 0.0, 1.0))
        # snow settles where wheels do not pass: tyre tracks of both lanes stay darker
        in_track = np.exp(-0.5 * ((d[:, None] - tracks) / 0.3) ** 2).max(axis=1) * (np.abs(d) < LANE_M)
        snow = np.clip(0.9 - 0.65 * in_track + 0.05 * rng.standard_normal(len(s)), 0.0, 1.0)
        m = MATERIALS["rain"]
        clouds.append(_Cloud.make(
            street.point(s, d, 0.0), quat_from_matrices(street.frame(s)),
            np.stack([np.full(len(s), SIGMA_OF_SPACING * ds), np.full(len(s), SIGMA_OF_SPACING * dv),
                      np.full(len(s), THIN_M)], -1),
            albedo, snow=snow, wet=m["asphalt_wet"] + (m["puddle_wet"] - m["asphalt_wet"]) * puddle,
            sheen=m["asphalt_sheen"] + (m["puddle_sheen"] - m["asphalt_sheen"]) * puddle))
        for side in (-1.0, 1.0):
            # sidewalk: concrete slabs with joints, reaching under the facades
            half_w = (SIDEWALK_M + 0.4) / 2
            u, v, ds, dv = _grid((s1 - s0) / 2, half_w, GROUND_STRETCH * dd, dd)
            s, d = sm + u, side * (ROAD_HALF_M + half_w + v)
            joints = 1.0 - (1.0 - _pulses(s, ds, 1.5, 0.0, 0.04)) * (1.0 - _pulses(np.abs(d), dv, 1.5, 0.0, 0.04))
            grey = 0.56 + 0.02 * rng.standard_normal(len(s)) - 0.12 * joints
            clouds.append(_Cloud.make(
                street.point(s, d, CURB_M), quat_from_matrices(street.frame(s)),
                np.array([SIGMA_OF_SPACING * ds, SIGMA_OF_SPACING * dv, THIN_M]),
                grey[:, None] * np.array([1.0, 0.99, 0.96]), snow=0.95, wet=0.7, sheen=0.15))
            # curb face, towards the road: columns tangent, up, normal (right-handed on the left side;
            # on the right side the in-plane axes swap to stay right-handed)
            u, v, ds, dz = _grid((s1 - s0) / 2, CURB_M / 2, dd, CURB_M / 2)
            s = sm + u
            F = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -side], [0.0, 1.0, 0.0]])
            sigma = np.array([SIGMA_OF_SPACING * ds, SIGMA_OF_SPACING * dz, THIN_M])
            if side < 0:
                F[:, [0, 1]], sigma[[0, 1]] = F[:, [1, 0]], sigma[[1, 0]]
            clouds.append(_Cloud.make(street.point(s, side * ROAD_HALF_M, CURB_M / 2 + v),
                                      quat_from_matrices(street.frame(s) @ F), sigma, np.array([0.62, 0.62, 0.6]),
                                      snow=0.0, wet=0.75))
    return _Cloud.concat(clouds)


def _facade_albedo(base: np.ndarray, height: float, block: int) -> AlbedoFn:
    """Facade colour: ``base`` with a shop-window ground floor, window rows above, a cornice band."""

    def albedo(face: str, local: np.ndarray, cell: np.ndarray) -> np.ndarray:
        axis = 0 if face[1] == "y" else 1  # the horizontal axis of the face
        along, cell_along = local[:, axis], float(cell[axis])
        z, cell_z = local[:, 2] + height / 2, float(cell[2])
        upper = _pulses(along, cell_along, 2.6, 0.7, 1.2) * _pulses(z - 3.6, cell_z, 3.1, 0.9, 1.4) * (z > 3.6)
        shop = _pulses(along, cell_along, 3.2, 0.4, 2.3) * _band(z, cell_z, 0.5, 2.9)
        win = np.clip(upper + shop, 0.0, 1.0)
        col = np.floor((along - 0.7) / 2.6)
        row = np.floor((z - 3.6) / 3.1)
        h = _hash01(np.full(len(z), block), col, row)
        glass = _GLASS + 0.08 * h[:, None] + np.where(h > 0.85, 0.3, 0.0)[:, None] * np.array([1.0, 0.9, 0.7])
        cornice = _band(z, cell_z, height - 0.5, height) * 0.2
        wall = base * (1.0 - cornice[:, None]) * (1.0 + 0.03 * np.sin(1.3 * along + 0.7 * z))[:, None]
        return wall * (1.0 - win[:, None]) + glass * win[:, None]

    return albedo


def _buildings(street: _Street, cameras: np.ndarray, rng: np.random.Generator) -> tuple[_Cloud, _Boxes]:
    """Continuous rows of building blocks on both sides and one across the street's end."""
    clouds, boxes = [], []
    block = 0
    for side in (-1.0, 1.0):
        heights: list[tuple[float, float, float]] = []  # (s0, length, height)
        s = STREET_START_M - 8.0
        while s < STREET_END_M - 1e-6:
            length = float(rng.uniform(10.0, 24.0))
            if STREET_END_M - s - length < 6.0:  # no sliver of a block at the end
                length = STREET_END_M - s
            heights.append((s, length, float(rng.uniform(7.0, 22.0))))
            s += length
        for n, (s0, length, height) in enumerate(heights):
            depth = 12.0
            sc = s0 + length / 2
            R = street.frame(sc)
            center = street.point(sc, side * (BUILDING_LINE_M + depth / 2), height / 2)
            half = np.array([length / 2, depth / 2, height / 2])
            base = _FACADE_PALETTE[rng.integers(len(_FACADE_PALETTE))] * rng.uniform(0.9, 1.05)
            albedo = _facade_albedo(base, height, block)
            front = street.point(sc, side * BUILDING_LINE_M, height / 2)
            spacing = _spacing(_distance(front, cameras, length / 2), 0.25, 1.8)
            clouds.append(_box(center, R, half, ("-y" if side > 0 else "+y",), spacing, albedo,
                               stretch_x=FACADE_STRETCH, wet=0.88))
            # the part of a side wall that rises above the neighbouring block
            for nb, face in ((n - 1, "-x"), (n + 1, "+x")):
                lower = heights[nb][2] if 0 <= nb < len(heights) else 0.0
                if lower >= height:
                    continue
                part_half = np.array([half[0], half[1], (height - lower) / 2])
                part_center = center + R[:, 2] * (lower + part_half[2] - height / 2)
                clouds.append(_box(part_center, R, part_half, (face,), spacing,
                                   _facade_albedo(base, height - lower, block), wet=0.88))
            boxes.append((center, R, half, 0.2, 0, -1))
            block += 1
    # the building that closes the street
    height = 18.0
    R = street.frame(STREET_END_M)
    half = np.array([6.0, BUILDING_LINE_M + 14.0, height / 2])
    center = street.point(STREET_END_M + half[0], 0.0, height / 2)
    base = _FACADE_PALETTE[rng.integers(len(_FACADE_PALETTE))]
    spacing = _spacing(_distance(street.point(STREET_END_M, 0.0, 5.0), cameras, 0.0), 0.22, 1.8)
    clouds.append(_box(center, R, half, ("-x",), spacing, _facade_albedo(base, height, block), wet=0.88))
    boxes.append((center, R, half, 0.2, 0, -1))
    return _Cloud.concat(clouds), _Boxes.of(boxes)


def _trees(street: _Street, cameras: np.ndarray, rng: np.random.Generator) -> tuple[_Cloud, _Boxes, np.ndarray]:
    """Street trees on the sidewalks: a trunk (box) and a canopy of leaf-like flat Gaussians on a sphere."""
    clouds, boxes, spheres = [], [], []
    for side in (-1.0, 1.0):
        s = float(rng.uniform(4.0, 12.0))
        while s < STREET_END_M - 10.0:
            r = float(rng.uniform(1.7, 2.5))
            hc = r + float(rng.uniform(2.4, 3.0))
            d = side * (ROAD_HALF_M + 0.8)
            top = street.point(s, d, hc)
            spacing = _spacing(_distance(top, cameras, r), 0.45, 1.5)
            n = int(np.clip(4 * math.pi * r * r / spacing**2, 40, 220))
            # Fibonacci sphere: an even cover without clumps
            k = np.arange(n) + 0.5
            z = 1.0 - 2.0 * k / n
            phi = k * math.pi * (3.0 - math.sqrt(5.0)) + rng.uniform(0, 2 * math.pi)
            normal = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], -1)
            radius = r * (1.0 + 0.08 * rng.standard_normal(n))
            t1 = np.cross(np.array([0.0, 0.0, 1.0]), normal)
            t1[np.linalg.norm(t1, axis=1) < 1e-6] = [1.0, 0.0, 0.0]
            t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
            frames = np.stack([t1, np.cross(normal, t1), normal], -1)
            sigma = SIGMA_OF_SPACING * 1.15 * math.sqrt(4 * math.pi) * r / math.sqrt(n)
            green = np.array([0.17, 0.31, 0.11]) * rng.uniform(0.8, 1.2) + 0.04 * rng.standard_normal((n, 1))
            shade = 0.65 + 0.35 * (normal[:, 2:] + 1) / 2  # the underside of a canopy is in its own shade
            clouds.append(_Cloud.make(top + radius[:, None] * normal, quat_from_matrices(frames),
                                      np.array([sigma, sigma, 0.03]), green * shade,
                                      snow=np.clip(0.85 + 0.1 * rng.standard_normal(n), 0, 1), wet=0.8, sheen=0.1))
            spheres.append([*top, r])
            trunk_h = hc - 0.6 * r
            R = street.frame(s)
            center = street.point(s, d, CURB_M + trunk_h / 2)
            half = np.array([0.14, 0.14, trunk_h / 2])
            clouds.append(_box(center, R, half, ("+x", "-x", "+y", "-y"), 0.14,
                               _solid([0.30, 0.22, 0.15]), snow=0.0, wet=0.7))
            boxes.append((center, R, half, 0.15, 0, -1))
            s += float(rng.uniform(11.0, 17.0))
    return _Cloud.concat(clouds), _Boxes.of(boxes), np.array(spheres, np.float64).reshape(-1, 4)


CAR_SIZE = np.array([4.5, 1.85, 1.5])  # length, width, height (m)


def _car(color: np.ndarray, spacing: float, snow: float) -> tuple[_Cloud, list[Part]]:
    """A car in its box frame (centre of the box, x forward, z up): body, glass cabin, wheels, lights.
    Returns its Gaussians and the (centre, rotation, half size) of the parts the lidar sees."""
    _, w, h = CAR_SIZE
    ground = -h / 2
    eye = np.eye(3)
    body_c, body_h = np.array([0.0, 0.0, ground + 0.65]), np.array([CAR_SIZE[0] / 2, w / 2, 0.35])
    cab_c, cab_h = np.array([-0.25, 0.0, ground + 1.125]), np.array([1.2, 0.82, 0.375])

    def body(face: str, p: np.ndarray, cell: np.ndarray) -> np.ndarray:
        out = np.tile(color, (len(p), 1))
        if face[1] != "x":
            return out
        y, z, du, dv = np.abs(p[:, 1]), p[:, 2] - body_c[2], float(cell[1]), float(cell[2])
        lamp = _band(y, du, 0.5, 0.8) * _band(z, dv, 0.02, 0.2)
        if face == "+x":
            out = out * (1 - lamp[:, None]) + np.array([0.95, 0.95, 0.85]) * lamp[:, None]
            grille = _band(y, du, 0.0, 0.4) * _band(z, dv, -0.05, 0.15)
            out = out * (1 - grille[:, None]) + 0.08 * grille[:, None]
        elif face == "-x":
            out = out * (1 - lamp[:, None]) + np.array([0.7, 0.08, 0.06]) * lamp[:, None]
        return out

    def cabin(face: str, p: np.ndarray, cell: np.ndarray) -> np.ndarray:
        if face == "+z":
            return np.tile(color, (len(p), 1))
        along = p[:, 0] - cab_c[0] if face[1] == "y" else np.abs(p[:, 1])
        du, dv = float(cell[0] if face[1] == "y" else cell[1]), float(cell[2])
        z = p[:, 2] - cab_c[2]
        pillar = _band(np.abs(along), du, cab_h[0] - 0.12, cab_h[0]) if face[1] == "y" else 0.0 * z
        frame = np.maximum(pillar, _band(z, dv, -cab_h[2], -cab_h[2] + 0.08))
        return _GLASS * (1 - frame[:, None]) + color * frame[:, None]

    parts = [_box(body_c, eye, body_h, ("+x", "-x", "+y", "-y", "+z"), spacing, body, snow=snow, wet=0.9,
                  sheen=0.5),
             _box(cab_c, eye, cab_h, ("+x", "-x", "+y", "-y", "+z"), spacing, cabin, snow=snow, wet=0.9,
                  sheen=0.6)]
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            c = np.array([sx * 1.45, sy * (w / 2 - 0.12), ground + 0.32])
            parts.append(_box(c, eye, np.array([0.32, 0.12, 0.32]), ("+x", "-x", "+y", "-y"), min(spacing, 0.1),
                              _solid([0.05, 0.05, 0.05]), snow=0.0, wet=0.95))
    return _Cloud.concat(parts), [(body_c, eye, body_h), (cab_c, eye, cab_h)]


def _pedestrian(shirt: np.ndarray, trousers: np.ndarray, skin: np.ndarray, cadence_hz: float
                ) -> Callable[[float], tuple[_Cloud, list[Part]]]:
    """A walking person in its box frame (0.9 x 0.7 x 1.8 m, centre of the box, x forward): legs and
    arms swing about the hips and shoulders at ``cadence_hz`` strides per second."""
    ground = -0.9

    def at(t: float) -> tuple[_Cloud, list[Part]]:
        swing = 0.42 * math.sin(2 * math.pi * cadence_hz * t)
        parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]] = []
        for side, phase in ((1.0, 1.0), (-1.0, -1.0)):
            R = _rot_y(phase * swing)
            hip = np.array([0.0, side * 0.1, ground + 0.88])
            parts.append((hip + R @ np.array([0.0, 0.0, -0.44]), R, np.array([0.08, 0.08, 0.44]), trousers, 0.0))
            R = _rot_y(-0.7 * phase * swing)
            shoulder = np.array([0.0, side * 0.27, ground + 1.45])
            parts.append((shoulder + R @ np.array([0.0, 0.0, -0.3]), R, np.array([0.05, 0.05, 0.3]), shirt, 0.0))
        parts.append((np.array([0.0, 0.0, ground + 1.19]), np.eye(3), np.array([0.13, 0.21, 0.31]), shirt, 0.0))
        parts.append((np.array([0.0, 0.0, ground + 1.64]), np.eye(3), np.array([0.1, 0.09, 0.12]), skin, 0.0))
        clouds = [_box(c, R, h, ("+x", "-x", "+y", "-y", "+z", "-z"), 0.045,
                       _solid(col), snow=s, wet=0.9)
                  for c, R, h, col, s in parts]
        return _Cloud.concat(clouds), [(c, R, h) for c, R, h, _, _ in parts]

    return at


def _street_pose(street: _Street, s: float, d: float, z: float, reverse: bool = False) -> np.ndarray:
    """[4, 4] pose at street coordinates, x along the street (against it when ``reverse``)."""
    R = street.frame(s)
    if reverse:
        R = R @ _rot_z(math.pi)
    return _pose(R, street.point(s, d, z))


def build_content(spec: SynthSpec) -> _Content:
    """Lay out scene ``spec``: all static Gaussians, lidar boxes and the moving objects' tracks.

    Parameters
    ----------
    spec : SynthSpec

    Returns
    -------
    _Content
        In street coordinates (m, z up, road surface at z = 0); a pure function of ``spec``.
    """
    rng = np.random.default_rng(spec.seed)
    street = _Street(spec.curvature)
    times = np.arange(N_FRAMES) / FPS
    ego = np.array([_street_pose(street, SPEED * t, EGO_LATERAL_M, 0.0) for t in times])
    cam_to_vehicle = _camera_to_vehicle()
    cameras = np.array([(ego[k] @ cam_to_vehicle)[:3, 3] for k in (0, 10, 20, N_FRAMES - 1)])
    # puddles (s, d, half-length, half-width; m): along the gutters and in both lanes
    puddles = np.array([[rng.uniform(8.0, 70.0), side * rng.uniform(3.3, 4.2), rng.uniform(3.0, 6.0),
                         rng.uniform(0.6, 1.0)] for side in (-1.0, -1.0, 1.0, 1.0)] +
                       [[rng.uniform(12.0, 50.0), lane * LANE_M / 2 + rng.uniform(-0.6, 0.6), rng.uniform(2.5, 5.0),
                         rng.uniform(0.8, 1.4)] for lane in (-1.0, -1.0, 1.0)])
    ground = _ground(street, cameras, rng, puddles)
    buildings, building_boxes = _buildings(street, cameras, rng)
    trees, trunk_boxes, spheres = _trees(street, cameras, rng)
    clouds = [ground, buildings, trees]
    boxes = [building_boxes, trunk_boxes]
    movers: list[_Mover] = []

    def add_static_car(s: float, side: float, n: int) -> None:
        pose = _street_pose(street, s, side * (LANE_M + PARKING_M / 2), CAR_SIZE[2] / 2, reverse=side > 0)
        spacing = _spacing(_distance(pose[:3, 3], cameras, 2.3), 0.12, 0.6)
        cloud, parts = _car(_CAR_PALETTE[rng.integers(len(_CAR_PALETTE))] * rng.uniform(0.9, 1.05), spacing, 1.0)
        clouds.append(cloud.posed(pose))
        boxes.append(_Boxes.of([(pose[:3, :3] @ c + pose[:3, 3], pose[:3, :3] @ R, h, 0.3, 1, -1)
                                for c, R, h in parts]))
        movers.append(_Mover(f"parked_{n}", "Vehicle", CAR_SIZE.copy(), np.repeat(pose[None], N_FRAMES, 0),
                             np.zeros((N_FRAMES, 3)), lambda k: (cloud, parts), moving=False))

    # the pedestrian walks on a sidewalk: 1.4 m/s along the street on the right, 1.3 m/s towards the
    # camera on the left
    side_ped = {"right": -1.0, "left": 1.0, None: 0.0}[spec.pedestrian]
    s_ped = (30.0 + 1.4 * times) if side_ped < 0 else (45.0 - 1.3 * times)
    d_ped = side_ped * (ROAD_HALF_M + 1.9)
    # no parked car between the camera and the pedestrian: where the sight lines cross the parking lane
    s_cam = SPEED * times + CAMERA_MOUNT_M[0]
    d_park = side_ped * (LANE_M + PARKING_M / 2)
    cross = s_cam + (s_ped - s_cam) * (d_park - EGO_LATERAL_M) / (d_ped - EGO_LATERAL_M)
    keep_clear = (float(cross.min()) - 3.0, float(s_ped.max()) + 3.0) if side_ped else (0.0, 0.0)

    n_parked = 0
    for side in (-1.0, 1.0):
        s = float(rng.uniform(6.0, 14.0))
        while s < 85.0:
            if rng.random() < 0.6 and not (side == side_ped and keep_clear[0] < s < keep_clear[1]):
                add_static_car(s, side, n_parked)
                n_parked += 1
            s += float(rng.uniform(6.5, 12.0))

    for kind in spec.movers:
        if kind == "oncoming":
            s0, speed, d, reverse = float(rng.uniform(50.0, 65.0)), -9.0, LANE_M / 2, True
        elif kind == "lead":
            s0, speed, d, reverse = float(rng.uniform(17.0, 21.0)), 6.5, EGO_LATERAL_M, False
        else:
            raise ValueError(f"unknown mover {kind!r}")
        poses = np.array([_street_pose(street, s0 + speed * t, d, CAR_SIZE[2] / 2, reverse) for t in times])
        spacing = _spacing(_distance(poses[:, :3, 3], cameras, 2.3), 0.12, 0.3)
        cloud, parts = _car(_CAR_PALETTE[rng.integers(len(_CAR_PALETTE))], spacing, 0.5)
        velocity = np.gradient(poses[:, :3, 3], times, axis=0)
        movers.append(_Mover(f"car_{kind}", "Vehicle", CAR_SIZE.copy(), poses, velocity,
                             (lambda c, p: lambda k: (c, p))(cloud, parts)))

    if spec.pedestrian is not None:
        poses = np.array([_street_pose(street, s, d_ped, CURB_M + 0.9, side_ped > 0) for s in s_ped])
        shirt = np.array([[0.7, 0.15, 0.12], [0.15, 0.35, 0.6], [0.85, 0.75, 0.2], [0.2, 0.5, 0.3]])[
            rng.integers(4)]
        trousers = np.array([[0.1, 0.12, 0.2], [0.08, 0.08, 0.08], [0.5, 0.45, 0.35]])[rng.integers(3)]
        skin = np.array([[0.8, 0.62, 0.5], [0.55, 0.4, 0.3], [0.35, 0.25, 0.2]])[rng.integers(3)]
        walk = _pedestrian(shirt, trousers, skin, cadence_hz=1.0)
        velocity = np.gradient(poses[:, :3, 3], times, axis=0)
        movers.append(_Mover("pedestrian_0", "Pedestrian", np.array([0.9, 0.7, 1.8]), poses, velocity,
                             lambda k: walk(k / FPS)))

    return _Content(spec=spec, street=street, static=_Cloud.concat(clouds), boxes=_Boxes.concat(boxes),
                    spheres=spheres, movers=movers, ego=ego, camera_to_vehicle=cam_to_vehicle, puddles=puddles)


def _cloud_at(content: _Content, k: int) -> _Cloud:
    """Static and moving Gaussians of frame ``k`` (street coordinates)."""
    parts = [content.static]
    for m in content.movers:
        if m.moving:
            parts.append(m.parts(k)[0].posed(m.poses[k]))
    return _Cloud.concat(parts)


def _boxes_at(content: _Content, k: int) -> _Boxes:
    """Lidar boxes of frame ``k``: the static ones and the moving objects' parts, posed."""
    items = []
    for i, m in enumerate(content.movers):
        if not m.moving:
            continue
        T = m.poses[k]
        flow = 2 if m.class_name == "Pedestrian" else 1
        items += [(T[:3, :3] @ c + T[:3, 3], T[:3, :3] @ R, h, 0.3, flow, i) for c, R, h in m.parts(k)[1]]
    return _Boxes.concat([content.boxes, _Boxes.of(items)])


# --------------------------------------------------------------------------------------------
# Lidar


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


def _cast(origin: np.ndarray, ego_R: np.ndarray, elevation: np.ndarray, azimuth: np.ndarray, boxes: _Boxes,
          spheres: np.ndarray, street: _Street) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First hits of a sweep's rays (street coordinates).

    Parameters
    ----------
    origin : ndarray [3]
        Sensor position (m).
    ego_R : ndarray [3, 3]
        Vehicle-to-world rotation.
    elevation, azimuth : ndarray [B], [C]
        The ray grid in the vehicle frame (rad, increasing).
    boxes : _Boxes
    spheres : ndarray [K, 4]
        Canopy spheres (centre, radius; m).
    street : _Street

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


def _lidar(content: _Content, k: int) -> np.ndarray:
    """The sweep of frame ``k``: float32 [N, 14] in the vehicle frame of frame k (drivestudio Waymo
    columns: ray origin 3, point 3, flow 3, flow class, ground, intensity, elongation, laser id)."""
    ego = content.ego[k]
    elevation = np.radians(np.linspace(*LIDAR_ELEVATION_DEG, LIDAR_BEAMS))
    azimuth = np.radians(np.linspace(-LIDAR_AZIMUTH_DEG, LIDAR_AZIMUTH_DEG, LIDAR_COLUMNS))
    origin_v = np.array(LIDAR_MOUNT_M)
    boxes = _boxes_at(content, k)
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


# --------------------------------------------------------------------------------------------
# Materials and the sky per weather


def _sky(rays_up: np.ndarray, weather: str) -> np.ndarray:
    """[H, W, 3] sky colour by the elevation of each pixel's ray (``rays_up``: sine of it)."""
    e = np.clip(rays_up, 0.0, 1.0)[..., None]
    if weather == "clear":
        horizon, zenith = np.array([0.78, 0.84, 0.92]), np.array([0.30, 0.52, 0.88])
        return horizon + (zenith - horizon) * (1.0 - np.exp(-e / 0.22))
    # an overcast sky is brighter overhead than at the horizon: luminance (1 + 2 sin e) / 3 in the CIE
    # overcast sky (Moon & Spencer 1942), softened
    grey = np.asarray(MATERIALS[weather]["overcast_sky"], np.float64)
    return grey * (0.8 + 0.2 * (1.0 + 2.0 * e) / 3.0)


def _shade(weather: str, cloud: _Cloud, normals: np.ndarray, eye: np.ndarray, reflected: np.ndarray) -> np.ndarray:
    """[N, 3] colours of the Gaussians under ``weather`` seen from ``eye`` (docs/design.md §3).

    ``reflected`` [3] is the sky colour a wet surface mirrors (the weather's overcast or haze colour).
    """
    up = normals[:, 2]
    if weather == "clear":
        m = MATERIALS["clear"]
        sun = np.asarray(m["sun_direction"], np.float64)
        light = m["ambient"] + m["sun"] * np.maximum(normals @ (sun / np.linalg.norm(sun)), 0.0)
        return cloud.albedo * light[:, None]
    m = MATERIALS[weather]
    light = (m["light"] * (1.0 - m["sky_light"] + m["sky_light"] * up))[:, None]  # the overcast sky lights from above
    if weather == "rain":
        view = cloud.means - eye
        cos = np.abs(np.sum(view * normals, axis=1)) / np.maximum(np.linalg.norm(view, axis=1), 1e-9)
        fresnel = (m["fresnel_f0"] + (1.0 - m["fresnel_f0"]) * (1.0 - cos) ** 5) * cloud.sheen
        return cloud.albedo * cloud.wet[:, None] * light * (1.0 - fresnel[:, None]) + fresnel[:, None] * reflected
    if weather == "snow":
        lo, hi = m["normal_up_from"], m["normal_up_full"]
        facing = np.clip((up - lo) / (hi - lo), 0.0, 1.0)
        cover = (cloud.snow * facing * facing * (3.0 - 2.0 * facing))[:, None]  # smoothstep
        # what snow leaves bare is damp
        return light * ((1.0 - cover) * cloud.albedo * m["wet"] + cover * np.asarray(m["snow_albedo"]))
    return cloud.albedo * light * m["wet"]


# --------------------------------------------------------------------------------------------
# Rendering and writing


@dataclass
class _Splats:
    """The five Gaussian arrays the renderer takes (float32)."""

    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    colors: np.ndarray


def _reference_model() -> tuple[Any, Any, Any]:
    """The renderer's classes, imported only when a scene is generated (they need torch and numba)."""
    try:
        from wcbench.reference_model.weather.conditions import Weather
        from wcbench.reference_model.weather.renderer import WeatherRenderer, camera_velocity
    except ImportError as exc:
        raise InputError(
            f"the synth_* scene sets are rendered with the reference model, which needs torch and numba "
            f"({exc}); install them with: pip install \"wcbench[model]\""
        ) from None
    return Weather, WeatherRenderer, camera_velocity


def _png(path: Path, image: np.ndarray) -> None:
    """Write uint8 RGB [H, W, 3] or a uint8 mask [H, W] as PNG (OpenCV's encoder is deterministic)."""
    img = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    path.write_bytes(buf.tobytes())


def _savetxt(path: Path, values: np.ndarray) -> None:
    """A matrix as text in numpy's default format (as drivestudio writes it): fixed, so deterministic."""
    np.savetxt(path, values, fmt="%.18e")


def _dynamic_masks(content: _Content, k: int, camera: Camera, lidar_world: np.ndarray, shift: np.ndarray
                   ) -> dict[str, np.ndarray]:
    """drivestudio's dynamic masks of frame ``k``: per class group, the 2D bounding rectangle of the
    projected box corners of objects moving faster than 1 m/s, skipping objects with a corner
    behind the camera or without a lidar point in their box (occluded)."""
    masks = {g: np.zeros((HEIGHT, WIDTH), np.uint8) for g in ("all", "human", "vehicle")}
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)
    for m in content.movers:
        if np.linalg.norm(m.velocity[k][:2]) <= 1.0:
            continue
        T = m.poses[k]
        local = (lidar_world - T[:3, 3]) @ T[:3, :3]
        if not np.any(np.all(np.abs(local) <= m.size / 2, axis=1)):
            continue
        corners = (signs * m.size / 2) @ T[:3, :3].T + T[:3, 3] - shift
        uv, z = camera.project(corners)
        if not np.all(z > 0):
            continue
        u = np.clip(uv[:, 0], 0, WIDTH)
        v = np.clip(uv[:, 1], 0, HEIGHT)
        if u.max() - u.min() == 0 or v.max() - v.min() == 0:
            continue
        group = "human" if m.class_name == "Pedestrian" else "vehicle"
        for g in ("all", group):
            masks[g][int(v.min()):int(v.max()), int(u.min()):int(u.max())] = 255
    return masks


def write_synth_scene(root: Path, index: int, *, n_frames: int = N_FRAMES) -> dict[str, Any]:
    """Generate synthetic scene ``index`` into ``root`` in drivestudio's Waymo layout, with truth frames.

    Writes ``images/{t:03d}_0.png``, ``ego_pose/{t:03d}.txt``, ``extrinsics/0.txt``,
    ``intrinsics/0.txt``, ``lidar/{t:03d}.bin``, ``sky_masks/{t:03d}_0.png``,
    ``dynamic_masks/{all,human,vehicle}/{t:03d}_0.png``, ``instances/instances_info.json`` and
    ``frame_instances.json``, ``truth/{rain,snow,fog}/{t:03d}_0.png``, ``truth/weather.json`` and,
    last, ``synth.json`` (docs/design.md §3).

    Parameters
    ----------
    root : Path
        Folder to write into; created if missing, must hold no scene yet.
    index : int
        Scene number in :data:`SCENES`.
    n_frames : int
        Frames to write (the first ones; fewer only for quick checks: the scene sets use all).

    Returns
    -------
    dict
        What was written: Gaussian counts (static, moving, per frame), lidar points per frame,
        pedestrian, presets (the contents of ``synth.json``).

    Raises
    ------
    InputError
        Without torch (the reference model renders the frames).
    """
    Weather, WeatherRenderer, camera_velocity = _reference_model()
    spec = SCENES[index]
    content = build_content(spec)
    root = Path(root)
    for sub in ("images", "ego_pose", "extrinsics", "intrinsics", "lidar", "sky_masks", "dynamic_masks/all",
                "dynamic_masks/human", "dynamic_masks/vehicle", "instances",
                *(f"truth/{w}" for w in TRUTH_WEATHERS)):
        (root / sub).mkdir(parents=True, exist_ok=True)

    K = np.array([[FOCAL, 0.0, WIDTH / 2], [0.0, FOCAL, HEIGHT / 2], [0.0, 0.0, 1.0]])
    _savetxt(root / "intrinsics" / "0.txt", np.array([FOCAL, FOCAL, WIDTH / 2, HEIGHT / 2, 0, 0, 0, 0, 0], float))
    _savetxt(root / "extrinsics" / "0.txt", content.camera_to_vehicle)
    global_offset = _pose(np.eye(3), GLOBAL_ORIGIN)
    c2w = [e @ content.camera_to_vehicle @ OPENCV_TO_WAYMO for e in content.ego]
    # Rendered where the loaders put the scene: the first camera at the origin (docs/design.md §2),
    # so a method using the same physics and seed sees the same particles.
    shift = c2w[0][:3, 3].copy()
    cameras = []
    for k in range(N_FRAMES):
        pose = c2w[k].copy()
        pose[:3, 3] -= shift
        cameras.append(Camera(K=K, width=WIDTH, height=HEIGHT, camera_to_world=pose))
    centers = np.array([c.center for c in cameras])
    times = np.arange(N_FRAMES) / FPS

    weathers = ("clear", *TRUTH_WEATHERS)
    first = _cloud_at(content, 0)
    splats0 = _Splats(*(np.asarray(a, np.float32) for a in (first.means - shift, first.quats, first.scales,
                                                           first.opacities, first.albedo)))
    renderers = {}
    for w in weathers:
        weather = Weather(kind=w, seed=spec.seed, **TRUTH_WEATHERS.get(w, {}))
        renderers[w] = WeatherRenderer(splats0, weather, up=np.array([0.0, 0.0, 1.0]),
                                       heading=cameras[0].camera_to_world[:3, 2], anchor=centers[0])
    # a wet surface mirrors the sky it sees: the weather's haze colour when it has haze (the sky then
    # takes that colour, docs/design.md §7), else its overcast colour
    reflected = {w: np.asarray(r.fog_color if r.beta > 0 else MATERIALS[w].get("overcast_sky", (0, 0, 0)),
                               np.float64) for w, r in renderers.items()}

    jj, ii = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    rays_cam = np.stack([(jj - K[0, 2]) / FOCAL, (ii - K[1, 2]) / FOCAL, np.ones_like(jj)], -1)
    rays_cam /= np.linalg.norm(rays_cam, axis=-1, keepdims=True)
    counts: dict[str, list[int]] = {"lidar_points": [], "gaussians": []}
    for k, cam in enumerate(cameras[:n_frames]):
        cloud = _cloud_at(content, k)
        normals = gaussian_normals(cloud.quats, cloud.scales)
        means = cloud.means - shift
        rays_up = rays_cam @ cam.camera_to_world[2, :3]
        velocity = camera_velocity(centers, times, k)
        for w in weathers:
            colors = _shade(w, cloud, normals, cam.center + shift, reflected[w])
            splats = _Splats(*(np.asarray(a, np.float32) for a in (means, cloud.quats, cloud.scales, cloud.opacities,
                                                                   np.clip(colors, 0.0, 1.0))))
            r = renderers[w]
            frame = r.render(cam, float(times[k]), camera_velocity=velocity, gaussians=splats,
                             background_image=_sky(rays_up, w).astype(np.float32) if r.background_visible else None)
            image = to_uint8(np.asarray(frame.image, np.float64))  # float64 math: the bytes VERSION 1 shipped
            if w == "clear":
                _png(root / "images" / f"{k:03d}_0.png", image)
                _png(root / "sky_masks" / f"{k:03d}_0.png", np.where(frame.alpha < 0.5, 255, 0).astype(np.uint8))
            else:
                _png(root / "truth" / w / f"{k:03d}_0.png", image)
        _savetxt(root / "ego_pose" / f"{k:03d}.txt", global_offset @ content.ego[k])
        sweep = _lidar(content, k)
        sweep.tofile(root / "lidar" / f"{k:03d}.bin")
        world = sweep[:, 3:6].astype(np.float64) @ content.ego[k][:3, :3].T + content.ego[k][:3, 3]
        for group, mask in _dynamic_masks(content, k, cam, world, shift).items():
            _png(root / "dynamic_masks" / group / f"{k:03d}_0.png", mask)
        counts["lidar_points"].append(len(sweep))
        counts["gaussians"].append(len(cloud))

    instances: dict[str, Any] = {}
    frame_instances: dict[str, list[int]] = {str(k): [] for k in range(n_frames)}
    for n, m in enumerate(content.movers):
        instances[str(n)] = {
            "id": f"{scene_folder(index)}_{m.id}",
            "class_name": m.class_name,
            "frame_annotations": {
                "frame_idx": list(range(n_frames)),
                "obj_to_world": [(global_offset @ p).tolist() for p in m.poses[:n_frames]],
                "box_size": [m.size.tolist()] * n_frames,
            },
        }
        for k in range(n_frames):
            frame_instances[str(k)].append(n)
    (root / "instances" / "instances_info.json").write_text(json.dumps(instances, indent=4), encoding="utf-8")
    (root / "instances" / "frame_instances.json").write_text(json.dumps(frame_instances, indent=4),
                                                             encoding="utf-8")

    truth = {}
    for w in TRUTH_WEATHERS:
        info = renderers[w].info()
        truth[w] = {"kind": w, "preset": info["preset"], "seed": spec.seed, "weather": info["weather"],
                    "rate_mm_h": info.get("particles", {}).get("spec", {}).get("rate_mm_h"),
                    "visibility_m": info["fog"]["visibility_m"], "renderer": info,
                    "materials": MATERIALS[w], "sky_mirrored_by_wet_surfaces": reflected[w]}
    truth["clear"] = {"materials": MATERIALS["clear"], "sky": "per-pixel gradient by ray elevation"}
    (root / "truth" / "weather.json").write_text(dumps_json(truth), encoding="utf-8")

    moving = [m for m in content.movers if m.moving]
    summary = {
        "version": VERSION, "scene": scene_folder(index), "seed": spec.seed, "curvature_per_m": spec.curvature,
        "pedestrian": spec.pedestrian, "moving_objects": [m.id for m in moving],
        "parked_cars": sum(not m.moving for m in content.movers),
        "frames": n_frames, "fps": FPS, "image_size": [WIDTH, HEIGHT], "focal_px": FOCAL, "speed_m_s": SPEED,
        "gaussians": {"static": len(content.static), "per_frame": counts["gaussians"][0],
                      "moving": counts["gaussians"][0] - len(content.static)},
        "lidar_points": counts["lidar_points"], "truth_weathers": TRUTH_WEATHERS,
        "global_origin_m": GLOBAL_ORIGIN.tolist(),
    }
    (root / MARKER).write_text(dumps_json(summary), encoding="utf-8")
    return summary


def ensure_synth_scenes(count: int) -> Path:
    """Build synthetic scenes 0 .. ``count`` - 1 once into the cache folder; return the folder holding them.

    Each scene is written into a temporary folder and renamed into place, so a killed build never
    leaves half a scene and concurrent builders race safely (the loser finds the winner's scene).

    Parameters
    ----------
    count : int
        Number of scenes (1 to ``len(SCENES)``).

    Returns
    -------
    Path
        ``<cache>/scenes/synth-v{VERSION}``; scene k is its sub-folder ``synth_{k:03d}``.

    Raises
    ------
    InputError
        When a scene must be generated and torch is missing, or an incomplete folder is in the way.
    """
    parent = cache_dir() / "scenes" / f"synth-v{VERSION}"
    for spec in SCENES[:count]:
        root = parent / scene_folder(spec.index)
        if (root / MARKER).is_file():
            continue
        _reference_model()  # fail before any work when torch is missing
        announce(f"generating synthetic scene {root.name} (first use only)")
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=parent))
        try:
            write_synth_scene(tmp, spec.index)
            try:
                os.replace(tmp, root)
            except OSError:
                if not (root / MARKER).is_file():  # another process won the race only if complete
                    raise InputError(f"{root}: an incomplete synthetic scene is in the way; delete the folder "
                                     "and it is generated again") from None
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return parent


def ensure_synth_1() -> Path:
    """Generator of the ``synth_1`` set: scene 0 (see :func:`ensure_synth_scenes`)."""
    return ensure_synth_scenes(1)


def ensure_synth_3() -> Path:
    """Generator of the ``synth_3`` set: scenes 0-2 (see :func:`ensure_synth_scenes`)."""
    return ensure_synth_scenes(3)
