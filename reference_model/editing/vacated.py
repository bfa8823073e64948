"""What a removed or moved object leaves behind, filled on the trained model before it renders
(docs/design.md §7, "What a removal leaves, filled when it is made").

A parked car stands before the same kerb, road and wall in every frame. The background Gaussians
there (behind it, seen through its windows where its node is sparse) were trained on the car's
pixels; once the car is removed they show as smears in its colours. And what an object hid from
every view (the road behind a car that drives ahead of the camera the whole time) learned
nothing: the sky shows through. So:

* :func:`hidden_by_objects` finds the background that a vacated object covered in some view and
  that most views saw only through an object (:func:`object_cover`: the hull of a node's
  Gaussians, from its box's nearest corner), and :func:`inside_boxes` the background within a
  vacated box's margin above the ground (what the object painted there: its reflections, its blur
  at the box's edge, seen from the front too);
* :func:`fill_from_surroundings` gives each the inverse-squared-distance mean of the features of
  its nearest seen neighbours (Shepard 1968), heights stretched so the ground continues the
  ground: the road, kerb and wall around the object continued into where it stood, as street-scene
  graphs complete what a removed vehicle hid (Yan et al. 2024, "Street Gaussians"; Chen et al.
  2024, "OmniRe");
* the ground is laid where nothing was learned: the vacated boxes' footprints
  (:func:`~wcbench.reference_model.scene_graph.footprints.fill_footprints`) and, in each view, the
  see-through pixels of a vacated box below the horizon (:func:`ground_under_holes`), with
  features filled the same way.

Places, shapes and opacities of the trained Gaussians stay; every weather's decoder reads the new
features. :func:`vacated_background` joins the steps for a trained model and its views.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from typing import Any

import cv2
import numpy as np
import torch
from scipy.spatial import cKDTree

from wcbench.reference_model.model.gaussians import GaussianParams
from wcbench.reference_model.model.objects import RigidObject
from wcbench.reference_model.model.scene_model import WeatherCityModel
from wcbench.reference_model.model.sky import view_directions
from wcbench.reference_model.raster.rasterizer import rasterize_image
from wcbench.reference_model.scene_graph.footprints import fill_footprints
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.weather.particle_geometry import quat_from_axis_to

__all__ = ["fill_from_surroundings", "ground_under_holes", "hidden_by_objects", "inside_boxes", "object_boxes",
           "object_cover", "vacated_background"]

#: The unit cube's corners, scaled by a box's half-size.
_CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)


def _project(points: np.ndarray, world_to_camera: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pixel coordinates [N, 2], camera depth [N]) of world ``points`` [N, 3]; pixel centres at +0.5."""
    cam = points @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = cam[:, :2] / z[:, None] * np.diag(K)[:2] + K[:2, 2]
    return uv, z


