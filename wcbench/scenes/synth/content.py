"""The content of a synthetic scene: street surfaces, buildings, trees, parked and moving cars and
pedestrians, as Gaussians with materials and as boxes for the lidar and the sun's shadows
(docs/design.md §3). What a scene has beyond v1's street (dark road patches, a white facade,
untracked movers) comes from its :class:`~.layout.Profile` and :class:`~.layout.SynthSpec`."""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from wcbench.reference_model.transforms import quat_from_matrices
from wcbench.scenes.synth.geometry import (
    AlbedoFn,
    Cloud,
    GlassFn,
    Part,
    Street,
    band_fraction,
    box_surface,
    cell_grid,
    hash01,
    pulse_fraction,
    rigid_transform,
    rot_y,
    rot_z,
    solid_albedo,
)
from wcbench.scenes.synth.layout import (
    BUILDING_LINE_M,
    CAMERA_MOUNT_M,
    CAMERA_PITCH_DEG,
    CURB_M,
    EGO_LATERAL_M,
    FACADE_STRETCH,
    FPS,
    GROUND_STRETCH,
    LANE_M,
    MATERIALS_V1,
    N_FRAMES,
    PARKING_M,
    ROAD_HALF_M,
    SIDEWALK_M,
    SIGMA_OF_SPACING,
    SPEED,
    STREET_END_M,
    STREET_START_M,
    SURFACE_SPACING_PER_M,
    THIN_M,
    Profile,
    SynthSpec,
)
from wcbench.scenes.synth.materials import physical_materials

__all__ = ["Boxes", "Content", "Mover", "boxes_at", "build_content", "cloud_at"]


@dataclass
class Boxes:
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
    def of(items: list[tuple[np.ndarray, np.ndarray, np.ndarray, float, int, int]]) -> Boxes:
        if not items:
            return Boxes(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0),
                          np.zeros(0, np.int64), np.zeros(0, np.int64))
        c, R, h, i, f, m = zip(*items)
        return Boxes(np.array(c, np.float64), np.array(R, np.float64), np.array(h, np.float64),
                      np.array(i, np.float64), np.array(f, np.int64), np.array(m, np.int64))

    @staticmethod
    def concat(parts: list[Boxes]) -> Boxes:
        return Boxes(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Boxes)})


@dataclass
class Mover:
    """An object with a pose per frame: its class, box size [l, w, h] (m), per-frame pose [F, 4, 4]
    (box centre, x along the length, z up) and velocity [F, 3] (m/s), and its parts per frame.
    ``moving``: it moves (parked cars do not); ``tracked``: it has an instance box (an untracked
    mover is in no instance file and no dynamic mask, yet the lidar and the camera see it)."""

    id: str
    class_name: str
    size: np.ndarray
    poses: np.ndarray
    velocity: np.ndarray
    parts: Callable[[int], tuple[Cloud, list[Part]]]
    moving: bool = True
    tracked: bool = True


@dataclass
class Content:
    """Everything of one scene, in street coordinates (z up, road at z = 0)."""

    spec: SynthSpec
    street: Street
    static: Cloud
    boxes: Boxes
    spheres: np.ndarray  # [K, 4]: centre (m) and radius (m) of the tree canopies
    movers: list[Mover]
    ego: np.ndarray  # [F, 4, 4] vehicle-to-world
    camera_to_vehicle: np.ndarray  # [4, 4] Waymo camera axes
    puddles: np.ndarray  # [P, 4]: s, d, half-length, half-width (m)
    road_patches: list[dict[str, Any]] = field(default_factory=list)  # dark patches (see _road_patches)
    white_facade: dict[str, Any] | None = None  # the white-painted block: s range (m), side, albedo


_FACADE_PALETTE = np.array([[0.62, 0.36, 0.28], [0.78, 0.72, 0.60], [0.55, 0.56, 0.58], [0.70, 0.66, 0.55],
                            [0.48, 0.52, 0.58], [0.82, 0.80, 0.76], [0.58, 0.44, 0.36]])
_CAR_PALETTE = np.array([[0.85, 0.85, 0.85], [0.62, 0.63, 0.65], [0.08, 0.08, 0.09], [0.60, 0.08, 0.07],
                         [0.10, 0.20, 0.50], [0.10, 0.30, 0.18], [0.72, 0.66, 0.52]])
