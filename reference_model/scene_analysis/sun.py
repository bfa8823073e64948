"""Where the sun of the clear frames came from, and what it lit: cast shadows from the scene's 3D.

A clear frame is lit by the sky and, where nothing stands between a surface and the sun, by the
sun. An overcast sky has no sun: to turn the frame overcast, shadowed and sunlit pixels must be
relit to one illumination (:mod:`wcbench.reference_model.appearance`). :func:`fit_sun` finds the
sun from the sequence (docs/design.md §7, "Cast shadows"):

* **occluders**: the static scene's returns higher than 0.3 m above the local ground, and the
  structure above the lidar's reach (walls rising from the topmost returns to the sky line of
  the frames, :func:`completed_structure`), in 0.25 m voxels;
* **receivers**: static ground returns (within 0.15 m of the local ground) within 40 m of their
  own frame's camera, with the linear luminance of the pixel they project to in that frame;
* **shadow mapping** (Williams 1978, "Casting curved shadows on curved surfaces", SIGGRAPH): for
  a candidate direction s, the occluders are projected orthographically along s onto a grid of
  0.25 m cells (a 3 x 3 maximum filter closes the gaps between returns), each cell keeping the
  largest s-coordinate; a receiver is in shadow when its cell holds an occluder more than 0.5 m
  nearer the sun;
* **the fit**: the direction whose lit and shadowed receivers differ most in mean log luminance,
  as a t statistic (elevations 4-76 degrees, azimuths all round; a 6 x 6 degree grid, then 1
  degree around the best). A sun is found when t >= 8, each side holds at least 5 % of the
  receivers and the lit side at least 20 % (a few lit receivers brighter than the rest are as often
  a brighter material as a sun: on ``synth_1``, whose clear frames have no cast shadow, the best
  direction lit 7 %, and relighting by it cost the editor 3.5 dB of rain and 3.4 of fog against the
  truth on three frames: docs/findings.md), the lit ones are at least
  1.6x brighter in the median, and warmer: the lit-to-shadow
  ratio of the median linear colours falls from red to green to blue, red at least 1.15x blue
  (the sun is warmer than the sky that alone lights a shadow, Finlayson, Hordley, Lu & Drew 2006,
  "On the removal of shadows from images", TPAMI). Otherwise the frames show no cast shadow to
  remove (an overcast source, or a street all in shade: a darker patch that is as blue as its
  surroundings is shade or a darker material, not a shadow of the sun), and the direction the
  best fit found is recorded with the reason it was refused;
* **the faces choose the sun or its mirror image**: the ground's shadows can be explained as well
  by the sun's mirror image front to back (same elevation, azimuth 180 - a), whose occluders
  (walls behind the cameras, above the lidar) the cameras never saw: on ``synth_hard_1`` the ground
  fits (32, 31) degrees, the truth's sun is (28, 155) (docs/findings.md). The static returns more
  than 0.5 m above the ground (facades, poles, crowns; PCA normals turned toward the camera that
  saw them) are lit only where they face the sun: with the same t statistic, a face counts as lit
  when its normal is turned toward the direction (cosine over 0.2) and the map has no occluder
  over it, tested 0.5 m off its surface (it is an occluder too: at a grazing sun a wall shadows
  itself through the map's cells). When the mirror image scores at least 8 higher (and at least
  8), it is the sun that lights the surfaces, and the ground fit's direction, whose occluders the
  map holds, keeps casting the ground's shadows (:attr:`SunEstimate.ground_direction`).

The per-channel ratio of the lit to the shadowed receivers' median linear colour gives the sun's
direct light over the sky's on the ground (Guo, Dai & Hoiem 2013, "Paired regions for shadow
detection and removal", TPAMI: the shadow-free value is (r + 1) / (r v + 1) times the observed
one, v the sun's visibility); :class:`ShadowMap` gives the visibility of any point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from scipy.spatial import cKDTree

from wcbench.reference_model.scene_analysis.motion import LidarReturns
from wcbench.reference_model.scene_analysis.normals import pca_normals
from wcbench.reference_model.scene_analysis.views import AnalysisViews, pixel_indices
from wcbench.reference_model.scene_graph.completion import FILL_WALL, complete_distance, ground_height_below

__all__ = ["GroundGrid", "ShadowMap", "SunEstimate", "completed_structure", "fit_sun", "sun_direction"]

#: Voxel and shadow-map cell (m); an occluder must lie this much nearer the sun than its receiver (m).
_CELL_M, _MARGIN_M = 0.25, 0.5
#: Occluders stand this high above the local ground (m); receivers lie within this of it (m), and
#: within this distance of their frame's camera (m).
_OCCLUDER_HEIGHT_M, _RECEIVER_HEIGHT_M, _RECEIVER_RANGE_M = 0.3, 0.15, 40.0
#: Acceptance of a fit: t statistic, median luminance ratio, smallest side, and how much warmer the
#: lit ground must be than the shadowed ground (red over blue of their ratio).
_MIN_T, _MIN_RATIO, _MIN_SIDE, _MIN_WARMTH = 8.0, 1.6, 0.05, 1.15
#: The least share of the receivers a sun's direction lights (see the module docstring).
_MIN_LIT = 0.2
#: Search: elevations (degrees), coarse step and fine half-width (degrees).
_ELEVATIONS = (4.0, 76.0)
_COARSE_DEG, _FINE_DEG = 6.0, 5.0
#: Receivers and occluders used by the search (subsampled, seeded).
_MAX_RECEIVERS, _MAX_OCCLUDERS = 20000, 150000
#: Faces: static returns this high above the local ground (m), their normals from the returns in
#: voxels of this size (m); lit when their normal's cosine with the sun is over this and the map
#: has no occluder over them tested this far off their surface (m, times the sine of the sun's
#: incidence: normal-offset shadows).
_FACE_ABOVE_M, _FACE_VOXEL_M, _FACE_MIN_COS, _FACE_OFFSET_M = 0.5, 0.1, 0.2, 0.5
#: How much higher the faces' t must be at the mirror image for it to light the surfaces.
_MIRROR_MARGIN_T = 8.0


def sun_direction(up: np.ndarray, heading: np.ndarray, elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """[3] unit vector toward the sun at ``elevation_deg`` above the horizontal and ``azimuth_deg``
    counter-clockwise (about ``up``) from ``heading``'s horizontal part."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    e1 = np.asarray(heading, np.float64) - (np.asarray(heading, np.float64) @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return math.cos(el) * (math.cos(az) * e1 + math.sin(az) * e2) + math.sin(el) * up


