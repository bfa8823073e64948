"""Per-pixel surface maps of one view: the scene's lidar surfaces rendered by the project's rasterizer.

:func:`surface_maps` rasterizes the :class:`~.surfaces.SurfaceScene` of a frame with its attribute
channels (normal, ground, open, puddle, track) and depth, then completes what the lidar does not
reach (docs/design.md §7):

* the **sky**: the scene's sky mask when it ships one, else the lidar-derived one
  (:func:`~wcbench.reference_model.training.views.derive_sky_mask`); infinitely far;
* the rest by :func:`~wcbench.reference_model.scene_graph.completion.complete_distance`: below the
  horizon the **ground plane** under the camera, its attributes evaluated at the ray's intersection
  (so they stay anchored in the world); above it a **vertical wall** rising from the surface below.

:func:`mirror_render` renders the non-ground surfaces mirrored about that ground plane: what a wet
road reflects at each pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
import torch

from wcbench.reference_model.appearance.shading import linear_to_srgb, srgb_to_linear
from wcbench.reference_model.appearance.surfaces import SurfaceScene
from wcbench.reference_model.model.sky import view_directions
from wcbench.reference_model.raster.rasterizer import rasterize
from wcbench.reference_model.scene_graph.completion import FILL_GROUND, FILL_SKY, FILL_WALL, complete_distance
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud

__all__ = ["SurfaceMaps", "coverage_sky", "mirror_render", "refine", "surface_maps"]

#: Accumulated opacity above which a pixel counts as covered by the lidar surfaces.
_COVERED = 0.5


@dataclass
class SurfaceMaps:
    """Per-pixel surfaces of a view (all [H, W] unless said).

    Attributes
    ----------
    normal : ndarray [H, W, 3] float32
        Unit world normal (the sky: ``-ray``).
    distance : ndarray float32
        Distance along the ray (m); ``inf`` for the sky.
    ground, open, puddle, track : ndarray float32
        The surface attributes (:data:`~.surfaces.ATTRIBUTES`), in [0, 1].
    sky : ndarray bool
    covered : ndarray bool
        Where the lidar surfaces were drawn (elsewhere the maps are completed).
    rays : ndarray [H, W, 3] float32
        Unit world ray directions.
    ground_height : float
        Height of the ground plane under the camera (m along ``up``).
    """

    normal: np.ndarray
    distance: np.ndarray
    ground: np.ndarray
    open: np.ndarray
    puddle: np.ndarray
    track: np.ndarray
    sky: np.ndarray
    covered: np.ndarray
    rays: np.ndarray
    ground_height: float


def _rays(camera: Any) -> tuple[np.ndarray, np.ndarray]:
    """(unit world rays [H, W, 3] of ``camera``'s pixels, the camera depth of each unit ray [H, W]),
    float64."""
    c2w = np.asarray(camera.camera_to_world, np.float64)
    rays = view_directions(c2w, camera.K, int(camera.width), int(camera.height)).astype(np.float64)
    return rays, rays @ c2w[:3, 2]


def _rasterize(cloud: GaussianCloud, channels: np.ndarray, camera: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(channels / alpha [H, W, C], alpha [H, W], camera depth [H, W]) of ``cloud`` seen by ``camera``."""
    out = rasterize(torch.from_numpy(cloud.means), torch.from_numpy(cloud.quats), torch.from_numpy(cloud.scales),
                    torch.from_numpy(cloud.opacities), torch.from_numpy(np.ascontiguousarray(channels, np.float32)),
                    np.asarray(camera.world_to_camera, np.float64), np.asarray(camera.K, np.float64),
                    int(camera.width), int(camera.height))
    alpha = out.alpha.numpy()
    assert out.depth is not None
    return out.color.numpy() / np.maximum(alpha, 1e-6)[..., None], alpha, out.depth.numpy()


def coverage_sky(alpha: np.ndarray, ray_up: np.ndarray, *, image: np.ndarray | None = None,
                 dilate_px: int = 2) -> np.ndarray:
    """Sky pixels of a view without a sky mask, from the render of its lidar surfaces: above the
    horizon, no surface drawn within ``dilate_px`` pixels, connected to the top of the image (holes
    between facades are not sky). [H, W] bool.

    The same rule as :func:`~wcbench.reference_model.training.views.derive_sky_mask`, which projects
    every raw lidar point instead; the rendered voxels make it one mask per view at no extra cost.
    Far voxels render wider than what they hit, so the rule stops short of the skyline; with the
    frame (``image``, display RGB [H, W, 3]) the sky grows into the pixels next to it that no
    surface covers (accumulated opacity under 0.5) and that have the sky's colour (each channel
    within 3 median absolute deviations of its median over the sky found, at least 0.06).
    """
    solid = (alpha > 0.05).astype(np.uint8)
    if dilate_px > 0:
        solid = cv2.dilate(solid, np.ones((2 * dilate_px + 1, 2 * dilate_px + 1), np.uint8))
    candidate = (solid == 0) & (ray_up > 0.0)
    n, labels = cv2.connectedComponents(candidate.astype(np.uint8), connectivity=4)
    top = np.unique(labels[0][candidate[0]])
    sky = np.isin(labels, top[top > 0]) if n > 1 else candidate
    if image is None or not sky.any():
        return sky
    colors = np.asarray(image, np.float32)[sky]
    median = np.median(colors, axis=0)
    spread = np.maximum(3.0 * np.median(np.abs(colors - median), axis=0), 0.06)
    alike = np.all(np.abs(np.asarray(image, np.float32) - median) <= spread, axis=-1)
    grow = sky | ((alpha < _COVERED) & (ray_up > 0.0) & alike)
    n, labels = cv2.connectedComponents(grow.astype(np.uint8), connectivity=4)
    seeds = np.unique(labels[sky])
    return np.isin(labels, seeds[seeds > 0])


def surface_maps(surfaces: SurfaceScene, index: int, camera: Any, sky: np.ndarray | None, *,
                 image: np.ndarray | None = None) -> SurfaceMaps:
    """The completed surface maps of frame ``index`` seen by ``camera`` (see the module docstring).

    Parameters
    ----------
    surfaces : SurfaceScene
    index : int
        Frame (places the moving nodes).
    camera : wcbench.scenes.scene.Camera
        The view, at the size the maps are wanted.
    sky : ndarray [H, W] bool, optional
        The view's sky pixels (the scene's mask); ``None``: :func:`coverage_sky` of the render.
    image : ndarray [H, W, 3], optional
        The frame at that size (display RGB): :func:`coverage_sky` grows the sky by its colour.

    Returns
    -------
    SurfaceMaps
    """
    cloud, attrs = surfaces.at_frame(index)
    values, alpha, depth = _rasterize(cloud, attrs, camera)
    rays, z_per_m = _rays(camera)
    up = surfaces.up
    center = np.asarray(camera.center, np.float64)
    if sky is None:
        sky = coverage_sky(alpha, rays @ up, image=image)
    covered = (alpha > _COVERED) & ~sky
    distance = np.where(covered, depth / np.maximum(z_per_m, 1e-9), np.inf)
    normal = values[..., :3]
    normal = normal / np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-6)
    fields = {name: np.clip(values[..., 3 + i], 0.0, 1.0)
              for i, name in enumerate(("ground", "open", "puddle", "track"))}
    ground_h = float(surfaces.ground_height(center[None])[0])
    distance, kind, source = complete_distance(distance, covered, sky, rays, center, up, ground_h,
                                               forward=np.asarray(camera.camera_to_world, np.float64)[:3, 2])
    fill_ground = kind == FILL_GROUND
    if np.any(fill_ground):  # attributes evaluated where the ray meets the plane: anchored in the world
        hit = center + rays[fill_ground] * np.where(np.isfinite(distance[fill_ground]), distance[fill_ground],
                                                     1e4)[:, None]
        normal[fill_ground] = up
        fields["ground"][fill_ground] = 1.0
        fields["open"][fill_ground] = 1.0
        fields["puddle"][fill_ground] = surfaces.puddle_field(hit)
        fields["track"][fill_ground] = surfaces.track_field(hit)
    wall = kind == FILL_WALL
    if np.any(wall):  # the wall's normal is that of the surface it rises from
        rr, cc = np.nonzero(wall)
        normal[rr, cc] = normal[source[rr, cc], cc]
        for name in fields:
            fields[name][rr, cc] = 0.0
    sky = sky | (kind == FILL_SKY)
    normal[sky] = -rays[sky]
    for name in fields:
        fields[name][sky] = 0.0
    return SurfaceMaps(normal=normal.astype(np.float32), distance=distance.astype(np.float32),
                       ground=fields["ground"], open=fields["open"], puddle=fields["puddle"], track=fields["track"],
                       sky=sky, covered=covered, rays=rays.astype(np.float32), ground_height=ground_h)