_GLASS = np.array([0.10, 0.12, 0.15])
#: A white-painted facade (sRGB): brighter than the clear sky's horizon in sun.
_WHITE_PAINT = np.array([0.93, 0.93, 0.91])
#: Road patches (sRGB albedo): fresh tar of a trench repair and an oil stain, both about as dark as
#: the asphalt (0.27) in the clear frames' shadow, whose light is 0.35 of the sunlit road's (linear).
_TAR, _OIL = 0.15, 0.17


def _camera_to_vehicle() -> np.ndarray:
    """[4, 4] camera-to-vehicle pose in Waymo camera axes (x forward, y left, z up)."""
    return rigid_transform(rot_y(math.radians(CAMERA_PITCH_DEG)), np.array(CAMERA_MOUNT_M))


def _spacing(dist: float, lo: float, hi: float) -> float:
    """Grid spacing (m) of a surface ``dist`` metres from the nearest camera: a constant on screen."""
    return float(np.clip(dist * SURFACE_SPACING_PER_M, lo, hi))


def _distance(points: np.ndarray, cameras: np.ndarray, radius: float) -> float:
    """Distance (m) from the nearest camera sample to a surface around ``points``, at least 1 m."""
    d = np.linalg.norm(np.asarray(points, np.float64).reshape(-1, 1, 3) - cameras[None], axis=-1).min()
    return max(float(d) - radius, 1.0)


