"""All the scene analyses of a scene, run once and shared by the weather editor and training.

:func:`analyse_scene` reads a scene's frames at the analysis size, labels its lidar returns
(:mod:`.motion`), registers them to the camera (a time offset found from the frames' own edges,
Levinson & Thrun 2013; :mod:`.register`: every later step and the editor's surfaces read the
registered returns), marks the pixels the returns land in (*solid*: never sky, :func:`solid_masks`),
segments the sky (:mod:`.sky`; the scene's own masks when it ships them), finds the ego
vehicle's body (:mod:`.ego`) and the clear frames' sun (:mod:`.sun`). The result is kept for the
last scenes analysed in this process (the editor and the training views of one run ask for the
same scene), keyed by the scene's folder, frames and analysis size.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.progress import announce
from wcbench.reference_model.scene_analysis.ego import ego_mask
from wcbench.reference_model.scene_analysis.motion import LidarReturns, classify_returns
from wcbench.reference_model.scene_analysis.reach import LidarReach, lidar_reach
from wcbench.reference_model.scene_analysis.register import LidarTimeOffset, fit_time_offset
from wcbench.reference_model.scene_analysis.sky import SkySegmentation, segment_sky, sky_matte
from wcbench.reference_model.scene_analysis.sun import SunEstimate, fit_sun
from wcbench.reference_model.scene_analysis.views import (
    ANALYSIS_WIDTH,
    AnalysisViews,
    PointColumns,
    analysis_size,
    build_analysis_views,
    resample_mask,
)
from wcbench.reference_model.transforms import lidar_depth

__all__ = ["SceneAnalysis", "analyse_scene", "anchor_depths", "clear_analysis_cache", "shipped_sky", "solid_masks"]

#: How many analysed scenes this process keeps.
_KEEP = 2
_CACHE: OrderedDict[tuple[Any, ...], SceneAnalysis] = OrderedDict()


@dataclass
class SceneAnalysis:
    """What :func:`analyse_scene` found (all maps at ``views.size`` unless a method says otherwise).

    Attributes
    ----------
    views : AnalysisViews
    returns : LidarReturns
        Registered to the camera by ``lidar_offset``.
    solid : list of ndarray [H, W] bool
        Per frame, the pixels a lidar return lands in (:func:`solid_masks`): never sky.
    sky : SkySegmentation
    ego : ndarray [H, W] bool
        The ego vehicle's body (the same in every frame; all false when there is none).
    sun : SunEstimate
        The clear frames' sun and what casts shadows (no direction when none is seen).
    lidar_offset : LidarTimeOffset
        The lidar's time offset to the camera that ``returns`` are moved by (0 s without support).
    reach : LidarReach or None
        How far and how high the lidar sees (:func:`~.reach.lidar_reach`; ``None``: too few far
        returns to tell).
    facts : dict
        For ``info.json``: counts, the registration, the sky's and the ego mask's facts, timings.
    """

    views: AnalysisViews
    returns: LidarReturns
    solid: list[np.ndarray]
    sky: SkySegmentation
    ego: np.ndarray
    sun: SunEstimate
    lidar_offset: LidarTimeOffset = field(default_factory=lambda: LidarTimeOffset(0.0))
    reach: LidarReach | None = None
    facts: dict[str, Any] = field(default_factory=dict)

    def record(self) -> dict[str, Any]:
        """What the analysis found, for ``info.json`` (its facts without the timings)."""
        return {k: v for k, v in self.facts.items() if k != "seconds"}

    def sky_mask(self, k: int, size: tuple[int, int] | None = None) -> np.ndarray:
        """[H, W] bool sky of frame ``k`` at ``size`` (default the analysis size)."""
        return resample_mask(self.sky.masks[k], size or self.views.size)

    def ego_mask(self, size: tuple[int, int] | None = None) -> np.ndarray:
        """[H, W] bool ego-vehicle body at ``size`` (default the analysis size)."""
        return resample_mask(self.ego, size or self.views.size)

    def solid_mask(self, k: int, size: tuple[int, int] | None = None) -> np.ndarray:
        """[H, W] bool: pixels of frame ``k`` at ``size`` that a lidar return lands in (when shrinking,
        a pixel is solid when any analysis pixel it overlaps is; when enlarging, nearest)."""
        solid = self.solid[k]
        if size is None or tuple(size) == self.views.size:
            return solid.copy()
        w, h = int(size[0]), int(size[1])
        if w * h < solid.size:
            return cv2.resize(solid.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) > 0
        return cv2.resize(solid.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0

    def sky_matte(self, k: int, image: np.ndarray) -> np.ndarray:
        """[H, W] float32 soft sky matte of frame ``k`` at the size of ``image`` (the frame there,
        display RGB): :func:`~.sky.sky_matte` of the resampled mask."""
        size = (image.shape[1], image.shape[0])
        radius = max(1, round(2 * image.shape[0] / 270))
        return sky_matte(self.sky_mask(k, size), image, self.solid_mask(k, size), radius=radius)


#: A static return of a sweep more than this many frames away marks a pixel solid only beyond
#: this distance (m) from the camera: returns of near structure registered from far-off sweeps land
#: pixels off (a pole 3 m away, 15 px at 480 px wide on pandaset_002_right), farther ones do not.
_NEAR_FRAMES, _FAR_M = 2, 20.0


def _static_pool(returns: LidarReturns) -> tuple[dict[int, np.ndarray], np.ndarray]:
    """Per sweep its static returns, and all of them together."""
    static = {j: p[returns.static_mask(j)] for j, p in returns.points.items()}
    everything = np.concatenate(list(static.values())) if static else np.zeros((0, 3))
    return static, everything


def _trusted_static(views: AnalysisViews, static: dict[int, np.ndarray], everything: np.ndarray,
                    k: int) -> np.ndarray:
    """[M, 3] the static returns :func:`solid_masks` trusts in frame ``k``: those of the sweeps within
    ``_NEAR_FRAMES`` frames of k (twice that for a frame without its own sweep) and those of every
    sweep farther than ``_FAR_M`` from frame k's camera."""
    # a frame without its own sweep takes the static returns of the nearest sweeps on either side
    reach = _NEAR_FRAMES if k in static else 2 * _NEAR_FRAMES
    near = [static[j] for j in static if abs(j - k) <= reach]
    far = everything[np.einsum("ij,ij->i", everything - views.center(k), everything - views.center(k))
                     > _FAR_M ** 2] if len(everything) else everything
    return np.concatenate([far, *near]) if (near or len(far)) else np.zeros((0, 3))