def mirror_render(surfaces: SurfaceScene, index: int, camera: Any, ground_height: float, exposure: float,
                  background: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What the ground plane mirrors at each pixel: the non-ground lidar surfaces reflected about it.

    Rendering the surfaces mirrored about the plane from the real camera gives, at a pixel on the
    plane, what the reflected ray meets (for isotropic Gaussians, mirroring their centres is exact).
    It is rendered at half the camera's size and resized up (a wet surface blurs its reflection).

    Parameters
    ----------
    surfaces : SurfaceScene
    index : int
    camera : Camera
    ground_height : float
        The plane's height along ``up`` (m).
    exposure : float
        Linear-light factor on the surfaces' clear colours (the weather's overcast exposure).
    background : ndarray [3]
        What the reflected ray sees where it meets no surface (the weather's sky), display RGB.

    Returns
    -------
    image : ndarray [H, W, 3] float32
        Display RGB of the reflection.
    distance : ndarray [H, W] float32
        Length of the reflected path from the camera (m; ``inf`` where it meets no surface).
    """
    cloud, attrs = surfaces.at_frame(index)
    up = surfaces.up
    keep = attrs[:, 3] < 0.5
    means = cloud.means[keep].astype(np.float64)
    h = means @ up - ground_height
    keep_above = h > 0.05
    mirrored = means[keep_above] - 2.0 * np.outer(h[keep_above], up)
    sub = GaussianCloud(means=mirrored, quats=cloud.quats[keep][keep_above], scales=cloud.scales[keep][keep_above],
                        opacities=cloud.opacities[keep][keep_above], colors=cloud.colors[keep][keep_above])
    if len(sub) == 0:
        hh, ww = int(camera.height), int(camera.width)
        return np.broadcast_to(np.asarray(background, np.float32), (hh, ww, 3)).copy(), np.full((hh, ww), np.inf,
                                                                                               np.float32)
    # at half the size: a reflection is blurred by the wet surface (a puddle's sharp one by little)
    w, h = int(camera.width), int(camera.height)
    half = replace(camera, K=np.diag([0.5, 0.5, 1.0]) @ np.asarray(camera.K, np.float64), width=max(1, w // 2),
                   height=max(1, h // 2))
    half = replace(half, K=np.diag([half.width / (0.5 * w), half.height / (0.5 * h), 1.0]) @ half.K)
    color, alpha, depth = _rasterize(sub, linear_to_srgb(srgb_to_linear(sub.colors) * exposure), half)
    _, z_per_m = _rays(half)
    a = np.clip(alpha, 0.0, 1.0)[..., None]
    image = color * a + np.asarray(background, np.float32) * (1.0 - a)
    distance = np.where(alpha > _COVERED, depth / np.maximum(z_per_m, 1e-9), 1e6).astype(np.float32)
    image = cv2.resize(np.clip(image, 0.0, 1.0).astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    distance = cv2.resize(distance, (w, h), interpolation=cv2.INTER_LINEAR)
    return image, np.where(distance >= 1e6, np.inf, distance).astype(np.float32)


def refine(mask: np.ndarray, guide: np.ndarray, *, radius: int, eps: float = 1e-3) -> np.ndarray:
    """A map snapped to the image's edges: OpenCV's guided filter (He et al. 2013) with the frame as guide.

    Parameters
    ----------
    mask : ndarray [H, W] float
    guide : ndarray [H, W, 3] float32
        The raw frame, display RGB in [0, 1].
    radius : int
        Window radius (px); 0 returns ``mask``.
    eps : float
        Regularisation (edges weaker than sqrt(eps) are smoothed over).

    Returns
    -------
    ndarray [H, W] float32 in [0, 1]
    """
    if radius <= 0:
        return np.asarray(mask, np.float32)
    out = cv2.ximgproc.guidedFilter(np.ascontiguousarray(guide, np.float32), np.ascontiguousarray(mask, np.float32),
                                    radius, eps)
    return np.clip(out, 0.0, 1.0).astype(np.float32)