def _patch_cover(s: np.ndarray, d: np.ndarray, ds: float, dv: float, patches: list[dict[str, Any]]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Share [M] of each road cell under a dark patch, and the patch's albedo there [M] (sRGB).

    Rectangles are box-filtered over the cell (no aliasing); an ellipse's edge is a ramp one cell wide.
    """
    cover, albedo = np.zeros(len(s)), np.zeros(len(s))
    for p in patches:
        if p["shape"] == "rectangle":
            c = (band_fraction(s, ds, p["s"] - p["half_length"], p["s"] + p["half_length"])
                 * band_fraction(d, dv, p["d"] - p["half_width"], p["d"] + p["half_width"]))
        else:
            r = np.hypot((s - p["s"]) / p["half_length"], (d - p["d"]) / p["half_width"])
            c = np.clip(0.5 + (1.0 - r) * min(p["half_length"], p["half_width"]) / max(ds, dv), 0.0, 1.0)
        albedo = np.where(c > cover, p["albedo"], albedo)
        cover = np.maximum(cover, c)
    return cover, albedo


def _ground(street: Street, cameras: np.ndarray, rng: np.random.Generator, puddles: np.ndarray,
            rain: dict[str, Any], patches: list[dict[str, Any]]) -> Cloud:
    """Road (asphalt, lane markings, puddle areas, dark ``patches``), curbs and raised sidewalks, in
    5 m strips whose spacing grows with the distance from the camera path; ``rain`` gives the wet
    factors and sheens of asphalt and puddles (``asphalt_wet``, ``puddle_wet``, ``asphalt_sheen``,
    ``puddle_sheen``)."""
    tracks = np.array([-LANE_M / 2 - 0.85, -LANE_M / 2 + 0.85, LANE_M / 2 - 0.85, LANE_M / 2 + 0.85])
    clouds = []
    edges = np.arange(STREET_START_M, STREET_END_M + 1e-9, 5.0)
    for s0, s1 in itertools.pairwise(edges):
        sm = 0.5 * (s0 + s1)
        dist = _distance(street.point(sm, np.array([-ROAD_HALF_M, 0.0, ROAD_HALF_M])), cameras, 2.5)
        dd = _spacing(dist, 0.22, 1.2)
        # road: cells longer along the street, which the camera sees at a grazing angle
        u, v, ds, dv = cell_grid((s1 - s0) / 2, ROAD_HALF_M, GROUND_STRETCH * dd, dd)
        s, d = sm + u, v
        mark = np.maximum(band_fraction(d, dv, -0.075, 0.075) * pulse_fraction(s, ds, 9.0, 0.0, 3.0),
                          band_fraction(np.abs(d), dv, LANE_M - 0.06, LANE_M + 0.06))
        grey = 0.27 + 0.025 * rng.standard_normal(len(s))
        if patches:
            cover, dark = _patch_cover(s, d, ds, dv, patches)
            grey = grey * (1 - cover) + dark * cover
        albedo = (grey * (1 - mark) + 0.82 * mark)[:, None] * np.array([1.0, 1.0, 1.03])
        puddle = np.zeros(len(s))
        for ps, pd, hl, hw in puddles:
            r2 = ((s - ps) / hl) ** 2 + ((d - pd) / hw) ** 2
            puddle = np.maximum(puddle, np.clip((1.0 - r2) * 3.0, 0.0, 1.0))
        # snow settles where wheels do not pass: tyre tracks of both lanes stay darker
        in_track = np.exp(-0.5 * ((d[:, None] - tracks) / 0.3) ** 2).max(axis=1) * (np.abs(d) < LANE_M)
        snow = np.clip(0.9 - 0.65 * in_track + 0.05 * rng.standard_normal(len(s)), 0.0, 1.0)
        m = rain
        clouds.append(Cloud.make(
            street.point(s, d, 0.0), quat_from_matrices(street.frame(s)),
            np.stack([np.full(len(s), SIGMA_OF_SPACING * ds), np.full(len(s), SIGMA_OF_SPACING * dv),
                      np.full(len(s), THIN_M)], -1),
            albedo, snow=snow, wet=m["asphalt_wet"] + (m["puddle_wet"] - m["asphalt_wet"]) * puddle,
            sheen=m["asphalt_sheen"] + (m["puddle_sheen"] - m["asphalt_sheen"]) * puddle))
        for side in (-1.0, 1.0):
            # sidewalk: concrete slabs with joints, reaching under the facades
            half_w = (SIDEWALK_M + 0.4) / 2
            u, v, ds, dv = cell_grid((s1 - s0) / 2, half_w, GROUND_STRETCH * dd, dd)
            s, d = sm + u, side * (ROAD_HALF_M + half_w + v)
            joints = 1.0 - ((1.0 - pulse_fraction(s, ds, 1.5, 0.0, 0.04))
                            * (1.0 - pulse_fraction(np.abs(d), dv, 1.5, 0.0, 0.04)))
            grey = 0.56 + 0.02 * rng.standard_normal(len(s)) - 0.12 * joints
            clouds.append(Cloud.make(
                street.point(s, d, CURB_M), quat_from_matrices(street.frame(s)),
                np.array([SIGMA_OF_SPACING * ds, SIGMA_OF_SPACING * dv, THIN_M]),
                grey[:, None] * np.array([1.0, 0.99, 0.96]), snow=0.95, wet=0.7, sheen=0.15))
            # curb face, towards the road: columns tangent, up, normal (right-handed on the left side;
            # on the right side the in-plane axes swap to stay right-handed)
            u, v, ds, dz = cell_grid((s1 - s0) / 2, CURB_M / 2, dd, CURB_M / 2)
            s = sm + u
            F = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -side], [0.0, 1.0, 0.0]])
            sigma = np.array([SIGMA_OF_SPACING * ds, SIGMA_OF_SPACING * dz, THIN_M])
            if side < 0:
                F[:, [0, 1]], sigma[[0, 1]] = F[:, [1, 0]], sigma[[1, 0]]
            clouds.append(Cloud.make(street.point(s, side * ROAD_HALF_M, CURB_M / 2 + v),
                                      quat_from_matrices(street.frame(s) @ F), sigma, np.array([0.62, 0.62, 0.6]),
                                      snow=0.0, wet=0.75))
    return Cloud.concat(clouds)


def _windows(face: str, local: np.ndarray, cell: np.ndarray, height: float) -> np.ndarray:
    """Share [M] of window glass of a facade's Gaussians: a shop-window ground floor and window rows
    above (box-filtered over each Gaussian's cell)."""
    axis = 0 if face[1] == "y" else 1  # the horizontal axis of the face
    along, cell_along = local[:, axis], float(cell[axis])
    z, cell_z = local[:, 2] + height / 2, float(cell[2])
    upper = (pulse_fraction(along, cell_along, 2.6, 0.7, 1.2) * pulse_fraction(z - 3.6, cell_z, 3.1, 0.9, 1.4)
             * (z > 3.6))
    shop = pulse_fraction(along, cell_along, 3.2, 0.4, 2.3) * band_fraction(z, cell_z, 0.5, 2.9)
    return np.clip(upper + shop, 0.0, 1.0)


def _facade_albedo(base: np.ndarray, height: float, block: int) -> AlbedoFn:
    """Facade colour: ``base`` with a shop-window ground floor, window rows above, a cornice band."""

    def albedo(face: str, local: np.ndarray, cell: np.ndarray) -> np.ndarray:
        along = local[:, 0 if face[1] == "y" else 1]  # along the horizontal axis of the face
        z, cell_z = local[:, 2] + height / 2, float(cell[2])
        win = _windows(face, local, cell, height)
        col = np.floor((along - 0.7) / 2.6)
        row = np.floor((z - 3.6) / 3.1)
        h = hash01(np.full(len(z), block), col, row)
        glass = _GLASS + 0.08 * h[:, None] + np.where(h > 0.85, 0.3, 0.0)[:, None] * np.array([1.0, 0.9, 0.7])
        cornice = band_fraction(z, cell_z, height - 0.5, height) * 0.2
        wall = base * (1.0 - cornice[:, None]) * (1.0 + 0.03 * np.sin(1.3 * along + 0.7 * z))[:, None]
        return wall * (1.0 - win[:, None]) + glass * win[:, None]

    return albedo


def _facade_glass(height: float) -> GlassFn:
    """The window glass of a facade of ``height`` (m) (:func:`_windows`)."""
    return lambda face, local, cell: _windows(face, local, cell, height)


def _buildings(street: Street, cameras: np.ndarray, rng: np.random.Generator, profile: Profile
               ) -> tuple[Cloud, Boxes, dict[str, Any] | None]:
    """Continuous rows of building blocks on both sides and one across the street's end; block
    heights from the ``profile``, and its white-painted block on the right (returned: s range (m),
    side, albedo; ``None`` without one)."""
    clouds, boxes = [], []
    white = None
    block = 0
    for side in (-1.0, 1.0):
        heights: list[tuple[float, float, float]] = []  # (s0, length, height)
        s = STREET_START_M - 8.0
        while s < STREET_END_M - 1e-6:
            length = float(rng.uniform(10.0, 24.0))
            if STREET_END_M - s - length < 6.0:  # no sliver of a block at the end
                length = STREET_END_M - s
            heights.append((s, length, float(rng.uniform(*profile.building_height_m[0 if side < 0 else 1]))))
            s += length
        for n, (s0, length, height) in enumerate(heights):
            depth = 12.0
            sc = s0 + length / 2
            R = street.frame(sc)
            center = street.point(sc, side * (BUILDING_LINE_M + depth / 2), height / 2)
            half = np.array([length / 2, depth / 2, height / 2])
            base = _FACADE_PALETTE[rng.integers(len(_FACADE_PALETTE))] * rng.uniform(0.9, 1.05)
            if side < 0 and profile.white_facade_s is not None and s0 <= profile.white_facade_s < s0 + length:
                base = _WHITE_PAINT
                white = {"side": "right", "s_m": [s0, s0 + length], "height_m": height,
                         "albedo_srgb": _WHITE_PAINT.tolist()}
            albedo = _facade_albedo(base, height, block)
            front = street.point(sc, side * BUILDING_LINE_M, height / 2)
            spacing = _spacing(_distance(front, cameras, length / 2), 0.25, 1.8)
            clouds.append(box_surface(center, R, half, ("-y" if side > 0 else "+y",), spacing, albedo,
                               stretch_x=FACADE_STRETCH, glass=_facade_glass(height), wet=0.88))
            # the part of a side wall that rises above the neighbouring block
            for nb, face in ((n - 1, "-x"), (n + 1, "+x")):
                lower = heights[nb][2] if 0 <= nb < len(heights) else 0.0
                if lower >= height:
                    continue
                part_half = np.array([half[0], half[1], (height - lower) / 2])
                part_center = center + R[:, 2] * (lower + part_half[2] - height / 2)
                clouds.append(box_surface(part_center, R, part_half, (face,), spacing,
                                   _facade_albedo(base, height - lower, block),
                                   glass=_facade_glass(height - lower), wet=0.88))
            boxes.append((center, R, half, 0.2, 0, -1))
            block += 1
    # the building that closes the street
    height = 18.0
    R = street.frame(STREET_END_M)
    half = np.array([6.0, BUILDING_LINE_M + 14.0, height / 2])
    center = street.point(STREET_END_M + half[0], 0.0, height / 2)
    base = _FACADE_PALETTE[rng.integers(len(_FACADE_PALETTE))]
    spacing = _spacing(_distance(street.point(STREET_END_M, 0.0, 5.0), cameras, 0.0), 0.22, 1.8)
    clouds.append(box_surface(center, R, half, ("-x",), spacing, _facade_albedo(base, height, block),
                              glass=_facade_glass(height), wet=0.88))
    boxes.append((center, R, half, 0.2, 0, -1))
    return Cloud.concat(clouds), Boxes.of(boxes), white


def _trees(street: Street, cameras: np.ndarray, rng: np.random.Generator) -> tuple[Cloud, Boxes, np.ndarray]:
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
            clouds.append(Cloud.make(top + radius[:, None] * normal, quat_from_matrices(frames),
                                      np.array([sigma, sigma, 0.03]), green * shade,
                                      snow=np.clip(0.85 + 0.1 * rng.standard_normal(n), 0, 1), wet=0.8, sheen=0.1))
            spheres.append([*top, r])
            trunk_h = hc - 0.6 * r
            R = street.frame(s)
            center = street.point(s, d, CURB_M + trunk_h / 2)
            half = np.array([0.14, 0.14, trunk_h / 2])
            clouds.append(box_surface(center, R, half, ("+x", "-x", "+y", "-y"), 0.14,
                               solid_albedo([0.30, 0.22, 0.15]), snow=0.0, wet=0.7))
            boxes.append((center, R, half, 0.15, 0, -1))
            s += float(rng.uniform(11.0, 17.0))
    return Cloud.concat(clouds), Boxes.of(boxes), np.array(spheres, np.float64).reshape(-1, 4)


CAR_SIZE = np.array([4.5, 1.85, 1.5])  # length, width, height (m)


def _car(color: np.ndarray, spacing: float, snow: float) -> tuple[Cloud, list[Part]]:
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
        lamp = band_fraction(y, du, 0.5, 0.8) * band_fraction(z, dv, 0.02, 0.2)
        if face == "+x":
            out = out * (1 - lamp[:, None]) + np.array([0.95, 0.95, 0.85]) * lamp[:, None]
            grille = band_fraction(y, du, 0.0, 0.4) * band_fraction(z, dv, -0.05, 0.15)
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
        pillar = band_fraction(np.abs(along), du, cab_h[0] - 0.12, cab_h[0]) if face[1] == "y" else 0.0 * z
        frame = np.maximum(pillar, band_fraction(z, dv, -cab_h[2], -cab_h[2] + 0.08))
        return _GLASS * (1 - frame[:, None]) + color * frame[:, None]

    parts = [box_surface(body_c, eye, body_h, ("+x", "-x", "+y", "-y", "+z"), spacing, body, snow=snow, wet=0.9,
                  sheen=0.5),
             box_surface(cab_c, eye, cab_h, ("+x", "-x", "+y", "-y", "+z"), spacing, cabin, snow=snow, wet=0.9,
                  sheen=0.6)]
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            c = np.array([sx * 1.45, sy * (w / 2 - 0.12), ground + 0.32])
            parts.append(box_surface(c, eye, np.array([0.32, 0.12, 0.32]), ("+x", "-x", "+y", "-y"), min(spacing, 0.1),
                              solid_albedo([0.05, 0.05, 0.05]), snow=0.0, wet=0.95))
    return Cloud.concat(parts), [(body_c, eye, body_h), (cab_c, eye, cab_h)]


def _pedestrian(shirt: np.ndarray, trousers: np.ndarray, skin: np.ndarray, cadence_hz: float, *,
                rigid_limbs: bool = False) -> Callable[[float], tuple[Cloud, list[Part]]]:
    """A walking person in its box frame (0.9 x 0.7 x 1.8 m, centre of the box, x forward): legs and
    arms swing about the hips and shoulders at ``cadence_hz`` strides per second.

    With ``rigid_limbs`` each limb's Gaussians are laid out once in the limb's frame and moved
    rigidly every frame (4x faster); without, they are laid out again in place every frame, as
    v1's pedestrians are (the same Gaussians up to rounding, which v1's bytes keep).
    """
    ground = -0.9
    limbs: list[Cloud] = []

    def at(t: float) -> tuple[Cloud, list[Part]]:
        swing = 0.42 * math.sin(2 * math.pi * cadence_hz * t)
        parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]] = []
        for side, phase in ((1.0, 1.0), (-1.0, -1.0)):
            R = rot_y(phase * swing)
            hip = np.array([0.0, side * 0.1, ground + 0.88])
            parts.append((hip + R @ np.array([0.0, 0.0, -0.44]), R, np.array([0.08, 0.08, 0.44]), trousers, 0.0))
            R = rot_y(-0.7 * phase * swing)
            shoulder = np.array([0.0, side * 0.27, ground + 1.45])
            parts.append((shoulder + R @ np.array([0.0, 0.0, -0.3]), R, np.array([0.05, 0.05, 0.3]), shirt, 0.0))
        parts.append((np.array([0.0, 0.0, ground + 1.19]), np.eye(3), np.array([0.13, 0.21, 0.31]), shirt, 0.0))
        parts.append((np.array([0.0, 0.0, ground + 1.64]), np.eye(3), np.array([0.1, 0.09, 0.12]), skin, 0.0))
        faces = ("+x", "-x", "+y", "-y", "+z", "-z")
        if not rigid_limbs:
            clouds = [box_surface(c, R, h, faces, 0.045, solid_albedo(col), snow=s, wet=0.9)
                      for c, R, h, col, s in parts]
        else:
            if not limbs:
                limbs.extend(box_surface(np.zeros(3), np.eye(3), h, faces, 0.045, solid_albedo(col), snow=s, wet=0.9)
                             for _, _, h, col, s in parts)
            clouds = [limb.posed(rigid_transform(R, c)) for limb, (c, R, _, _, _) in zip(limbs, parts)]
        return Cloud.concat(clouds), [(c, R, h) for c, R, h, _, _ in parts]

    return at