def object_cover(objects: Sequence[RigidObject], frame: int, world_to_camera: np.ndarray, K: np.ndarray,
                 width: int, height: int, *, min_opacity: float = 0.3) -> np.ndarray:
    """[H, W] float64: where the ``objects`` present at ``frame`` stand before the camera, the camera
    depth (m) of the nearest corner of the box of an object covering each pixel; ``inf`` elsewhere.

    An object covers the convex hull of the projections of its Gaussians of opacity over
    ``min_opacity`` (its silhouette, windows and all: a car's glass, where its node is sparse, hid
    what lies behind it from the camera all the same). An object with a Gaussian or a box corner
    less than 0.1 m in front of the camera is left out (its projection is not its silhouette).

    Parameters
    ----------
    objects : sequence of RigidObject
        Nodes with their per-frame poses and ``box_size`` (m).
    frame : int
    world_to_camera : ndarray [4, 4]
    K : ndarray [3, 3]
        Intrinsics (px) at ``width`` x ``height``.
    width, height : int
    min_opacity : float
    """
    cover = np.full((height, width), np.inf)
    w2c, intrinsics = np.asarray(world_to_camera, np.float64), np.asarray(K, np.float64)
    for obj in objects:
        if not obj.at(frame):
            continue
        with torch.no_grad():
            means, _ = obj.world(frame)
            solid = torch.sigmoid(obj.gaussians.opacity_logits) > min_opacity
        pts = means[solid].detach().cpu().numpy().astype(np.float64)
        R = obj.rotation[frame].detach().cpu().numpy().astype(np.float64)
        t = obj.position[frame].detach().cpu().numpy().astype(np.float64)
        _, corner_z = _project((_CORNERS * np.asarray(obj.box_size, np.float64) / 2.0) @ R.T + t, w2c, intrinsics)
        uv, z = _project(pts, w2c, intrinsics)
        if len(pts) < 3 or not np.all(z > 0.1) or not np.all(corner_z > 0.1):
            continue
        mask = np.zeros((height, width), np.uint8)
        hull = cv2.convexHull(np.clip(np.round(uv - 0.5), -4 * width, 4 * width).astype(np.int32))
        cv2.fillConvexPoly(mask, hull, 1)
        inside = mask.astype(bool)
        cover[inside] = np.minimum(cover[inside], float(corner_z.min()))
    return cover


