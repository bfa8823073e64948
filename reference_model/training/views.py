"""Training views: a scene's frames at the training resolution with everything the losses compare to.

A :class:`TrainingView` holds one frame's camera (scaled to the training size), its raw image and
the edited images of each supervised weather, the sparse lidar depth, a sky mask and the pixels of
moving objects (for reporting). :func:`build_views` makes them from a scene (any object with the
attributes of :class:`wcbench.scenes.scene.Scene`: this library does not import the harness).

Images are float32 RGB in [0, 1]. Resizing uses area averaging, so a training frame is the mean of
the full-resolution pixels it covers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.image_io import read_rgb8, to_float
from wcbench.reference_model.scene_analysis.analysis import analyse_scene, anchor_depths
from wcbench.reference_model.scene_graph.lidar_init import moving_tracks
from wcbench.reference_model.transforms import lidar_depth, project_points

__all__ = [
    "TrainingView",
    "box_mask",
    "build_views",
    "resize_float",
    "scaled_view",
]


@dataclass
class TrainingView:
    """One frame at the training resolution.

    Attributes
    ----------
    frame : int
        Scene frame index.
    time : float
        Seconds since the scene's first frame.
    camera_to_world, world_to_camera : ndarray [4, 4] float64
        OpenCV axes.
    K : ndarray [3, 3] float64
        Intrinsics at ``width`` x ``height`` (pixel centers at +0.5).
    width, height : int
    images : dict of str to ndarray [H, W, 3] float32
        ``"clear"``: the raw frame; other weathers: their edited frame (supervision).
    depth : ndarray [H, W] float32 or None
        Lidar z-depth of the frame's own sweep (m), 0 where no point lands; None without a sweep.
    sky : ndarray [H, W] bool or None
        Sky pixels, when known or derived.
    solid : ndarray [H, W] bool or None
        Pixels a lidar return the scene analysis trusts lands in
        (:func:`~wcbench.reference_model.scene_analysis.analysis.solid_masks`): never sky, the scene
        is opaque there (outside the ego vehicle's body); None when the scene was not analysed.
    anchor_depth : ndarray [H, W] float32 or None
        Camera z (m) of the nearest static trusted return in each ``solid`` pixel
        (:func:`~wcbench.reference_model.scene_analysis.analysis.anchor_depths`), 0 elsewhere: where
        the lidar fill may place a Gaussian (``TrainConfig.lidar_fill``); None without ``solid``.
    dynamic : ndarray [H, W] bool
        Pixels inside the projected boxes of moving objects.
    ignore : ndarray [H, W] bool
        Pixels no loss looks at: the ego vehicle's own body, fixed in the frame (empty when none).
    """

    frame: int
    time: float
    camera_to_world: np.ndarray
    K: np.ndarray
    width: int
    height: int
    images: dict[str, np.ndarray]
    depth: np.ndarray | None = None
    sky: np.ndarray | None = None
    solid: np.ndarray | None = None
    anchor_depth: np.ndarray | None = None
    dynamic: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    ignore: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))

    @property
    def world_to_camera(self) -> np.ndarray:
        """[4, 4] inverse of the pose."""
        R, t = self.camera_to_world[:3, :3], self.camera_to_world[:3, 3]
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = R.T, -R.T @ t
        return out

    @property
    def center(self) -> np.ndarray:
        """[3] camera position (m)."""
        return np.asarray(self.camera_to_world[:3, 3], np.float64)


def scaled_view(view: TrainingView, divisor: int) -> TrainingView:
    """``view`` at 1/``divisor`` of its width and height (progressive resolution): images averaged over
    the pixels each covers, the lidar depth and the masks sampled (nearest), the intrinsics scaled.

    Parameters
    ----------
    view : TrainingView
    divisor : int
        >= 1; 1 returns ``view`` itself.

    Raises
    ------
    ValueError
        ``divisor`` below 1.
    """
    if divisor < 1:
        raise ValueError(f"divisor must be >= 1, got {divisor}")
    if divisor == 1:
        return view
    w, h = max(1, view.width // divisor), max(1, view.height // divisor)
    K = np.array(view.K, np.float64, copy=True)
    K[0] *= w / view.width  # pixel edges scale with the image: centres stay at +0.5
    K[1] *= h / view.height

    def nearest(a: np.ndarray) -> np.ndarray:
        return cv2.resize(a, (w, h), interpolation=cv2.INTER_NEAREST)

    def mask(a: np.ndarray) -> np.ndarray:
        return nearest(a.astype(np.uint8)).astype(bool) if a.shape == (view.height, view.width) else a

    return TrainingView(
        frame=view.frame, time=view.time, camera_to_world=view.camera_to_world, K=K, width=w, height=h,
        images={k: resize_float(img, (w, h)) for k, img in view.images.items()},
        depth=None if view.depth is None else nearest(view.depth),
        sky=None if view.sky is None else mask(view.sky),
        solid=None if view.solid is None else mask(view.solid),
        anchor_depth=None if view.anchor_depth is None else nearest(view.anchor_depth),
        dynamic=mask(view.dynamic), ignore=mask(view.ignore),
    )


def _read_mask(path: Any) -> np.ndarray:
    """A mask image (8-bit, nonzero = set) as uint8 [H, W]."""
    mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise InputError(f"{path}: cannot read mask image (missing or corrupt); expected an 8-bit PNG")
    return mask


def resize_float(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Float RGB [H, W, 3] (or uint8, divided by 255) resized to (width, height) by area averaging."""
    img = to_float(image) if image.dtype == np.uint8 else np.asarray(image, np.float32)
    if (img.shape[1], img.shape[0]) == tuple(size):
        return img
    interp = cv2.INTER_AREA if size[0] * size[1] < img.shape[0] * img.shape[1] else cv2.INTER_LINEAR
    return cv2.resize(img, tuple(size), interpolation=interp)


def box_mask(tracks: Sequence[Any], frame: int, world_to_camera: np.ndarray, K: np.ndarray, width: int,
             height: int) -> np.ndarray:
    """[H, W] bool: pixels inside the projected boxes of ``tracks`` at ``frame`` (boxes in front only)."""
    mask = np.zeros((height, width), np.uint8)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)
    for track in tracks:
        hit = np.nonzero(np.asarray(track.frames) == frame)[0]
        if hit.size == 0:
            continue
        k = int(hit[0])
        T = np.asarray(track.object_to_world[k], np.float64)
        corners = (signs * np.asarray(track.box_size[k], np.float64) / 2) @ T[:3, :3].T + T[:3, 3]
        uv, z = project_points(corners, world_to_camera, K)
        if not np.all(z > 0.1):
            continue  # partly behind the camera: its projection is not a box
        hull = cv2.convexHull(np.round(uv).astype(np.int32))
        cv2.fillConvexPoly(mask, hull, 1)
    return mask.astype(bool)