def solid_masks(views: AnalysisViews, returns: LidarReturns) -> tuple[list[np.ndarray], list[int]]:
    """Per frame k, the pixels a lidar return lands in: every return of frame k's own sweep (of the
    nearest sweep within two frames without one) but its ghosts (:meth:`LidarReturns.frame_dynamic`),
    the static returns of the sweeps within ``_NEAR_FRAMES`` frames of k (twice that for a frame
    without its own sweep), and the static returns of every sweep farther than ``_FAR_M`` from
    frame k's camera (isolated returns excluded); and the frames none lands in.

    Returns
    -------
    solid : list of ndarray [H, W] bool
    without : list of int
    """
    static, everything = _static_pool(returns)
    solid, without = [], []
    for k in range(len(views)):
        pts = np.concatenate([_trusted_static(views, static, everything, k), returns.frame_dynamic(k)])
        hits = views.hit_map(PointColumns.of(pts), k)
        solid.append(hits)
        if not hits.any():
            without.append(k)
    return solid, without


def anchor_depths(views: AnalysisViews, returns: LidarReturns, size: tuple[int, int],
                  frames: Sequence[int]) -> list[np.ndarray]:
    """Per frame k of ``frames``, [H, W] float32 camera z (m) at ``size`` (width, height) of the
    nearest static return :func:`solid_masks` trusts in k, 0 where none lands: where the scene holds
    still structure for certain, and how far (the training's lidar fill places Gaussians there,
    ``TrainConfig.lidar_fill``). A moving thing's returns are left out: a Gaussian of the static
    scene at one would stay where the thing was.
    """
    static, everything = _static_pool(returns)
    w, h = int(size[0]), int(size[1])
    scale = np.diag([w / views.width, h / views.height, 1.0])  # pixel edges scale: centres stay at +0.5
    return [lidar_depth(_trusted_static(views, static, everything, k), views.world_to_camera(k),
                        scale @ np.asarray(views.K[k], np.float64), w, h) for k in frames]