def hidden_by_objects(means: np.ndarray, cameras: Sequence[tuple[np.ndarray, np.ndarray, int, int]],
                      objects: Sequence[np.ndarray], vacated: Sequence[np.ndarray], *,
                      slack_m: float = 0.3, share: float = 0.5) -> np.ndarray:
    """Which points no camera saw but through an object, and some camera saw through a vacated one.

    A camera sees a point where it projects into its image at a depth over 0.1 m. It sees it
    through an object where an object covers that pixel from a depth more than ``slack_m`` nearer
    (:func:`object_cover`). A point is hidden when every camera that sees it sees it through an
    object, and at least one through a vacated one.

    Parameters
    ----------
    means : ndarray [N, 3]
        World points (m): the background Gaussians' centres.
    cameras : sequence of (ndarray [4, 4], ndarray [3, 3], int, int)
        Each frame's world-to-camera matrix, intrinsics (px), width and height.
    objects, vacated : sequences of ndarray [H, W] float
        Per camera, :func:`object_cover` of every object, and of the vacated ones.
    slack_m : float

    Returns
    -------
    ndarray [N] bool

    Raises
    ------
    ValueError
        If the three sequences differ in length, or a cover is not its camera's size.
    """
    if not len(cameras) == len(objects) == len(vacated):
        raise ValueError(f"one cover of the objects and one of the vacated ones per camera were expected, got "
                         f"{len(cameras)} cameras, {len(objects)} and {len(vacated)} covers")
    pts = np.asarray(means, np.float64).reshape(-1, 3)
    seen_in = np.zeros(len(pts), np.int64)
    clear_in = np.zeros(len(pts), np.int64)
    through_vacated = np.zeros(len(pts), bool)
    for (w2c, K, width, height), every, gone in zip(cameras, objects, vacated):
        if np.shape(every) != (height, width) or np.shape(gone) != (height, width):
            raise ValueError(f"covers of {width}x{height} were expected for that camera, got "
                             f"{np.shape(every)} and {np.shape(gone)}")
        uv, z = _project(pts, np.asarray(w2c, np.float64), np.asarray(K, np.float64))
        seen = (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
        col = np.where(seen, uv[:, 0], 0).astype(np.int64)
        row = np.where(seen, uv[:, 1], 0).astype(np.int64)
        seen_in += seen
        clear_in += seen & ~(z > np.asarray(every, np.float64)[row, col] + slack_m)
        through_vacated |= seen & (z > np.asarray(gone, np.float64)[row, col] + slack_m)
    return through_vacated & (clear_in <= (1.0 - share) * seen_in)


def fill_from_surroundings(features: np.ndarray, means: np.ndarray, hidden: np.ndarray, *,
                           neighbours: int = 8, up: np.ndarray | None = None,
                           vertical_weight: float = 1.0) -> np.ndarray:
    """``features`` with each hidden row replaced by the inverse-squared-distance mean (Shepard 1968)
    of the features of its ``neighbours`` nearest rows that are not hidden (by centre, in 3D, the
    vertical stretched by ``vertical_weight``).

    Parameters
    ----------
    features : ndarray [N, F]
    means : ndarray [N, 3]
        Centres (m).
    hidden : ndarray [N] bool
    neighbours : int
        At least 1.
    up : ndarray [3], optional
        The scene's up, with ``vertical_weight``.
    vertical_weight : float
        Distances along ``up`` count this many times over (1: plain 3D distance): a hidden row takes
        the features of the surfaces at its own height around it (the ground the ground's, a
        facade the facade's) rather than those of the nearest thing above or below it.

    Returns
    -------
    ndarray [N, F]
        A copy; ``features`` itself where nothing is hidden or nothing is left to fill from.

    Raises
    ------
    ValueError
        On shapes that disagree, or ``neighbours`` < 1.
    """
    feats = np.asarray(features)
    pts = np.asarray(means, np.float64)
    mask = np.asarray(hidden, bool)
    if feats.ndim != 2 or pts.shape != (len(feats), 3) or mask.shape != (len(feats),):
        raise ValueError(f"features [N, F], means [N, 3] and hidden [N] were expected, got {feats.shape}, "
                         f"{pts.shape} and {mask.shape}")
    if neighbours < 1:
        raise ValueError(f"neighbours must be at least 1, got {neighbours}")
    if not vertical_weight > 0:
        raise ValueError(f"vertical_weight must be > 0, got {vertical_weight}")
    out = feats.copy()
    if not mask.any() or mask.all():
        return out
    known = np.flatnonzero(~mask)
    k = min(neighbours, len(known))
    if up is not None and vertical_weight != 1.0:
        u = np.asarray(up, np.float64) / np.linalg.norm(up)
        pts = pts + (vertical_weight - 1.0) * np.outer(pts @ u, u)
    d, j = cKDTree(pts[known]).query(pts[mask], k=k)
    d, j = np.asarray(d).reshape(-1, k), np.asarray(j).reshape(-1, k)
    weight = 1.0 / np.maximum(d, 1e-3) ** 2
    source = feats[known].astype(np.float64)
    out[mask] = (np.einsum("nk,nkf->nf", weight, source[j]) / weight.sum(1, keepdims=True)).astype(feats.dtype)
    return out


def vacated_background(model: WeatherCityModel, keys: Collection[str],
                       cameras: Sequence[tuple[int, np.ndarray, np.ndarray, int, int]], *,
                       up: np.ndarray, neighbours: int = 8, vertical_weight: float = 4.0,
                       tile_margin_m: float = 0.3, box_margin_m: float = 0.3, box_floor_m: float = 0.2,
                       tile_opacity: float = 0.95) -> tuple[WeatherCityModel, dict[str, Any]]:
    """``model`` with the background that the objects ``keys`` hid given the features of what was
    seen around it (the module docstring).

    Parameters
    ----------
    model : WeatherCityModel
    keys : collection of str
        The vacated nodes (removed, or moved away): keys of ``model.objects()``.
    cameras : sequence of (int, ndarray [4, 4], ndarray [3, 3], int, int)
        The views that trained it: frame, world-to-camera, intrinsics (px), width, height.
    up : ndarray [3]
        The scene's up.
    neighbours, vertical_weight
        As :func:`fill_from_surroundings`: 4 keeps the ground under a car to the ground around it,
        not the crown of a tree beside it (pandaset_002, docs/findings.md).
    box_margin_m, box_floor_m : float
        As :func:`inside_boxes`: the background within a vacated box grown by ``box_margin_m`` (m),
        from ``box_floor_m`` (m) above its bottom face, is refilled too (on pandaset_002 a removed
        queue of cars left a red smear on the road, docs/findings.md).

    Returns
    -------
    model : WeatherCityModel
        A new model sharing every node but the background (its features copied) with ``model``;
        ``model`` itself when nothing is vacated.
    facts : dict
        ``hidden_gaussians``: how many background Gaussians were refilled; ``ground_tiles``: how
        many flat Gaussians were laid on the ground (under the footprints and the see-through pixels).

    Raises
    ------
    ValueError
        If a key is not an object of ``model``.
    """
    objects = model.objects()
    unknown = sorted(set(keys) - set(objects))
    if unknown:
        raise ValueError(f"not objects of the model: {unknown}")
    if not keys:
        return model, {"hidden_gaussians": 0, "ground_tiles": 0}
    every = list(objects.values())
    gone = [objects[k] for k in keys]
    views = [(w2c, K, w, h) for _, w2c, K, w, h in cameras]
    covers = [object_cover(every, f, w2c, K, w, h) for f, w2c, K, w, h in cameras]
    vacated = [object_cover(gone, f, w2c, K, w, h) for f, w2c, K, w, h in cameras]
    bg = model.background
    means = bg.means.detach().cpu().numpy().astype(np.float64)
    features = bg.features.detach().cpu().numpy()
    boxes = object_boxes(gone)
    hidden = hidden_by_objects(means, views, covers, vacated) | inside_boxes(
        means, boxes, up=up, margin_m=box_margin_m, floor_m=box_floor_m)
    # the ground under each vacated box, where no seen background Gaussian lies (what was hidden
    # there may have been trained transparent behind the object: the sky would show through)
    seen = ~hidden
    tiles = fill_footprints(means[seen], np.zeros((int(seen.sum()), 3)), boxes, up,
                            margin_m=tile_margin_m, opacity=tile_opacity)
    if len(tiles):  # what the footprints leave see-through (the ground behind an object, from far)
        under = GaussianParams.from_cloud(tiles, feature_dim=bg.feature_dim)
        with_tiles = GaussianParams(*(torch.cat([a.detach().cpu(), b.detach()]) for a, b in zip(
            (bg.means, bg.log_scales, bg.quats, bg.opacity_logits, bg.features),
            (under.means, under.log_scales, under.quats, under.opacity_logits, under.features))))
    else:
        with_tiles = bg
    behind = ground_under_holes(with_tiles, gone, cameras, up=up, opacity=tile_opacity)
    tiles = GaussianCloud.concatenate([tiles, behind])
    if not hidden.any() and len(tiles) == 0:
        return model, {"hidden_gaussians": 0, "ground_tiles": 0}
    stacked_means = np.concatenate([means, np.asarray(tiles.means, np.float64)])
    stacked = np.concatenate([features, np.zeros((len(tiles), features.shape[1]), features.dtype)])
    todo = np.concatenate([hidden, np.ones(len(tiles), bool)])
    filled = fill_from_surroundings(stacked, stacked_means, todo, neighbours=neighbours, up=up,
                                    vertical_weight=vertical_weight)
    extra = GaussianParams.from_cloud(tiles, feature_dim=bg.feature_dim)
    device = bg.means.device
    background = GaussianParams(
        means=torch.cat([bg.means.detach(), extra.means.detach().to(device)]),
        log_scales=torch.cat([bg.log_scales.detach(), extra.log_scales.detach().to(device)]),
        quats=torch.cat([bg.quats.detach(), extra.quats.detach().to(device)]),
        opacity_logits=torch.cat([bg.opacity_logits.detach(), extra.opacity_logits.detach().to(device)]),
        features=torch.from_numpy(filled).to(device))
    return model.with_background(background), {"hidden_gaussians": int(hidden.sum()), "ground_tiles": len(tiles)}


def _bottom_heights(objects: Sequence[RigidObject], frame: int, world_to_camera: np.ndarray, K: np.ndarray,
                    width: int, height: int, up: np.ndarray) -> np.ndarray:
    """[H, W] float64: the height along ``up`` (m) of the bottom face of the box of an object present at
    ``frame`` whose box's projection covers each pixel (the lowest, where several do); NaN elsewhere.
    A box with a corner less than 0.1 m in front of the camera is left out."""
    out = np.full((height, width), np.nan)
    for obj in objects:
        if not obj.at(frame):
            continue
        R = obj.rotation[frame].detach().cpu().numpy().astype(np.float64)
        t = obj.position[frame].detach().cpu().numpy().astype(np.float64)
        corners = (_CORNERS * np.asarray(obj.box_size, np.float64) / 2.0) @ R.T + t
        uv, z = _project(corners, world_to_camera, K)
        if not np.all(z > 0.1):
            continue
        mask = np.zeros((height, width), np.uint8)
        cv2.fillConvexPoly(mask, cv2.convexHull(np.round(uv - 0.5).astype(np.int32)), 1)
        inside = mask.astype(bool)
        out[inside] = np.fmin(out[inside], float((corners @ up).min()))
    return out


def ground_under_holes(background: GaussianParams, objects: Sequence[RigidObject],
                       cameras: Sequence[tuple[int, np.ndarray, np.ndarray, int, int]], *, up: np.ndarray,
                       step_px: int = 2, min_alpha: float = 0.5, cell_m: float = 0.1, thickness_m: float = 0.02,
                       opacity: float = 0.95) -> GaussianCloud:
    """Flat Gaussians on the ground where the vacated ``objects`` leave the ``background`` see-through.

    In each camera, a pixel inside the box of a vacated object, below the horizon, where the
    background's accumulated opacity is under ``min_alpha`` (nothing was learned there: what the
    object hid from every camera, under it and in its shadow behind it) gets a Gaussian where
    its ray meets the ground the object stood on (the plane at the box's bottom face), every
    ``step_px``-th pixel. Its side grows with the ground that the pixel's step covers there
    (``2 step_px`` pixels, in cells of ``cell_m`` doubled as often as needed, so a far one is as
    large as the few pixels it fills); one per cell of the world's ground grid at each size.

    Parameters
    ----------
    background : GaussianParams
    objects : sequence of RigidObject
        The vacated objects.
    cameras : sequence of (int, ndarray [4, 4], ndarray [3, 3], int, int)
        Frame, world-to-camera, intrinsics (px), width, height.
    up : ndarray [3]

    Returns
    -------
    GaussianCloud
        World coordinates, colours 0 (their features are filled afterwards).
    """
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    axes = np.stack([e1, np.cross(u, e1)])
    with torch.no_grad():
        args = (background.means.detach().float().cpu(), background.quats.detach().float().cpu(),
                torch.exp(background.log_scales.detach()).float().cpu(),
                torch.sigmoid(background.opacity_logits.detach()).float().cpu(),
                torch.zeros(len(background), 1))
    made: dict[tuple[int, int, int], tuple[np.ndarray, float]] = {}
    for frame, w2c, K, width, height in cameras:
        w2c, K = np.asarray(w2c, np.float64), np.asarray(K, np.float64)
        bottom = _bottom_heights(objects, frame, w2c, K, width, height, u)
        if not np.isfinite(bottom).any():
            continue
        with torch.no_grad():
            alpha = rasterize_image(*args, w2c, K, width, height, render_depth=False).alpha.numpy()
        c2w = np.linalg.inv(w2c)
        rays = view_directions(c2w, K, width, height).astype(np.float64)
        grid = np.zeros((height, width), bool)
        grid[::step_px, ::step_px] = True
        down = -(rays @ u)
        rr, cc = np.nonzero(grid & (alpha < min_alpha) & np.isfinite(bottom) & (down > 0.01))
        center = c2w[:3, 3]
        t = (center @ u - bottom[rr, cc]) / down[rr, cc]
        keep = t > 0
        rr, cc, t = rr[keep], cc[keep], t[keep]
        points = center + rays[rr, cc] * t[:, None]
        # the ground a step of pixels covers there: across the ray t / f per pixel, along it 1 / sin(e) more
        side = 2 * step_px * t / float(K[0, 0]) / np.maximum(down[rr, cc], 0.05)
        level = np.maximum(0, np.ceil(np.log2(np.maximum(side, cell_m) / cell_m))).astype(np.int64)
        size = cell_m * 2.0 ** level
        ij = np.floor((points @ axes.T) / size[:, None]).astype(np.int64)
        for p, lv, sz, (i, j) in zip(points, level.tolist(), size.tolist(), ij.tolist()):
            made.setdefault((lv, i, j), (p, sz))
    n = len(made)
    if n == 0:
        return GaussianCloud(np.zeros((0, 3), np.float32), np.zeros((0, 4), np.float32), np.zeros((0, 3), np.float32),
                             np.zeros(0, np.float32), np.zeros((0, 3), np.float32))
    points = np.stack([p for p, _ in made.values()])
    sizes = np.array([sz for _, sz in made.values()])
    scales = np.stack([0.75 * sizes, 0.75 * sizes, np.full(n, thickness_m)], 1)
    return GaussianCloud(means=points.astype(np.float32),
                         quats=np.tile(quat_from_axis_to(u[None]).astype(np.float32), (n, 1)),
                         scales=scales.astype(np.float32), opacities=np.full(n, opacity, np.float32),
                         colors=np.zeros((n, 3), np.float32))


def inside_boxes(points: np.ndarray, boxes: Sequence[tuple[np.ndarray, np.ndarray]], *, up: np.ndarray,
                 margin_m: float = 0.3, floor_m: float = 0.2) -> np.ndarray:
    """[N] bool: the ``points`` inside any of ``boxes`` grown by ``margin_m`` on every side, above the
    height ``floor_m`` over the box's lowest corner (along ``up``): the ground under and beside the box
    is left out, what stands on it is in.

    Parameters
    ----------
    points : ndarray [N, 3]
        World points (m).
    boxes : sequence of (ndarray [4, 4], ndarray [3])
        Object-to-world pose and size along the box's own axes (m), as :func:`object_boxes` lists them.
    up : ndarray [3]
        The scene's up.
    margin_m, floor_m : float
        Both at least 0 (m).
    """
    if margin_m < 0 or floor_m < 0:
        raise ValueError(f"margin_m {margin_m} and floor_m {floor_m}: both at least 0 (m) were expected")
    p = np.asarray(points, np.float64).reshape(-1, 3)
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    out = np.zeros(len(p), bool)
    for T, size in boxes:
        T, half = np.asarray(T, np.float64), np.asarray(size, np.float64) / 2.0
        local = (p - T[:3, 3]) @ T[:3, :3]
        inside = np.all(np.abs(local) <= half + margin_m, axis=1)
        lowest = float((((_CORNERS * half) @ T[:3, :3].T + T[:3, 3]) @ u).min())
        out |= inside & (p @ u >= lowest + floor_m)
    return out


def object_boxes(objects: Sequence[RigidObject], *, tolerance_m: float = 0.05) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each object's (object-to-world [4, 4], size [3]) box at the frames it is present, a box that
    moved less than ``tolerance_m`` since the last one listed left out (a parked car's: once)."""
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for obj in objects:
        last: np.ndarray | None = None
        for f in np.flatnonzero(obj.present.detach().cpu().numpy()):
            T = np.eye(4)
            T[:3, :3] = obj.rotation[f].detach().cpu().numpy()
            T[:3, 3] = obj.position[f].detach().cpu().numpy()
            if last is None or np.abs(T[:3, 3] - last).max() > tolerance_m:
                out.append((T, np.asarray(obj.box_size, np.float64)))
                last = T[:3, 3]
    return out
