"""Gaussians initialised from a scene's lidar: a scene to render before any training.

Every lidar point is colored from the image of its own frame (same instant, so moving objects get
their own colors, and the lidar and camera see nearly the same surfaces), then the points of all
sweeps are voxel-downsampled (mean position and color per voxel). Each Gaussian is isotropic with
the scale of 3D Gaussian Splatting's initialisation, sqrt(mean squared distance to the 3 nearest
neighbours), clipped. This is also where training starts from.

Colors are RGB in [0, 1] (the images' sRGB values / 255, as 3DGS trains on them); positions are
world metres of the re-based scene. numpy only (no torch).

Moving objects (tracks whose box moves more than ``moving_threshold_m``) would smear into trails
if their sweeps were accumulated in the world. Their points are cut out of the static cloud and,
with :func:`init_scene_from_lidar`, kept as rigid nodes in their box frame and moved by the track
pose (the rigid nodes of docs/design.md §7, :mod:`.nodes`): :meth:`SceneGaussians.at_frame` gives
the Gaussians of a frame. With ``static_nodes`` every other boxed track (a parked car, a cone)
becomes a node as well, held at one pose (:func:`node_tracks`), so that object
editing reaches every object the scene ships a box for.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from wcbench.core.errors import InputError
from wcbench.core.image_io import read_rgb8, to_float
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.scene_graph.nodes import RigidNode, SceneGaussians
from wcbench.reference_model.transforms import apply_linear

__all__ = [
    "LidarInitOptions",
    "colored_lidar_points",
    "estimate_sky_color",
    "init_from_lidar",
    "init_scene_from_lidar",
    "moving_tracks",
    "node_tracks",
    "sample_image",
    "voxel_downsample",
]


def _read_rgb_float(path: Path) -> np.ndarray:
    """[H, W, 3] float32 RGB in [0, 1] of an 8-bit sRGB image, read as strictly as evaluation reads it."""
    return to_float(read_rgb8(path))


def sample_image(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at pixel coordinates (pixel centers at +0.5).

    Parameters
    ----------
    image : ndarray [H, W, C]
    uv : ndarray [N, 2]
        x right, y down (px); clamped to the image.

    Returns
    -------
    ndarray [N, C] float32
    """
    h, w = image.shape[:2]
    x = np.clip(np.asarray(uv[:, 0], np.float64) - 0.5, 0.0, w - 1.0)
    y = np.clip(np.asarray(uv[:, 1], np.float64) - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2) if w > 1 else np.zeros(len(x), np.int64)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2) if h > 1 else np.zeros(len(y), np.int64)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