@dataclass
class GroundGrid:
    """The local ground height: the 5th percentile of the returns' heights (along ``up``) per 2 m
    cell of the horizontal plane; a cell without returns takes the nearest cell's."""

    up: np.ndarray
    axes: np.ndarray
    origin: np.ndarray
    heights: np.ndarray
    cell_m: float = 2.0

    @classmethod
    def of(cls, points: np.ndarray, up: np.ndarray, cell_m: float = 2.0) -> GroundGrid:
        """The grid of ``points`` [N, 3] (world, m; at least one)."""
        up = np.asarray(up, np.float64) / np.linalg.norm(up)
        a = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(up, a)
        e1 /= np.linalg.norm(e1)
        axes = np.stack([e1, np.cross(up, e1)])
        xy = points @ axes.T
        origin = xy.min(axis=0)
        ij = np.floor((xy - origin) / cell_m).astype(np.int64)
        shape = tuple(ij.max(axis=0) + 1)
        h = points @ up
        key = ij[:, 0] * shape[1] + ij[:, 1]
        order = np.lexsort((h, key))
        key_s, h_s = key[order], h[order]
        starts = np.flatnonzero(np.r_[True, key_s[1:] != key_s[:-1]])
        counts = np.diff(np.r_[starts, len(key_s)])
        low = h_s[starts + (0.05 * (counts - 1)).astype(np.int64)]
        grid = np.full(shape, np.nan)
        grid.ravel()[key_s[starts]] = low
        if np.isnan(grid).any():  # empty cells: the nearest filled cell's height
            from scipy.ndimage import distance_transform_edt

            _, (ii, jj) = distance_transform_edt(np.isnan(grid), return_indices=True)
            grid = grid[ii, jj]
        return cls(up=up, axes=axes, origin=origin, heights=grid, cell_m=cell_m)

    def height(self, points: np.ndarray) -> np.ndarray:
        """[N] ground height below ``points`` [N, 3] (m along ``up``)."""
        ij = np.floor((np.asarray(points, np.float64) @ self.axes.T - self.origin) / self.cell_m).astype(np.int64)
        ij[:, 0] = np.clip(ij[:, 0], 0, self.heights.shape[0] - 1)
        ij[:, 1] = np.clip(ij[:, 1], 0, self.heights.shape[1] - 1)
        return self.heights[ij[:, 0], ij[:, 1]]