def _street_pose(street: Street, s: float, d: float, z: float, reverse: bool = False) -> np.ndarray:
    """[4, 4] pose at street coordinates, x along the street (against it when ``reverse``)."""
    R = street.frame(s)
    if reverse:
        R = R @ rot_z(math.pi)
    return rigid_transform(R, street.point(s, d, z))


def _road_patches(rng: np.random.Generator, count: int) -> list[dict[str, Any]]:
    """``count`` dark road patches ahead of the camera, half tar repairs (rectangles: a trench across
    a lane or a sealed strip along it), half oil stains (ellipses between a lane's tyre tracks).

    Returns
    -------
    list of dict
        ``kind``, ``shape``, centre ``s``, ``d``, ``half_length`` (along the street), ``half_width``
        (m) and ``albedo`` (sRGB grey).
    """
    out = []
    for n in range(count):
        lane = (-1.0, 1.0)[n % 2] * LANE_M / 2
        s = float(rng.uniform(12.0, 70.0))
        if n < (count + 1) // 2:
            across = bool(rng.random() < 0.5)
            hl, hw = (float(rng.uniform(0.5, 0.9)), LANE_M / 2 - 0.2) if across else (float(rng.uniform(3.0, 6.0)),
                                                                                      float(rng.uniform(0.3, 0.6)))
            out.append({"kind": "tar repair", "shape": "rectangle", "s": s,
                        "d": lane + (0.0 if across else float(rng.uniform(-0.8, 0.8))), "half_length": hl,
                        "half_width": hw, "albedo": _TAR})
        else:
            out.append({"kind": "oil stain", "shape": "ellipse", "s": s, "d": lane + float(rng.uniform(-0.3, 0.3)),
                        "half_length": float(rng.uniform(0.6, 1.1)), "half_width": float(rng.uniform(0.4, 0.6)),
                        "albedo": _OIL})
    return out