def any_sweep_masks(views: AnalysisViews, returns: LidarReturns) -> list[np.ndarray]:
    """Per frame k, the pixels any static return of any sweep (and frame k's own returns) lands in:
    :func:`solid_masks` without its trust in time and distance, so with the copies of a structure
    that the other sweeps' registration puts 1-3 px off (a pole, a wire seen from far away).

    Returns
    -------
    list of ndarray [H, W] bool
    """
    cols = PointColumns.of(returns.static_points())
    out = []
    for k in range(len(views)):
        hits = views.hit_map(cols, k)
        own = returns.frame_dynamic(k)
        if len(own):
            hits |= views.hit_map(PointColumns.of(own), k)
        out.append(hits)
    return out


def shipped_sky(scene: Any, size: tuple[int, int]) -> SkySegmentation | None:
    """The scene's own sky masks at ``size`` (nearest-neighbour resize, 255 = sky) when every frame
    ships one, else ``None``.

    Raises
    ------
    InputError
        A mask that is not a readable image.
    """
    paths = [f.sky_mask_path for f in scene.frames]
    if not paths or any(p is None for p in paths):
        return None
    masks = []
    for p in paths:
        m = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if m is None:
            raise InputError(f"{p}: not a readable image (a sky mask, 8-bit grayscale, was expected)")
        masks.append(cv2.resize(m, tuple(size), interpolation=cv2.INTER_NEAREST) > 127)
    stack = np.stack(masks)
    return SkySegmentation(masks=stack, probability=stack.astype(np.float32), alpha=stack.astype(np.float32),
                           facts={"source": "shipped sky masks"})


def _key(scene: Any, size: tuple[int, int]) -> tuple[Any, ...]:
    return (str(getattr(scene, "root", "")), str(getattr(scene, "id", "")), len(scene.frames),
            tuple(str(f.image_path) for f in scene.frames), tuple(size))


def clear_analysis_cache() -> None:
    """Forget the analysed scenes of this process."""
    _CACHE.clear()


def analyse_scene(scene: Any, *, width: int = ANALYSIS_WIDTH, log: Any = announce) -> SceneAnalysis:
    """Analyse ``scene`` at ``width`` px wide (see the module docstring), or return this process's
    earlier analysis of it.

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
        Or any object with its attributes (frames with cameras and image paths, ``lidar(k)``,
        tracks, ``up``, ``class_names``).
    width : int
        Analysis width (px); the frames' own when they are narrower.
    log : callable or None
        Told what is being done (one line; default: on stderr unless ``WCBENCH_PROGRESS=0``).

    Returns
    -------
    SceneAnalysis
    """
    size = analysis_size(scene.image_size, width)
    key = _key(scene, size)
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    if log is not None:
        log(f"analysing scene {getattr(scene, 'id', '')} ({len(scene.frames)} frames at {size[0]}x{size[1]}): "
            "moving returns, registration, sky, ego vehicle, sun")
    t0 = time.perf_counter()
    views = build_analysis_views(scene, size)
    t1 = time.perf_counter()
    returns = classify_returns(scene, views)
    t_reg = time.perf_counter()
    offset = fit_time_offset(views, returns)
    returns = offset.apply(views, returns)
    t2 = time.perf_counter()
    static = returns.static_points()
    solid, without = solid_masks(views, returns)
    t3 = time.perf_counter()
    sky = shipped_sky(scene, size) or segment_sky(views, solid, untrusted=any_sweep_masks(views, returns))
    t4 = time.perf_counter()
    ego, ego_facts = ego_mask(views, static)
    t5 = time.perf_counter()
    sun = fit_sun(views, returns, sky.masks)
    reach = lidar_reach(views, returns)
    t6 = time.perf_counter()
    facts = {"size": list(size), "returns": returns.facts, "lidar_time_offset": offset.facts, "sky": sky.facts,
             **ego_facts, "sun": sun.facts, "lidar_reach": None if reach is None else reach.facts(),
             "frames_without_lidar_in_view": without,
             "seconds": {"views": round(t1 - t0, 2), "returns": round(t_reg - t1, 2),
                         "register": round(t2 - t_reg, 2), "solid": round(t3 - t2, 2),
                         "sky": round(t4 - t3, 2), "ego": round(t5 - t4, 2), "sun": round(t6 - t5, 2)}}
    out = SceneAnalysis(views=views, returns=returns, solid=solid, sky=sky, ego=ego, sun=sun, lidar_offset=offset,
                        reach=reach, facts=facts)
    _CACHE[key] = out
    while len(_CACHE) > _KEEP:
        _CACHE.popitem(last=False)
    return out