def voxel_downsample(
    points: np.ndarray, values: np.ndarray, voxel_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean point and mean value per occupied voxel.

    Parameters
    ----------
    points : ndarray [N, 3]
        Metres.
    values : ndarray [N, C]
        Per-point values to average (colors).
    voxel_m : float
        Voxel edge (m), > 0.

    Returns
    -------
    centers : ndarray [M, 3] float32
        Mean position of the points in each voxel (sums in float64).
    means : ndarray [M, C] float32
    counts : ndarray [M] int64
        Points per voxel.

    Raises
    ------
    ValueError
        If ``voxel_m`` is not positive or shapes disagree.
    """
    if not voxel_m > 0 or math.isinf(voxel_m):
        raise ValueError(f"voxel_m must be a positive finite size (m), got {voxel_m}")
    points = np.asarray(points, np.float64)
    values = np.asarray(values, np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or values.shape[0] != points.shape[0]:
        raise ValueError(f"points [N, 3] and values [N, C] must match, got {points.shape} and {values.shape}")
    if len(points) == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0, values.shape[1]), np.float32), np.zeros(0, np.int64)
    ijk = np.floor(points / voxel_m).astype(np.int64)
    ijk -= ijk.min(axis=0)
    dims = ijk.max(axis=0) + 1
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]  # fits int64 for any real scene
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    m = len(counts)
    centers = (
        np.stack([np.bincount(inverse, points[:, a], minlength=m) for a in range(3)], 1) / counts[:, None]
    )
    sums = np.stack([np.bincount(inverse, values[:, c], minlength=m) for c in range(values.shape[1])], 1)
    means = sums.astype(np.float64) / counts[:, None]
    return centers.astype(np.float32), means.astype(np.float32), counts


def _lidar_frames(scene: Any, frames: Iterable[int] | None) -> list[int]:
    indices = range(len(scene.frames)) if frames is None else frames
    out = []
    for i in indices:
        if not 0 <= i < len(scene.frames):
            raise ValueError(f"frames: index {i} outside the scene's {len(scene.frames)} frames")
        if scene.frames[i].lidar_path is not None:
            out.append(int(i))
    return out


def colored_lidar_points(
    scene: Any, *, frames: Iterable[int] | None = None, keep: Mapping[int, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lidar points seen by their own frame's camera, with the image color there.

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
    frames : iterable of int, optional
        Frames whose sweeps to use (default all; frames without lidar are skipped).
    keep : mapping of int to ndarray [N] bool, optional
        Per frame, which returns of its sweep to use (e.g. the static ones of
        :func:`wcbench.reference_model.scene_analysis.motion.classify_returns`); a frame it does not
        name keeps every return.

    Returns
    -------
    points : ndarray [N, 3] float64
        World (m).
    colors : ndarray [N, 3] float32
        RGB in [0, 1].
    frame : ndarray [N] int64
        Frame index of each point's sweep.
    """
    pts_all, col_all, frame_all = [], [], []
    for i in _lidar_frames(scene, frames):
        sweep = scene.lidar(i)
        if sweep is None or len(sweep.points) == 0:
            continue
        cam = scene.frames[i].camera
        uv, z = cam.project(sweep.points)
        inside = (
            (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        )
        if keep is not None and i in keep:
            if len(keep[i]) != len(sweep.points):
                raise ValueError(f"keep[{i}]: {len(keep[i])} flags for a sweep of {len(sweep.points)} returns")
            inside &= np.asarray(keep[i], bool)
        if not np.any(inside):
            continue
        image = _read_rgb_float(scene.frames[i].image_path)
        if image.shape[:2] != (cam.height, cam.width):
            raise InputError(
                f"{scene.frames[i].image_path}: image is {image.shape[1]}x{image.shape[0]}, "
                f"the camera says {cam.width}x{cam.height}"
            )
        pts_all.append(np.asarray(sweep.points, np.float64)[inside])
        col_all.append(sample_image(image, uv[inside]))
        frame_all.append(np.full(int(inside.sum()), i, np.int64))
    if not pts_all:
        return np.zeros((0, 3)), np.zeros((0, 3), np.float32), np.zeros(0, np.int64)
    return np.concatenate(pts_all), np.concatenate(col_all), np.concatenate(frame_all)


def _cloud(opts: LidarInitOptions, points: np.ndarray, colors: np.ndarray, ranges: np.ndarray, *,
           voxel_m: float | None = None) -> GaussianCloud:
    """Voxel-downsampled isotropic Gaussians of colored points seen at ``ranges`` (m)."""
    voxel = opts.voxel_m if voxel_m is None else voxel_m
    values = np.concatenate([colors, ranges[:, None]], 1)
    means, avg, counts = voxel_downsample(points, values, voxel)
    rgb, rng = avg[:, :3], avg[:, 3]
    spacing = _knn_scale(means, opts.knn)
    # A lone return far from any other is noise (a bird, a spray droplet, a multipath hit); as
    # a Gaussian as wide as its distance to the neighbours it would be a blob in front of the
    # camera. Dense voxels and points with close neighbours stay.
    keep = (counts >= opts.min_points) | (spacing <= 3.0 * voxel)
    means, rgb, rng, spacing = means[keep], rgb[keep], rng[keep], spacing[keep]
    # No wider than a fixed angle seen from the sensor: sparse far points may grow, near ones
    # (a few centimetres of lidar spacing) may not.
    upper = np.minimum(opts.max_scale_m, opts.max_angular_scale * rng)
    scales = np.clip(opts.scale_factor * spacing, min(opts.min_scale, voxel / 5.0), None)
    scales = np.maximum(np.minimum(scales, upper), min(opts.min_scale, voxel / 5.0))
    return GaussianCloud.isotropic(means, scales, rgb, opts.opacity)


def _ranges(scene: Any, points: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """[N] distance of every point to the camera of its own frame (m)."""
    centers = np.stack([np.asarray(f.camera.center, np.float64) for f in scene.frames])
    d = points - centers[frame]
    return np.sqrt(np.einsum("ij,ij->i", d, d))


def moving_tracks(scene: Any, threshold_m: float = 0.5) -> list[Any]:
    """Tracks whose box center moves more than ``threshold_m`` over the sequence."""
    out = []
    for track in scene.tracks:
        centers = np.asarray(track.object_to_world, np.float64)[:, :3, 3]
        if len(centers) and np.linalg.norm(centers - centers[0], axis=1).max() > threshold_m:
            out.append(track)
    return out


@dataclass(frozen=True)
class _HeldTrack:
    """A track that does not move, posed at one box in each of its annotated frames (:func:`node_tracks`)."""

    id: str
    class_name: str
    frames: np.ndarray  # [M] int
    object_to_world: np.ndarray  # [M, 4, 4]
    box_size: np.ndarray  # [M, 3]


def _held_still(track: Any) -> _HeldTrack:
    """``track`` at its median annotation (the box nearest the centres' median) in each annotated frame."""
    T = np.asarray(track.object_to_world, np.float64)
    sizes = np.asarray(track.box_size, np.float64).reshape(-1, 3)
    k = int(np.argmin(np.linalg.norm(T[:, :3, 3] - np.median(T[:, :3, 3], axis=0), axis=1)))
    return _HeldTrack(id=str(track.id), class_name=str(track.class_name), frames=np.asarray(track.frames),
                      object_to_world=np.repeat(T[k][None], len(T), axis=0),
                      box_size=np.repeat(sizes[k][None], len(T), axis=0))


def node_tracks(scene: Any, *, moving_threshold_m: float = 0.5, static_nodes: bool = False) -> list[Any]:
    """The tracks that become scene-graph nodes: the moving ones, and with ``static_nodes`` the others.

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
        Or any object with ``tracks``.
    moving_threshold_m : float
        A track whose box centre moves more than this (m) is moving (:func:`moving_tracks`): posed
        per annotated frame, one node even if it stands still part of the time.
    static_nodes : bool
        Every other track too, held at its median box in each frame it is annotated in (annotation
        jitter does not shake it). Not in the others: a still box annotated only late (a pedestrian
        who stops) says nothing of what stood there before.

    Returns
    -------
    list
        The moving tracks as the scene has them, then the held ones, each in scene order.
    """
    moving = moving_tracks(scene, moving_threshold_m)
    if not static_nodes:
        return moving
    ids = {id(t) for t in moving}
    return moving + [_held_still(t) for t in scene.tracks if id(t) not in ids and len(np.asarray(t.frames))]


def _inside_box(
    points: np.ndarray, object_to_world: np.ndarray, size: np.ndarray, margin_m: float
) -> np.ndarray:
    """[N] bool: points inside the box (grown by ``margin_m``), and their box-frame coordinates."""
    T = np.asarray(object_to_world, np.float64)
    local = apply_linear(points - T[:3, 3], T[:3, :3])
    return np.all(np.abs(local) <= np.asarray(size, np.float64) / 2.0 + margin_m, axis=1)


def _split_moving(
    scene: Any, points: np.ndarray, frame: np.ndarray, tracks: list[Any], margin_m: float
) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Mask of static points, and per moving track the indices of its points.

    ``frame`` must be non-decreasing (as :func:`colored_lidar_points` returns it). Per frame, only
    the points within a box's bounding sphere (a k-d tree of the frame's points) are tested.
    """
    static = np.ones(len(points), bool)
    found: dict[int, list[np.ndarray]] = {}
    per_track = [{int(f): k for k, f in enumerate(np.asarray(t.frames))} for t in tracks]
    for f in np.unique(frame):
        lo, hi = np.searchsorted(frame, f, side="left"), np.searchsorted(frame, f, side="right")
        tree = None
        for ti, track in enumerate(tracks):
            k = per_track[ti].get(int(f))
            if k is None:
                continue
            T = np.asarray(track.object_to_world[k], np.float64)
            half = np.asarray(track.box_size[k], np.float64) / 2.0 + margin_m
            tree = tree or cKDTree(points[lo:hi])
            cand = np.asarray(tree.query_ball_point(T[:3, 3], float(np.linalg.norm(half))), np.int64)
            if cand.size == 0:
                continue
            inside = _inside_box(points[lo + cand], T, 2.0 * (half - margin_m), margin_m)
            if inside.any():
                found.setdefault(ti, []).append(lo + cand[inside])
    members: dict[int, np.ndarray] = {}
    for ti, parts in sorted(found.items()):
        idx = np.sort(np.concatenate(parts))
        static[idx] = False
        members[ti] = idx
    return static, members


@dataclass(frozen=True)
class LidarInitOptions:
    """How Gaussians are initialised from the lidar (:func:`init_from_lidar`, :func:`init_scene_from_lidar`).

    Attributes
    ----------
    voxel_m : float
        Voxel edge of the downsampling of the static cloud (m).
    node_voxel_m : float
        Voxel edge of the object clouds of :func:`init_scene_from_lidar` (m); finer, objects are small.
    opacity : float
        Initial opacity in (0, 1]. 0.9 renders a viewable scene; 3DGS training starts from 0.1.
    knn : int
        Neighbours for the scale (3 in 3DGS).
    scale_factor : float
        Scale = factor * sqrt(mean squared distance to the ``knn`` nearest points). 3DGS uses 1
        (with opacity 0.1, then optimises); 0.5 keeps an untrained render sharp while the
        Gaussians still overlap into surfaces.
    min_scale_m, max_scale_m : float
        Clip of the scale (m); ``min_scale_m`` defaults to a fifth of ``voxel_m``. The upper clip
        keeps sparse far points from becoming metre-wide blobs.
    max_angular_scale : float
        The scale is also at most this angle (radians) times the point's distance to the camera
        of its sweep: sparse far points may grow, isolated near ones may not.
    min_points : int
        A voxel with fewer raw points is dropped when its nearest neighbours are farther than 3
        voxels (isolated returns: noise).
    moving_threshold_m : float
        A track whose box center moves more than this is moving (m).
    static_nodes : bool
        :func:`init_scene_from_lidar` makes every boxed track a node, the ones that do not move too
        (:func:`node_tracks`), and cuts their returns out of the static cloud: what object editing
        needs (the training's default). Off, they stay in the static cloud, for renderers that draw
        the static cloud alone.
    box_margin_m : float
        Growth of the boxes when cutting points out (m).

    Raises
    ------
    ValueError
        On out-of-range options (on construction).
    """

    voxel_m: float = 0.2
    node_voxel_m: float = 0.1
    opacity: float = 0.9
    knn: int = 3
    scale_factor: float = 0.5
    min_scale_m: float | None = None
    max_scale_m: float = 0.5
    max_angular_scale: float = 0.02
    min_points: int = 2
    moving_threshold_m: float = 0.5
    static_nodes: bool = False
    box_margin_m: float = 0.2

    def __post_init__(self) -> None:
        if not self.voxel_m > 0 or math.isinf(self.voxel_m):
            raise ValueError(f"voxel_m must be a positive finite size (m), got {self.voxel_m}")
        if not self.node_voxel_m > 0:
            raise ValueError(f"node_voxel_m must be > 0 metres, got {self.node_voxel_m}")
        if not 0 < self.opacity <= 1:
            raise ValueError(f"opacity must be in (0, 1], got {self.opacity}")
        if self.knn < 1:
            raise ValueError(f"knn must be >= 1, got {self.knn}")
        if not self.scale_factor > 0:
            raise ValueError(f"scale_factor must be > 0, got {self.scale_factor}")
        if not self.max_angular_scale > 0:
            raise ValueError(f"max_angular_scale must be > 0 radians, got {self.max_angular_scale}")
        if self.min_points < 1:
            raise ValueError(f"min_points must be >= 1, got {self.min_points}")
        if not 0 < self.min_scale <= self.max_scale_m:
            raise ValueError(f"need 0 < min_scale_m <= max_scale_m, got {self.min_scale}, {self.max_scale_m}")

    @property
    def min_scale(self) -> float:
        """``min_scale_m``, or a fifth of ``voxel_m`` when it is not set (m)."""
        return self.voxel_m / 5.0 if self.min_scale_m is None else float(self.min_scale_m)


def init_from_lidar(
    scene: Any,
    options: LidarInitOptions | None = None,
    *,
    frames: Iterable[int] | None = None,
    moving_objects: str = "drop",
) -> GaussianCloud:
    """Static Gaussians from a scene's lidar, colored by its images.

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
    options : LidarInitOptions, optional
        Voxel size, opacity, scales, noise and moving-object settings (default: its defaults).
    frames : iterable of int, optional
        Frames whose sweeps to use (default: all that have one).
    moving_objects : {"drop", "keep"}
        ``"drop"`` removes the points inside the boxes of moving tracks (see
        :func:`init_scene_from_lidar` to keep them as rigid nodes); ``"keep"`` accumulates every
        sweep as is (moving objects leave trails).

    Returns
    -------
    GaussianCloud
        Isotropic Gaussians, identity rotations, world coordinates.

    Raises
    ------
    InputError
        If the scene has no lidar point inside any camera image.
    ValueError
        On an unknown ``moving_objects``.
    """
    if moving_objects not in ("drop", "keep"):
        raise ValueError(f"moving_objects must be 'drop' or 'keep', got {moving_objects!r}")
    opts = options or LidarInitOptions()
    points, colors, frame = colored_lidar_points(scene, frames=frames)
    if len(points) == 0:
        raise InputError(f"scene {scene.id!r} ({scene.root}): no lidar point projects into any camera image")
    ranges = _ranges(scene, points, frame)
    if moving_objects == "drop":
        static, _ = _split_moving(
            scene, points, frame, moving_tracks(scene, opts.moving_threshold_m), opts.box_margin_m
        )
        points, colors, ranges = points[static], colors[static], ranges[static]
    return _cloud(opts, points, colors, ranges)


def init_scene_from_lidar(
    scene: Any,
    options: LidarInitOptions | None = None,
    *,
    frames: Iterable[int] | None = None,
    keep: Mapping[int, np.ndarray] | None = None,
) -> SceneGaussians:
    """Static Gaussians plus one rigid node per moving track (per track with ``static_nodes``).

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
    options : LidarInitOptions, optional
        As in :func:`init_from_lidar`; the object clouds use ``node_voxel_m``.
    frames : iterable of int, optional
        As in :func:`init_from_lidar`.
    keep : mapping of int to ndarray [N] bool, optional
        Per frame, the returns of its sweep to use (:func:`colored_lidar_points`); the tracked
        movers' returns must be kept for their nodes.

    Returns
    -------
    SceneGaussians
        Nodes in :func:`node_tracks`' order; a track with no return in its box has none.

    Raises
    ------
    InputError
        If the scene has no lidar point inside any camera image.
    """
    opts = options or LidarInitOptions()
    points, colors, frame = colored_lidar_points(scene, frames=frames, keep=keep)
    if len(points) == 0:
        raise InputError(f"scene {scene.id!r} ({scene.root}): no lidar point projects into any camera image")
    ranges = _ranges(scene, points, frame)
    tracks = node_tracks(scene, moving_threshold_m=opts.moving_threshold_m, static_nodes=opts.static_nodes)
    static, members = _split_moving(scene, points, frame, tracks, opts.box_margin_m)
    static_cloud = _cloud(opts, points[static], colors[static], ranges[static])
    nodes = []
    for ti, idx in members.items():
        track = tracks[ti]
        frame_to_k = {int(f): k for k, f in enumerate(np.asarray(track.frames))}
        local = np.empty((idx.size, 3))
        point_frame = frame[idx]
        for f in np.unique(point_frame):
            sel = point_frame == f
            T = np.asarray(track.object_to_world[frame_to_k[int(f)]], np.float64)
            local[sel] = apply_linear(points[idx[sel]] - T[:3, 3], T[:3, :3])
        cloud = _cloud(opts, local, colors[idx], ranges[idx], voxel_m=opts.node_voxel_m)
        nodes.append(
            RigidNode(
                track_id=str(track.id),
                class_name=str(track.class_name),
                cloud=cloud,
                frames=np.asarray(track.frames),
                object_to_world=np.asarray(track.object_to_world),
            )
        )
    return SceneGaussians(static=static_cloud, nodes=nodes)


def _knn_scale(points: np.ndarray, k: int) -> np.ndarray:
    """sqrt(mean squared distance to the k nearest other points), [N] float32."""
    n = len(points)
    if n < 2:
        return np.full(n, 0.1, np.float32)
    k_eff = min(k, n - 1)
    d, _ = cKDTree(points).query(points, k=k_eff + 1, workers=1)
    d = np.asarray(d, np.float64).reshape(n, -1)[:, 1:]
    return np.sqrt((d**2).mean(axis=1)).astype(np.float32)


def estimate_sky_color(
    scene: Any, *, frame: int = 0, top_fraction: float = 0.4, radius_px: int = 12
) -> np.ndarray:
    """Median color of the upper image where no lidar point lands (the sky, for a background).

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
    frame : int
        Frame to look at; the nearest frame with lidar is used if it has none.
    top_fraction : float
        Fraction of the image height (from the top) considered.
    radius_px : int
        Pixels around every lidar hit that count as covered.

    Returns
    -------
    ndarray [3] float32
        RGB in [0, 1]; the median of the top rows when every pixel is covered.
    """
    import cv2

    with_lidar = _lidar_frames(scene, None)
    if not with_lidar:
        image = _read_rgb_float(scene.frames[frame].image_path)
        top = image[: max(1, int(image.shape[0] * top_fraction))]
        return np.median(top.reshape(-1, 3), axis=0).astype(np.float32)
    f = min(with_lidar, key=lambda i: abs(i - frame))
    cam = scene.frames[f].camera
    image = _read_rgb_float(scene.frames[f].image_path)
    sweep = scene.lidar(f)
    covered = np.zeros((cam.height, cam.width), np.uint8)
    if sweep is not None and len(sweep.points):
        uv, z = cam.project(sweep.points)
        ij = np.floor(uv).astype(np.int64)
        ok = (z > 0) & (ij[:, 0] >= 0) & (ij[:, 0] < cam.width) & (ij[:, 1] >= 0) & (ij[:, 1] < cam.height)
        covered[ij[ok, 1], ij[ok, 0]] = 1
        covered = cv2.dilate(covered, np.ones((2 * radius_px + 1, 2 * radius_px + 1), np.uint8))
    rows = max(1, int(cam.height * top_fraction))
    free = covered[:rows] == 0
    pixels = image[:rows][free] if np.any(free) else image[:rows].reshape(-1, 3)
    return np.median(pixels, axis=0).astype(np.float32)