def _walker_track(kind: str, street: Street, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses [F, 4, 4] and arc lengths [F] (m) of a pedestrian walking ``kind``.

    ``"right"``: along the right sidewalk at 1.4 m/s from 30 m; ``"left"``: towards the camera on
    the left sidewalk at 1.3 m/s from 45 m; ``"crossing"``: across the road at 55 m, from the left
    sidewalk towards the right at 1.3 m/s, stepping down the curb.
    """
    if kind == "crossing":
        d = ROAD_HALF_M + 1.6 - 1.3 * times
        step = np.clip((np.abs(d) - ROAD_HALF_M + 0.2) / 0.4, 0.0, 1.0)
        z = 0.9 + CURB_M * step * step * (3.0 - 2.0 * step)
        s = np.full(len(times), 55.0)
        poses = np.array([rigid_transform(street.frame(si) @ rot_z(-math.pi / 2), street.point(si, di, zi))
                          for si, di, zi in zip(s, d, z)])
        return poses, s
    side = {"right": -1.0, "left": 1.0}[kind]
    s = (30.0 + 1.4 * times) if side < 0 else (45.0 - 1.3 * times)
    lateral = side * (ROAD_HALF_M + 1.9)
    return np.array([_street_pose(street, si, lateral, CURB_M + 0.9, side > 0) for si in s]), s


def _sight_line_clear(kind: str, street: Street, times: np.ndarray) -> tuple[float, float, float]:
    """Where no car may park so that the camera sees the pedestrian ``kind``: (side, s from, s to)."""
    if kind == "crossing":
        return 1.0, 55.0 - 4.0, 55.0 + 4.0
    side = {"right": -1.0, "left": 1.0}[kind]
    _, s_ped = _walker_track(kind, street, times)
    d_ped = side * (ROAD_HALF_M + 1.9)
    # where the sight lines from the camera cross the parking lane
    s_cam = SPEED * times + CAMERA_MOUNT_M[0]
    d_park = side * (LANE_M + PARKING_M / 2)
    cross = s_cam + (s_ped - s_cam) * (d_park - EGO_LATERAL_M) / (d_ped - EGO_LATERAL_M)
    return side, float(cross.min()) - 3.0, float(s_ped.max()) + 3.0


def build_content(spec: SynthSpec) -> Content:
    """Lay out scene ``spec``: all static Gaussians, lidar boxes and the moving objects' tracks.

    Parameters
    ----------
    spec : SynthSpec

    Returns
    -------
    Content
        In street coordinates (m, z up, road surface at z = 0); a pure function of ``spec``.
    """
    profile = spec.profile
    rng = np.random.default_rng(spec.seed)
    street = Street(spec.curvature)
    times = np.arange(N_FRAMES) / FPS
    ego = np.array([_street_pose(street, SPEED * t, EGO_LATERAL_M, 0.0) for t in times])
    cam_to_vehicle = _camera_to_vehicle()
    cameras = np.array([(ego[k] @ cam_to_vehicle)[:3, 3] for k in (0, 10, 20, N_FRAMES - 1)])
    # puddles (s, d, half-length, half-width; m): along the gutters and in both lanes
    puddles = np.array([[rng.uniform(8.0, 70.0), side * rng.uniform(3.3, 4.2), rng.uniform(3.0, 6.0),
                         rng.uniform(0.6, 1.0)] for side in (-1.0, -1.0, 1.0, 1.0)] +
                       [[rng.uniform(12.0, 50.0), lane * LANE_M / 2 + rng.uniform(-0.6, 0.6), rng.uniform(2.5, 5.0),
                         rng.uniform(0.8, 1.4)] for lane in (-1.0, -1.0, 1.0)])
    # what v1 has not draws from streams of its own, so v1's stream (and its scenes) stay as they were
    patches = _road_patches(np.random.default_rng([spec.seed, 1]), profile.road_patches)
    rain = MATERIALS_V1["rain"] if profile.sun is None else physical_materials()["rain"]
    # a moving car holds a share of a parked one's snow: v1's frozen half, the editor's table's for the others
    mover_snow = 0.5 if profile.sun is None else float(physical_materials()["snow"]["mover_share"])
    ground = _ground(street, cameras, rng, puddles, rain, patches)
    buildings, building_boxes, white = _buildings(street, cameras, rng, profile)
    trees, trunk_boxes, spheres = _trees(street, cameras, rng)
    clouds = [ground, buildings, trees]
    boxes = [building_boxes, trunk_boxes]
    movers: list[Mover] = []

    def add_static_car(s: float, side: float, n: int) -> None:
        pose = _street_pose(street, s, side * (LANE_M + PARKING_M / 2), CAR_SIZE[2] / 2, reverse=side > 0)
        spacing = _spacing(_distance(pose[:3, 3], cameras, 2.3), 0.12, 0.6)
        cloud, parts = _car(_CAR_PALETTE[rng.integers(len(_CAR_PALETTE))] * rng.uniform(0.9, 1.05), spacing, 1.0)
        clouds.append(cloud.posed(pose))
        boxes.append(Boxes.of([(pose[:3, :3] @ c + pose[:3, 3], pose[:3, :3] @ R, h, 0.3, 1, -1)
                                for c, R, h in parts]))
        movers.append(Mover(f"parked_{n}", "Vehicle", CAR_SIZE.copy(), np.repeat(pose[None], N_FRAMES, 0),
                             np.zeros((N_FRAMES, 3)), lambda k: (cloud, parts), moving=False))

    # no parked car between the camera and a pedestrian on a sidewalk, nor where one crosses
    keep_clear = [_sight_line_clear(kind, street, times)
                  for kind in ((spec.pedestrian,) if spec.pedestrian else ()) + spec.walkers]
    n_parked = 0
    for side in (-1.0, 1.0):
        s = float(rng.uniform(6.0, 14.0))
        while s < 85.0:
            if rng.random() < 0.6 and not any(side == cs and lo < s < hi for cs, lo, hi in keep_clear):
                add_static_car(s, side, n_parked)
                n_parked += 1
            s += float(rng.uniform(6.5, 12.0))

    def add_car(kind: str, tracked: bool) -> None:
        if kind == "oncoming":
            s0, speed, d, reverse = float(rng.uniform(50.0, 65.0)), -9.0, LANE_M / 2, True
        elif kind == "lead":
            s0, speed, d, reverse = float(rng.uniform(17.0, 21.0)), 6.5, EGO_LATERAL_M, False
        else:
            raise ValueError(f"unknown mover {kind!r}")
        poses = np.array([_street_pose(street, s0 + speed * t, d, CAR_SIZE[2] / 2, reverse) for t in times])
        spacing = _spacing(_distance(poses[:, :3, 3], cameras, 2.3), 0.12, 0.3)
        cloud, parts = _car(_CAR_PALETTE[rng.integers(len(_CAR_PALETTE))], spacing, mover_snow)
        velocity = np.gradient(poses[:, :3, 3], times, axis=0)
        movers.append(Mover(f"car_{kind}" if tracked else f"car_{kind}_untracked", "Vehicle", CAR_SIZE.copy(), poses,
                             velocity, (lambda c, p: lambda k: (c, p))(cloud, parts), tracked=tracked))

    def add_walker(kind: str, name: str, tracked: bool, rigid_limbs: bool) -> None:
        poses, _ = _walker_track(kind, street, times)
        shirt = np.array([[0.7, 0.15, 0.12], [0.15, 0.35, 0.6], [0.85, 0.75, 0.2], [0.2, 0.5, 0.3]])[
            rng.integers(4)]
        trousers = np.array([[0.1, 0.12, 0.2], [0.08, 0.08, 0.08], [0.5, 0.45, 0.35]])[rng.integers(3)]
        skin = np.array([[0.8, 0.62, 0.5], [0.55, 0.4, 0.3], [0.35, 0.25, 0.2]])[rng.integers(3)]
        walk = _pedestrian(shirt, trousers, skin, cadence_hz=1.0, rigid_limbs=rigid_limbs)
        velocity = np.gradient(poses[:, :3, 3], times, axis=0)
        # a frame's lidar, shadows and render each ask for the walker's parts: built once per frame
        parts = functools.lru_cache(maxsize=2)(lambda k: walk(k / FPS))
        movers.append(Mover(name, "Pedestrian", np.array([0.9, 0.7, 1.8]), poses, velocity, parts,
                            tracked=tracked))

    for kind in spec.movers:
        add_car(kind, tracked=True)
    if spec.pedestrian is not None:
        add_walker(spec.pedestrian, "pedestrian_0", tracked=True, rigid_limbs=False)
    for kind in spec.untracked:
        add_car(kind, tracked=False)
    for n, kind in enumerate(spec.walkers):
        add_walker(kind, f"pedestrian_{kind}_{n}_untracked", tracked=False, rigid_limbs=True)

    return Content(spec=spec, street=street, static=Cloud.concat(clouds), boxes=Boxes.concat(boxes),
                    spheres=spheres, movers=movers, ego=ego, camera_to_vehicle=cam_to_vehicle, puddles=puddles,
                    road_patches=patches, white_facade=white)


def cloud_at(content: Content, k: int) -> Cloud:
    """Static and moving Gaussians of frame ``k`` (street coordinates)."""
    parts = [content.static]
    for m in content.movers:
        if m.moving:
            parts.append(m.parts(k)[0].posed(m.poses[k]))
    return Cloud.concat(parts)


def boxes_at(content: Content, k: int) -> Boxes:
    """Lidar boxes of frame ``k``: the static ones and the moving objects' parts, posed."""
    items = []
    for i, m in enumerate(content.movers):
        if not m.moving:
            continue
        T = m.poses[k]
        flow = 2 if m.class_name == "Pedestrian" else 1
        items += [(T[:3, :3] @ c + T[:3, 3], T[:3, :3] @ R, h, 0.3, flow, i) for c, R, h in m.parts(k)[1]]
    return Boxes.concat([content.boxes, Boxes.of(items)])