def build_views(
    scene: Any,
    *,
    size: tuple[int, int],
    supervision: Mapping[str, Sequence[np.ndarray]] | None = None,
    frames: Sequence[int] | None = None,
    derive_sky: bool = True,
    moving_threshold_m: float = 0.5,
    solid: bool = True,
    anchors: bool = False,
) -> tuple[list[TrainingView], dict[str, Any]]:
    """The training views of a scene.

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
        Or any object with its attributes.
    size : (int, int)
        Training (width, height).
    supervision : mapping of str to sequence of ndarray, optional
        Edited frames per weather (uint8 or float RGB, any size, one per scene frame); resized to
        ``size``.
    frames : sequence of int, optional
        Frames to build (default all).
    derive_sky : bool
        Segment the sky (:mod:`wcbench.reference_model.scene_analysis.sky`: from the image, checked
        by the lidar) when the scene ships no sky masks, and find the ego vehicle's body
        (:mod:`~wcbench.reference_model.scene_analysis.ego`), whose pixels no loss looks at. Needs
        the scene's lidar; without any, no sky is derived.
    moving_threshold_m : float
        Tracks moving more than this (m) make the ``dynamic`` masks.
    solid : bool
        Mark the pixels a trusted lidar return lands in (``TrainingView.solid``, from the scene
        analysis); only the opacity loss's lidar term and the lidar fill read them
        (``TrainConfig.opacity_lidar``, ``TrainConfig.lidar_fill``), so a training without either
        leaves them ``None``.
    anchors : bool
        With ``solid``, also the depth of the static returns there (``TrainingView.anchor_depth``,
        read by the lidar fill alone: ``TrainConfig.lidar_fill``).

    Returns
    -------
    views : list of TrainingView
    facts : dict
        How the views were made (sky mask source, frames with lidar depth), for ``info.json``.
    """
    width, height = int(size[0]), int(size[1])
    indices = list(range(len(scene.frames))) if frames is None else list(frames)
    supervision = dict(supervision or {})
    for weather, seq in supervision.items():
        if len(seq) != len(scene.frames):
            raise ValueError(f"supervision {weather!r}: {len(seq)} frames for a scene of {len(scene.frames)}")
    t0 = float(scene.frames[0].timestamp)
    tracks = moving_tracks(scene, moving_threshold_m)
    shipped = all(scene.frames[k].sky_mask_path is not None for k in indices)
    has_lidar = any(f.lidar_path is not None for f in scene.frames)
    analysis = analyse_scene(scene) if (derive_sky and has_lidar) else None
    ignore = analysis.ego_mask((width, height)) if analysis is not None else np.zeros((height, width), bool)
    anchor_maps: dict[int, np.ndarray] = {}
    if analysis is not None and solid and anchors:
        anchor_maps = dict(zip(indices, anchor_depths(analysis.views, analysis.returns, (width, height), indices)))
    views = []
    for k in indices:
        f = scene.frames[k]
        cam = f.camera
        sx, sy = width / cam.width, height / cam.height
        K = np.diag([sx, sy, 1.0]) @ np.asarray(cam.K, np.float64)
        c2w = np.asarray(cam.camera_to_world, np.float64)
        w2c = np.linalg.inv(c2w)
        images = {"clear": resize_float(read_rgb8(f.image_path), (width, height))}
        for weather, seq in supervision.items():
            images[weather] = resize_float(np.asarray(seq[k]), (width, height))
        sweep = scene.lidar(f)
        depth = None if sweep is None else lidar_depth(sweep.points, w2c, K, width, height)
        dynamic = box_mask(tracks, k, w2c, K, width, height)
        sky = None
        if f.sky_mask_path is not None:
            sky = cv2.resize(_read_mask(f.sky_mask_path), (width, height), interpolation=cv2.INTER_NEAREST) > 0
        elif analysis is not None:
            sky = analysis.sky_mask(k, (width, height)) & ~dynamic
        hits = None if analysis is None or not solid else analysis.solid_mask(k, (width, height)) & ~ignore
        if hits is not None and sky is not None:
            hits &= ~sky  # a shipped mask has the last word
        anchor = None if hits is None or k not in anchor_maps else np.where(hits, anchor_maps[k], np.float32(0))
        views.append(TrainingView(frame=k, time=float(f.timestamp) - t0, camera_to_world=c2w, K=K, width=width,
                                  height=height, images=images, depth=depth, sky=sky, solid=hits, anchor_depth=anchor,
                                  dynamic=dynamic, ignore=ignore.copy()))
    facts: dict[str, Any] = {
        "size": [width, height],
        "sky_masks": "shipped" if shipped else ("segmented: from the image, checked by the lidar"
                                                if analysis is not None else "none"),
        "frames_with_lidar_depth": sum(v.depth is not None for v in views),
        "moving_tracks": len(tracks),
        "ignored_pixels": round(float(ignore.mean()), 4),
    }
    if analysis is not None:
        facts["scene_analysis"] = analysis.record()
    return views, facts