class ShadowMap:
    """An orthographic depth map of occluders along the sun direction (see the module docstring).

    Parameters
    ----------
    occluders : ndarray [N, 3]
        World points (m) that cast shadows.
    direction : ndarray [3]
        Unit vector toward the sun.
    cell_m : float
        Grid cell (m) perpendicular to the sun.
    """

    def __init__(self, occluders: np.ndarray, direction: np.ndarray, *, cell_m: float = _CELL_M):
        s = np.asarray(direction, np.float64)
        self.direction = s / np.linalg.norm(s)
        a = np.array([1.0, 0.0, 0.0]) if abs(self.direction[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(self.direction, a)
        u /= np.linalg.norm(u)
        self.basis = np.stack([u, np.cross(self.direction, u)])
        self.cell_m = float(cell_m)
        occ = np.asarray(occluders, np.float64).reshape(-1, 3)
        if len(occ) == 0:
            self.origin, self.grid = np.zeros(2), np.full((1, 1), -np.inf, np.float32)
            return
        uv = occ @ self.basis.T
        self.origin = uv.min(axis=0) - 2 * self.cell_m
        ij = np.floor((uv - self.origin) / self.cell_m).astype(np.int64)
        shape = tuple(ij.max(axis=0) + 3)
        depth = np.full(shape[0] * shape[1], -np.inf)
        np.maximum.at(depth, ij[:, 0] * shape[1] + ij[:, 1], occ @ self.direction)
        # the gaps between returns closed: a 3 x 3 maximum
        self.grid = cv2.dilate(depth.reshape(shape).astype(np.float32), np.ones((3, 3), np.uint8))

    def lit_off_surface(self, points: np.ndarray, normals: np.ndarray, *, offset_m: float = _FACE_OFFSET_M
                        ) -> np.ndarray:
        """[N] bool: :meth:`lit` of ``points`` [N, 3] moved off their surface along their unit
        ``normals`` [N, 3] by ``offset_m`` times the sine of the sun's incidence (normal-offset
        shadows: a surface the sun grazes does not shadow itself through the map's cells)."""
        n = np.asarray(normals, np.float64).reshape(-1, 3)
        cos = np.clip(n @ self.direction, 0.0, 1.0)
        moved = np.asarray(points, np.float64).reshape(-1, 3) + n * (offset_m * np.sqrt(1.0 - cos * cos))[:, None]
        return self.lit(moved)

    def lit(self, points: np.ndarray, *, margin_m: float = _MARGIN_M) -> np.ndarray:
        """[N] bool: whether the sun reaches ``points`` [N, 3] (no occluder more than ``margin_m``
        nearer the sun in their cell)."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        ij = np.floor((p @ self.basis.T - self.origin) / self.cell_m).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < self.grid.shape[0]) & (ij[:, 1] >= 0) & (ij[:, 1] < self.grid.shape[1])
        top = np.full(len(p), -np.inf)
        top[inside] = self.grid[ij[inside, 0], ij[inside, 1]]
        return ~(top > p @ self.direction + margin_m)


@dataclass
class SunEstimate:
    """What :func:`fit_sun` found.

    Attributes
    ----------
    direction : ndarray [3] or None
        Unit vector toward the sun; ``None`` when no cast shadow is seen.
    elevation_deg, azimuth_deg : float or None
        The same as angles (azimuth counter-clockwise from the first camera's heading).
    direct_to_diffuse : ndarray [3]
        Per channel, the sun's light over the sky's on a horizontal surface (lit / shadowed - 1
        of the receivers' median linear colours); zeros without a sun.
    occluders : ndarray [M, 3]
        What casts the shadows (voxel centres, m).
    facts : dict
    ground_direction : ndarray [3] or None
        The direction whose shadow map casts the ground's shadows where the faces found the sun at
        the ground fit's mirror image (see the module docstring); ``None``: ``direction``.
    """

    direction: np.ndarray | None
    elevation_deg: float | None
    azimuth_deg: float | None
    direct_to_diffuse: np.ndarray
    occluders: np.ndarray
    facts: dict[str, Any] = field(default_factory=dict)
    ground_direction: np.ndarray | None = None

    def shadow_map(self, extra: np.ndarray | None = None, *, ground: bool = False) -> ShadowMap | None:
        """The shadow map of the occluders (and ``extra`` ones, e.g. a frame's movers) along the sun,
        or with ``ground`` along :attr:`ground_direction` where there is one; ``None`` without a sun."""
        if self.direction is None:
            return None
        occ = self.occluders if extra is None or not len(extra) else np.concatenate([self.occluders, extra])
        return ShadowMap(occ, self.ground_direction if ground and self.ground_direction is not None
                         else self.direction)


def completed_structure(views: AnalysisViews, returns: LidarReturns, sky: np.ndarray, *, every: int = 3,
                        stride_px: int = 3) -> np.ndarray:
    """[M, 3] points on the structure above the lidar's reach: in every ``every``-th frame, the
    pixels between the topmost return of each column and the sky line (not sky, above the
    horizon), at their completed distance (a vertical wall continuing the nearest return below,
    :func:`~wcbench.reference_model.scene_graph.completion.complete_distance`), every
    ``stride_px`` pixels.

    Parameters
    ----------
    views : AnalysisViews
    returns : LidarReturns
    sky : ndarray [F, H, W] bool
        The frames' sky.
    """
    static = returns.static_points()
    out = []
    for k in range(0, len(views), every):
        u, v, z, ok = pixel_indices(static, views.world_to_camera(k), views.K[k], views.size)
        depth = np.full((views.height, views.width), np.float32(np.inf), np.float32)
        np.minimum.at(depth, (v[ok], u[ok]), z[ok].astype(np.float32))
        depth = cv2.erode(np.where(np.isfinite(depth), depth, 1e9).astype(np.float32), np.ones((3, 3), np.uint8))
        known = depth < 1e8
        rays = views.rays(k).astype(np.float64)
        z_per_m = rays @ views.camera_to_world[k][:3, 2]
        distance = np.where(known, depth / np.maximum(z_per_m, 1e-9), np.inf)
        center = views.center(k)
        # the walls column by column, not smoothed along the frame (complete_distance's guide): a
        # smoothed wall stands between the two surfaces it averages, where nothing casts a shadow
        # (the editor on synth_hard_1 lost 0.1-0.3 dB with it, docs/findings.md)
        filled, kind, _ = complete_distance(distance, known, sky[k], rays, center, views.up,
                                            ground_height_below(static, center, views.up),
                                            forward=views.camera_to_world[k][:3, 2])
        wall = (kind == FILL_WALL) & np.isfinite(filled) & (filled < 150.0)
        sel = np.zeros_like(wall)
        sel[::stride_px, ::stride_px] = wall[::stride_px, ::stride_px]
        rr, cc = np.nonzero(sel)
        out.append(center + rays[rr, cc] * filled[rr, cc, None])
    return np.concatenate(out) if out else np.zeros((0, 3))


def _voxels(points: np.ndarray, cell: float) -> np.ndarray:
    """One point (the first) per occupied voxel of ``cell`` metres."""
    if len(points) == 0:
        return points
    key = np.floor(points / cell).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    return points[np.sort(first)]


def _t_statistic(lit: np.ndarray, log_lum: np.ndarray) -> float:
    """Pooled-variance t statistic of the lit minus the shadowed ``log_lum``; -inf when either side
    holds under :data:`_MIN_SIDE` of them or under two."""
    n1, n0 = int(lit.sum()), int((~lit).sum())
    if min(n1, n0) < max(_MIN_SIDE * len(lit), 2):
        return -np.inf
    a, b = log_lum[lit], log_lum[~lit]
    pooled = ((n1 - 1) * a.var() + (n0 - 1) * b.var()) / max(n1 + n0 - 2, 1)
    return float((a.mean() - b.mean()) / math.sqrt(max(pooled, 1e-12) * (1.0 / n1 + 1.0 / n0)))


def _score(occluders: np.ndarray, receivers: np.ndarray, log_lum: np.ndarray, s: np.ndarray
           ) -> tuple[float, np.ndarray]:
    """(t statistic of lit minus shadowed log luminance, lit mask) for sun direction ``s``."""
    lit = ShadowMap(occluders, s).lit(receivers)
    return _t_statistic(lit, log_lum), lit


def _face_score(occluders: np.ndarray, faces: np.ndarray, normals: np.ndarray, log_lum: np.ndarray,
                s: np.ndarray) -> float:
    """The t statistic of the faces (points [N, 3], unit ``normals`` [N, 3]) lit by a sun along
    ``s``: turned toward it and unshadowed off their surface (see the module docstring)."""
    lit = (normals @ s > _FACE_MIN_COS) & ShadowMap(occluders, s).lit_off_surface(faces, normals)
    return _t_statistic(lit, log_lum)


def _log_luminance(colors: np.ndarray) -> np.ndarray:
    """[N] log of the linear luminance of display-RGB ``colors`` [N, 3] (floored at 1e-4)."""
    lin = np.where(colors <= 0.04045, colors / 12.92, ((colors + 0.055) / 1.055) ** 2.4)
    return np.log(np.maximum(lin @ np.array([0.2126, 0.7152, 0.0722]), 1e-4))


def _faces(views: AnalysisViews, returns: LidarReturns, ground: GroundGrid, static: np.ndarray,
           rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points [N, 3], unit normals [N, 3], log luminance [N]) of the static returns more than
    :data:`_FACE_ABOVE_M` above the ground within :data:`_RECEIVER_RANGE_M` of their frame's camera,
    their normals those of the static returns' voxels nearest them, turned toward that camera
    (at most :data:`_MAX_RECEIVERS`, seeded)."""
    vox = _voxels(static, _FACE_VOXEL_M)
    if len(vox) < 3:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    tree = cKDTree(vox)
    vox_normals = pca_normals(vox)
    pts, nrm, col = [], [], []
    for k, p in sorted(returns.points.items()):
        p = p[returns.static_mask(k)]
        center = views.center(k)
        p = p[(np.linalg.norm(p - center, axis=1) < _RECEIVER_RANGE_M) &
              (p @ ground.up - ground.height(p) > _FACE_ABOVE_M)]
        ij, _, inside = views.project(p, k)
        p, ij = p[inside], ij[inside]
        _, near = tree.query(p, workers=-1)
        n = vox_normals[near]
        n[np.einsum("ij,ij->i", center - p, n) < 0] *= -1.0
        pts.append(p)
        nrm.append(n)
        col.append(views.images[k][ij[:, 1], ij[:, 0]])
    points = np.concatenate(pts) if pts else np.zeros((0, 3))
    normals = np.concatenate(nrm) if nrm else np.zeros((0, 3))
    colors = np.concatenate(col) if col else np.zeros((0, 3), np.float32)
    if len(points) > _MAX_RECEIVERS:
        pick = rng.choice(len(points), _MAX_RECEIVERS, replace=False)
        points, normals, colors = points[pick], normals[pick], colors[pick]
    return points, normals, _log_luminance(colors)


def fit_sun(views: AnalysisViews, returns: LidarReturns, sky: np.ndarray, *, seed: int = 0) -> SunEstimate:
    """The sun of the clear frames (see the module docstring).

    Parameters
    ----------
    views : AnalysisViews
    returns : LidarReturns
    sky : ndarray [F, H, W] bool
        The frames' sky (bounds the structure above the lidar).
    seed : int
        Seeds the subsampling of receivers and occluders.

    Returns
    -------
    SunEstimate
        ``direction`` is ``None`` when the frames show no cast shadow that the scene's 3D explains.
    """
    up = views.up
    static = returns.static_points()
    empty = SunEstimate(None, None, None, np.zeros(3), np.zeros((0, 3)))
    if len(static) < 100:
        empty.facts["sun"] = "none: too few static returns"
        return empty
    ground = GroundGrid.of(static, up)
    rel = static @ up - ground.height(static)
    structure = completed_structure(views, returns, sky)
    occluders = _voxels(np.concatenate([static[rel > _OCCLUDER_HEIGHT_M], structure]), _CELL_M)
    # receivers: static ground returns seen by their own frame's camera, with their pixel's luminance
    rec, col = [], []
    for k, pts in sorted(returns.points.items()):
        keep = returns.static_mask(k)
        p = pts[keep]
        near = (np.abs(p @ up - ground.height(p)) < _RECEIVER_HEIGHT_M) & \
            (np.linalg.norm(p - views.center(k), axis=1) < _RECEIVER_RANGE_M)
        p = p[near]
        ij, _, inside = views.project(p, k)
        rec.append(p[inside])
        col.append(views.images[k][ij[inside, 1], ij[inside, 0]])
    receivers = np.concatenate(rec) if rec else np.zeros((0, 3))
    colors = np.concatenate(col) if col else np.zeros((0, 3), np.float32)
    rng = np.random.default_rng(seed)
    if len(receivers) > _MAX_RECEIVERS:
        pick = rng.choice(len(receivers), _MAX_RECEIVERS, replace=False)
        receivers, colors = receivers[pick], colors[pick]
    occ_search = occluders if len(occluders) <= _MAX_OCCLUDERS else \
        occluders[rng.choice(len(occluders), _MAX_OCCLUDERS, replace=False)]
    facts: dict[str, Any] = {"occluders": len(occluders), "structure_points": len(structure),
                             "receivers": len(receivers)}
    if len(receivers) < 200:
        empty.facts.update(facts, sun="none: too few ground returns to read shadows from")
        return empty
    lin = np.where(colors <= 0.04045, colors / 12.92, ((colors + 0.055) / 1.055) ** 2.4)
    lum = lin @ np.array([0.2126, 0.7152, 0.0722])
    log_lum = _log_luminance(colors)
    heading = views.camera_to_world[0][:3, 2]

    def search(elevations: np.ndarray, azimuths: np.ndarray) -> tuple[float, float, float]:
        best = (-np.inf, 0.0, 0.0)
        for el in elevations:
            for az in azimuths:
                t, _ = _score(occ_search, receivers, log_lum, sun_direction(up, heading, float(el), float(az)))
                if t > best[0]:
                    best = (t, float(el), float(az))
        return best

    t, el, az = search(np.arange(_ELEVATIONS[0], _ELEVATIONS[1] + 1e-9, _COARSE_DEG),
                       np.arange(0.0, 360.0, _COARSE_DEG))
    if np.isfinite(t):
        t, el, az = search(np.clip(np.arange(el - _FINE_DEG, el + _FINE_DEG + 1e-9, 1.0), *_ELEVATIONS),
                           np.arange(az - _FINE_DEG, az + _FINE_DEG + 1e-9, 1.0) % 360.0)
    if not np.isfinite(t):
        empty.facts.update(facts, sun="none: no direction puts both lit and shadowed ground in view")
        return empty
    s = sun_direction(up, heading, el, az)
    lit = ShadowMap(occluders, s).lit(receivers)
    ratio = float(np.median(lum[lit]) / max(np.median(lum[~lit]), 1e-6)) if lit.any() and (~lit).any() else 1.0
    facts.update(t=round(t, 2), elevation_deg=el, azimuth_deg=round(az % 360.0, 1), luminance_ratio=round(ratio, 3),
                 lit_fraction=round(float(lit.mean()), 3))
    med_lit = np.median(lin[lit], axis=0) if lit.any() else np.ones(3)
    med_sh = np.maximum(np.median(lin[~lit], axis=0), 1e-6) if (~lit).any() else np.ones(3)
    gain = med_lit / med_sh
    facts["lit_to_shadow_rgb"] = [round(float(x), 3) for x in gain]
    warm = bool(gain[0] >= gain[1] >= gain[2] and gain[0] >= _MIN_WARMTH * gain[2])
    if t < _MIN_T or ratio < _MIN_RATIO or not warm or lit.mean() < _MIN_LIT:
        empty.facts.update(facts, sun=f"none: the best direction (elevation {el:.0f}, azimuth {az % 360:.0f} deg) is "
                                      f"no sun's: t {t:.1f}, lit/shadow {ratio:.2f}x, colour ratio "
                                      f"{'/'.join(f'{x:.2f}' for x in gain)}, lit {100 * lit.mean():.0f} % "
                                      f"(needs t >= {_MIN_T:g}, >= {_MIN_RATIO:g}x, red >= green >= blue, "
                                      f"red >= {_MIN_WARMTH:g}x blue, lit >= {100 * _MIN_LIT:.0f} %)")
        return empty
    direct = np.clip(gain - 1.0, 0.0, None)
    # the faces above the ground choose between the ground's direction and its mirror image
    mirror_az = (180.0 - az) % 360.0
    mirror = sun_direction(up, heading, el, mirror_az)
    faces, normals, face_log_lum = _faces(views, returns, ground, static, rng)
    t_fit, t_mirror = (_face_score(occ_search, faces, normals, face_log_lum, d) for d in (s, mirror))
    facts.update(faces=len(faces), faces_t={name: round(t, 2) if np.isfinite(t) else None
                                            for name, t in (("fit", t_fit), ("mirror", t_mirror))})
    ground_direction = None
    if t_mirror >= max(t_fit + _MIRROR_MARGIN_T, _MIN_T):
        ground_direction, s, az = s, mirror, mirror_az
        where = (f"elevation {el:.0f} deg, azimuth {az % 360:.0f} deg from the first heading (the faces' "
                 f"choice: t {t_mirror:.1f} against {t_fit:.1f} at the ground's mirror image; the ground's "
                 f"shadows along azimuth {facts['azimuth_deg']:.0f} deg)")
    else:
        where = f"elevation {el:.0f} deg, azimuth {az % 360:.0f} deg from the first heading"
    facts.update(sun=where, direct_to_diffuse=[round(float(x), 3) for x in direct])
    return SunEstimate(s, el, az % 360.0, direct, occluders, facts, ground_direction)
