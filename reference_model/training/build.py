"""Build the WeatherCity model to train from a scene: the scene graph skips what the scene does not need.

- Background: Gaussians from the lidar of the training frames (voxel-downsampled, colored by their
  own frame), plus sparse far Gaussians along the rays of pixels no lidar return reaches, so that
  distant structure exists; Gaussians outside every training frustum are dropped.
- One rigid node per boxed track, moving or not (``static_nodes``, on by default; off, tracks that
  do not move stay in the background), its lidar returns cut out of the background, so that every object the
  scene ships a box for can be edited; tracks of deformable classes (pedestrians, cyclists) become
  non-rigid nodes. A node type with no object is not built, and its code never runs.
- Under each node's box, where no lidar return saw the ground, opaque flat Gaussians on the fitted
  ground coloured from the road around it (``footprint_fill``): a removed object leaves road.
- Decoders for the clear weather and each supervised weather only (a weather without supervision
  is not trained); one sky map per decoded weather, warm-started from the sky pixels.

What was built and skipped is returned as a JSON-ready record for ``info.json``.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import cv2
import numpy as np
import torch

from wcbench.reference_model.model.decoders import WeatherDecoders
from wcbench.reference_model.model.gaussians import GaussianParams
from wcbench.reference_model.model.objects import NonRigidObject, RigidObject
from wcbench.reference_model.model.scene_model import WeatherCityModel
from wcbench.reference_model.model.sky import SkyModel, sky_window, view_directions
from wcbench.reference_model.scene_graph.completion import (
    FILL_GROUND,
    FILL_WALL,
    complete_distance,
    ground_height_below,
)
from wcbench.reference_model.scene_graph.footprints import fill_footprints
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.scene_graph.lidar_init import (
    LidarInitOptions,
    init_scene_from_lidar,
    node_tracks,
    sample_image,
)
from wcbench.reference_model.training.config import TrainConfig
from wcbench.reference_model.training.views import TrainingView, box_mask

__all__ = ["FILL_OPACITY", "NONRIGID_WORDS", "build_model", "completion_cloud", "far_cloud", "in_any_frustum",
           "is_nonrigid", "seen_colour"]

#: Opacity the footprint fill starts with: hidden behind its object in every training view, it gets
#: no gradient to grow from the low opacity the others start at, and must stand as the road does.
FILL_OPACITY = 0.95

#: Track classes containing one of these words (case-insensitive) deform: non-rigid nodes.
NONRIGID_WORDS = ("pedestrian", "person", "cyclist", "bicyclist", "human", "child")


def is_nonrigid(class_name: str) -> bool:
    """Whether a track class is deformable (pedestrians, cyclists)."""
    name = class_name.lower()
    return any(w in name for w in NONRIGID_WORDS)


def in_any_frustum(means: np.ndarray, views: Sequence[TrainingView], *, margin: float = 0.05,
                   near: float = 0.1) -> np.ndarray:
    """[N] bool: centres (world, m) inside the view frustum of at least one view (image grown by
    ``margin`` of its size on each side, beyond ``near`` metres)."""
    keep = np.zeros(len(means), bool)
    pts = np.asarray(means, np.float64)
    for v in views:
        w2c = v.world_to_camera
        p = pts @ w2c[:3, :3].T + w2c[:3, 3]
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = p[:, 0] / z * v.K[0, 0] + v.K[0, 2]
            w = p[:, 1] / z * v.K[1, 1] + v.K[1, 2]
        mx, my = margin * v.width, margin * v.height
        keep |= (z > near) & (u >= -mx) & (u <= v.width + mx) & (w >= -my) & (w <= v.height + my)
    return keep


def _isotropic_cloud(means: list[np.ndarray], colors: list[np.ndarray], scales: list[np.ndarray],
                     opacity: float) -> GaussianCloud:
    """Isotropic Gaussians from per-view lists of centres [n, 3], colours [n, 3] and scales [n]."""
    if not means:
        return GaussianCloud(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    return GaussianCloud.isotropic(np.concatenate(means), np.concatenate(scales), np.concatenate(colors), opacity)


def far_cloud(views: Sequence[TrainingView], *, stride_px: int = 8, every: int = 3,
              opacity: float = 0.5, objects: Mapping[int, np.ndarray] | None = None) -> GaussianCloud:
    """Gaussians far along the rays of pixels that no lidar return reaches (not sky, not objects).

    Each sampled pixel gets one Gaussian at 1.2 times the view's 95th-percentile lidar depth (at
    least 40 m), as wide as ``stride_px`` pixels there, colored by the pixel. ``objects`` maps a
    view's frame to an [H, W] bool mask of pixels no Gaussian is made for besides its moving
    objects (the scene graph's object boxes, :func:`build_model`).
    """
    means, colors, scales = [], [], []
    for v in list(views)[::every]:
        if v.depth is None:
            continue
        hits = v.depth[v.depth > 0]
        dist = max(40.0, 1.2 * float(np.percentile(hits, 95))) if hits.size else 40.0
        ys, xs = np.mgrid[stride_px // 2 : v.height : stride_px, stride_px // 2 : v.width : stride_px]
        ys, xs = ys.ravel(), xs.ravel()
        # no lidar return within half a stride of the sample
        covered = np.zeros(len(xs), bool)
        r = stride_px // 2
        for dy in range(-r, r + 1, max(1, r // 2)):
            for dx in range(-r, r + 1, max(1, r // 2)):
                yy, xx = np.clip(ys + dy, 0, v.height - 1), np.clip(xs + dx, 0, v.width - 1)
                covered |= v.depth[yy, xx] > 0
        ok = ~covered & ~v.dynamic[ys, xs]
        if objects is not None and v.frame in objects:
            ok &= ~objects[v.frame][ys, xs]
        if v.ignore.shape == (v.height, v.width):
            ok &= ~v.ignore[ys, xs]
        if v.sky is not None:
            ok &= ~v.sky[ys, xs]
        xs, ys = xs[ok], ys[ok]
        if not len(xs):
            continue
        rays = np.stack([(xs + 0.5 - v.K[0, 2]) / v.K[0, 0], (ys + 0.5 - v.K[1, 2]) / v.K[1, 1], np.ones(len(xs))], 1)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        world = (rays * dist) @ v.camera_to_world[:3, :3].T + v.camera_to_world[:3, 3]
        means.append(world)
        colors.append(sample_image(v.images["clear"], np.stack([xs + 0.5, ys + 0.5], 1)))
        scales.append(np.full(len(xs), dist * stride_px / (2 * v.K[0, 0])))
    return _isotropic_cloud(means, colors, scales, opacity)


def completion_cloud(views: Sequence[TrainingView], *, up: np.ndarray, stride_px: int = 6, every: int = 2,
                     opacity: float = 0.5, max_distance_m: float = 200.0,
                     objects: Mapping[int, np.ndarray] | None = None) -> GaussianCloud:
    """Gaussians on the surfaces a view sees beyond its lidar: the ground plane below the lidar's
    lowest beam and the walls above its highest
    (:func:`~wcbench.reference_model.scene_graph.completion.complete_distance`).

    Each sampled pixel (every ``stride_px`` pixels of every ``every``-th view, not sky, not a moving
    object, no lidar return within half a stride) gets one Gaussian at its completed distance, as
    wide as ``stride_px`` pixels there, colored by the pixel; ``objects`` as in :func:`far_cloud`.
    """
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    means, colors, scales = [], [], []
    for v in list(views)[::every]:
        if v.depth is None or not np.any(v.depth > 0):
            continue
        h, w = v.height, v.width
        r = stride_px // 2
        depth = np.where(v.depth > 0, v.depth, np.inf).astype(np.float32)
        # the nearest return within half a stride stands for the pixel (lidar is sparser than the image)
        near = cv2.erode(depth, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
        known = np.isfinite(near)
        rays = view_directions(v.camera_to_world, v.K, w, h).astype(np.float64)
        norm = 1.0 / (rays @ v.camera_to_world[:3, 2])  # ray length per metre of camera depth
        center = v.camera_to_world[:3, 3]
        distance = np.where(known, near * norm, np.inf)
        points = center + rays[v.depth > 0] * (v.depth[v.depth > 0] * norm[v.depth > 0])[:, None]
        sky = v.sky if v.sky is not None else np.zeros((h, w), bool)
        filled, kind, _ = complete_distance(distance, known, sky, rays, center, up,
                                            ground_height_below(points, center, up),
                                            forward=v.camera_to_world[:3, 2], guide=v.images["clear"])
        ys_, xs_ = np.mgrid[r:h:stride_px, r:w:stride_px]
        ys_, xs_ = ys_.ravel(), xs_.ravel()
        d = filled[ys_, xs_]
        ok = np.isin(kind[ys_, xs_], (FILL_GROUND, FILL_WALL)) & np.isfinite(d) & (d < max_distance_m)
        if v.dynamic.shape == (h, w):
            ok &= ~v.dynamic[ys_, xs_]
        if objects is not None and v.frame in objects:
            ok &= ~objects[v.frame][ys_, xs_]
        if v.ignore.shape == (h, w):
            ok &= ~v.ignore[ys_, xs_]
        ys_, xs_, d = ys_[ok], xs_[ok], d[ok]
        if not len(d):
            continue
        means.append(center + rays[ys_, xs_] * d[:, None])
        colors.append(sample_image(v.images["clear"], np.stack([xs_ + 0.5, ys_ + 0.5], 1)))
        scales.append(d * stride_px / (2 * v.K[0, 0]))
    return _isotropic_cloud(means, colors, scales, opacity)


def seen_colour(points: np.ndarray, views: Sequence[TrainingView], objects: Mapping[int, np.ndarray], *,
                slack_m: float = 0.5, grow_px: int = 2) -> np.ndarray:
    """[N, 3] median clear RGB of world ``points`` [N, 3] (m) over the views that see them: inside the
    image, outside ``objects[frame]`` (the nodes' boxes, [H, W] bool, grown by ``grow_px``) and not behind the view's
    lidar depth there by more than ``slack_m`` (something else before them); NaN where none does."""
    pts = np.asarray(points, np.float64)
    samples: list[np.ndarray] = []
    for v in views:
        cam = pts @ v.world_to_camera[:3, :3].T + v.world_to_camera[:3, 3]
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = cam[:, :2] / z[:, None] * np.diag(v.K)[:2] + v.K[:2, 2]
        ok = (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < v.width) & (uv[:, 1] >= 0) & (uv[:, 1] < v.height)
        ij = np.where(ok[:, None], uv, 0.0).astype(np.int64)
        if v.frame in objects:  # grown by a few pixels: the edge pixels blend the object in
            grown = cv2.dilate(objects[v.frame].astype(np.uint8), np.ones((2 * grow_px + 1,) * 2, np.uint8))
            ok &= grown[ij[:, 1], ij[:, 0]] == 0
        if v.depth is not None:
            d = v.depth[ij[:, 1], ij[:, 0]]
            ok &= ~((d > 0) & (d < z - slack_m))
        rgb = np.full((len(pts), 3), np.nan)
        rgb[ok] = sample_image(v.images["clear"], uv[ok])
        samples.append(rgb)
    if not samples:
        return np.full((len(pts), 3), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN column: a point no view sees
        return np.nanmedian(np.stack(samples), axis=0)


def _distinct_boxes(tracks: Sequence[Any], *, tolerance_m: float = 0.05) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each track's (object-to-world [4, 4], size [3]) boxes, a held track's repeated box once."""
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for track in tracks:
        poses = np.asarray(track.object_to_world, np.float64)
        sizes = np.asarray(track.box_size, np.float64).reshape(-1, 3)
        last: np.ndarray | None = None
        for T, size in zip(poses, sizes):
            if last is None or np.abs(T[:3, 3] - last).max() > tolerance_m:
                out.append((T, size))
                last = T[:3, 3]
    return out


def build_model(scene: Any, views: Sequence[TrainingView], config: TrainConfig, *,
                weathers: Sequence[str]) -> tuple[WeatherCityModel, dict[str, Any]]:
    """The model to train, initialised from the scene's lidar and the training views.

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
        Or any object with its attributes.
    views : sequence of TrainingView
        The training views (held-out frames excluded): their lidar builds the Gaussians, their
        frusta cull them, their sky pixels warm-start the sky maps.
    config : TrainConfig
    weathers : sequence of str
        ``"clear"`` first, then the supervised weathers.

    Returns
    -------
    model : WeatherCityModel
    facts : dict
        Gaussian counts per node type, what was skipped and why.
    """
    frames = [v.frame for v in views]
    options = LidarInitOptions(voxel_m=config.voxel_m, node_voxel_m=config.node_voxel_m, opacity=config.init_opacity,
                               moving_threshold_m=config.moving_threshold_m, static_nodes=config.static_nodes)
    graph = init_scene_from_lidar(scene, options, frames=frames)
    clouds = [graph.static]
    # no far or completion Gaussian where a node's box is: coloured by the object's pixels that the
    # lidar missed (windows), they would stay in the background when the object is removed
    boxed = node_tracks(scene, moving_threshold_m=config.moving_threshold_m, static_nodes=config.static_nodes)
    objects = {v.frame: box_mask(boxed, v.frame, v.world_to_camera, v.K, v.width, v.height) for v in views}
    n_far = 0
    if config.far_points:
        far = far_cloud(views, opacity=config.init_opacity, objects=objects)
        n_far = len(far)
        clouds.append(far)
    n_fill = 0
    if config.footprint_fill and boxed:
        fill = fill_footprints(graph.static.means, graph.static.colors, _distinct_boxes(boxed),
                               np.asarray(scene.up, np.float64), margin_m=options.box_margin_m + 0.1,
                               opacity=FILL_OPACITY, colour_at=lambda p: seen_colour(p, views, objects))
        n_fill = len(fill)
        clouds.append(fill)
    n_completion = 0
    if config.completion_points:
        completed = completion_cloud(views, up=np.asarray(scene.up, np.float64), opacity=config.init_opacity,
                                     objects=objects)
        n_completion = len(completed)
        clouds.append(completed)
    background = GaussianCloud.concatenate(clouds)
    inside = in_any_frustum(background.means, views) if config.cull_frustum else np.ones(len(background), bool)
    dropped = int((~inside).sum())
    background = background.subset(inside)
    n_frames = len(scene.frames)
    rigid: list[RigidObject] = []
    nonrigid: list[NonRigidObject] = []
    tracks = {str(t.id): t for t in scene.tracks}
    empty_nodes = 0
    for i, node in enumerate(graph.nodes):
        if len(node.cloud) == 0:  # too few lidar returns on the object to make a Gaussian
            empty_nodes += 1
            continue
        track = tracks[node.track_id]
        size = np.asarray(track.box_size, np.float64).reshape(-1, 3).mean(0)
        params = GaussianParams.from_cloud(node.cloud, feature_dim=config.feature_dim, seed=config.seed + 1 + i)
        kwargs: dict[str, Any] = dict(track_id=node.track_id, class_name=node.class_name, frames=node.frames,
                                      object_to_world=node.object_to_world, box_size=size, n_frames=n_frames)
        if is_nonrigid(node.class_name):
            nonrigid.append(NonRigidObject(params, **kwargs))
        else:
            rigid.append(RigidObject(params, **kwargs))
    decoders = WeatherDecoders(weathers, feature_dim=config.feature_dim, hidden=config.hidden,
                               shared=config.shared_decoder, seed=config.seed)
    first = views[0]
    up, heading = np.asarray(scene.up, np.float64), first.camera_to_world[:3, 2]
    rays = {v.frame: torch.from_numpy(view_directions(v.camera_to_world, v.K, v.width, v.height)) for v in views}
    window = None
    if config.sky_window:
        window = sky_window(SkyModel(weathers[:1], up=up, heading=heading), list(rays.values()))
    sky = SkyModel(weathers, up=up, heading=heading, rows=config.sky_map[0], cols=config.sky_map[1],
                   shared=config.shared_decoder, window=window)
    for v in views:
        if v.sky is None or not v.sky.any():
            continue
        grid = sky.grid(rays[v.frame])
        for w in weathers:
            if w in v.images:
                sky.fill_from(w, grid, torch.from_numpy(v.images[w]), torch.from_numpy(v.sky))
    model = WeatherCityModel(
        GaussianParams.from_cloud(background, feature_dim=config.feature_dim, seed=config.seed),
        rigid, nonrigid, decoders, sky,
    )
    n_nodes = len(graph.nodes)
    facts = {
        "gaussians": model.counts(),
        "far_gaussians": n_far,
        "completion_gaussians": n_completion,
        "footprint_fill_gaussians": n_fill,
        "skipped": {
            "tracks_in_background": len(scene.tracks) - n_nodes,
            "tracks_without_lidar_points": empty_nodes,
            "gaussians_outside_every_training_frustum": dropped,
            "nonrigid_nodes": None if nonrigid else "no boxed pedestrian or cyclist: node type not built",
            "rigid_nodes": None if rigid else "no boxed rigid object: node type not built",
        },
        "weathers": list(weathers),
    }
    return model, facts
