"""Per-pixel surface maps of one view: the scene's lidar surfaces rendered by the project's rasterizer.

:func:`surface_maps` rasterizes the :class:`~.surfaces.SurfaceScene` of a frame with its attribute
channels (normal, ground, open, puddle, track) and depth, then completes what the lidar does not
reach (docs/design.md §7):

* the **sky**: given (the scene's mask when it ships one, else the scene analysis's segmentation,
  :mod:`wcbench.reference_model.scene_analysis.sky`), with its soft matte; infinitely far;
* the rest by :func:`~wcbench.reference_model.scene_graph.completion.complete_distance`: below the
  horizon the **fitted ground** (the 2 m cells' heights, continued by their plane), its
  attributes evaluated at the ray's intersection (so they stay anchored in the world); above it a
  **vertical wall** rising from the surface below (the scene's facade plane behind it where one
  is fitted, else the closing's depth), facing the camera horizontally: structure above
  the lidar's reach keeps its appearance, nothing settles on it.

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

__all__ = ["SurfaceMaps", "mirror_render", "refine", "surface_maps"]

#: Accumulated opacity above which a pixel counts as covered by the lidar surfaces.
_COVERED = 0.5
#: A tracked object's box face stands for it where the lidar surfaces lie this far behind it (m).
_BOX_SLACK_M = 0.3


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
    sky_alpha : ndarray float32
        Soft sky matte in [0, 1] (1 inside the sky, fractional along its edges).
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
    sky_alpha: np.ndarray
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


def _box_shells(surfaces: SurfaceScene, index: int, camera: Any, rays: np.ndarray, center: np.ndarray,
                distance: np.ndarray, normal: np.ndarray, fields: dict[str, np.ndarray], sky: np.ndarray) -> np.ndarray:
    """Where a pixel inside a tracked object's silhouette sees the lidar surfaces more than 0.3 m
    behind the object's box (the lidar sampled the object sparsely and what lies behind or under it
    shows through), the box's face stands for the object: its distance and face normal, open to
    the sky, not ground; where it sees a lidar surface on the object (within 0.3 m of its box), the
    box's face gives the normal (a car's panels are smooth; a stray return's normal is not)
    (``distance``, ``normal`` and ``fields`` are updated in place). A car's roof takes snow, its
    doors do not, and the road under it stays hidden. Returns the pixels changed.

    The silhouette is the convex hull of the projections of the surface Gaussians inside the box
    (grown by 0.1 m), so the air around a car inside its box keeps what lies behind it; the ray's
    entry into the box is found by the slab method in the box frame.
    """
    changed = np.zeros(distance.shape, bool)
    boxes = surfaces.boxes_at(index)
    cloud, _ = surfaces.at_frame(index)
    if not boxes or len(cloud) == 0:
        return changed
    h, w = distance.shape
    means = np.asarray(cloud.means, np.float64)
    w2c = np.asarray(camera.world_to_camera, np.float64)
    K = np.asarray(camera.K, np.float64)
    for T, size in boxes:
        R, t = T[:3, :3], T[:3, 3]
        half = np.asarray(size, np.float64) / 2.0
        o = R.T @ (center - t)
        if np.all(np.abs(o) <= half):
            continue  # the camera inside a box (the ego vehicle's own track): no shell
        near = surfaces.near(index, t, float(np.linalg.norm(half + 0.1)))
        if near.size < 3:
            continue
        local = (means[near] - t) @ R
        inside = near[np.all(np.abs(local) <= half + 0.1, axis=1)]
        if inside.size < 3:
            continue
        cam = means[inside] @ w2c[:3, :3].T + w2c[:3, 3]
        cam = cam[cam[:, 2] > 0.1]
        if len(cam) < 3:
            continue
        uv = np.stack([K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2], K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]], 1)
        if uv[:, 0].max() < 0 or uv[:, 0].min() >= w or uv[:, 1].max() < 0 or uv[:, 1].min() >= h:
            continue
        hull = cv2.convexHull(np.clip(np.round(uv - 0.5), -4 * w, 4 * w).astype(np.int32))
        silhouette = np.zeros((h, w), np.uint8)
        cv2.fillConvexPoly(silhouette, hull, 1)
        rr, cc = np.nonzero(silhouette.astype(bool) & ~sky)
        if rr.size == 0:
            continue
        d = rays[rr, cc] @ R  # ray directions in the box frame
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - o) / d, (half - o) / d
        near = np.nanmax(np.minimum(t1, t2), axis=1)
        far = np.nanmin(np.maximum(t1, t2), axis=1)
        enters = (far >= near) & (near > 0.0)
        seen = distance[rr, cc]
        behind = enters & (near + _BOX_SLACK_M < seen)  # the lidar's surfaces show through the object
        on = np.zeros_like(enters)  # the lidar's surface lies on the object: the box's face is its shape
        finite = enters & np.isfinite(seen)
        on[finite] = np.all(np.abs(o + d[finite] * seen[finite, None]) <= half + _BOX_SLACK_M, axis=1)
        hit = behind | on
        if not hit.any():
            continue
        rr, cc, near, d, behind = rr[hit], cc[hit], near[hit], d[hit], behind[hit]
        entry = o + d * near[:, None]
        axis = np.argmax(np.abs(entry) / half, axis=1)  # the face the ray enters through
        face = np.zeros((rr.size, 3))
        face[np.arange(rr.size), axis] = np.sign(entry[np.arange(rr.size), axis])
        normal[rr, cc] = face @ R.T
        distance[rr[behind], cc[behind]] = near[behind]
        fields["ground"][rr, cc] = 0.0
        fields["open"][rr, cc] = 1.0
        fields["puddle"][rr, cc] = 0.0
        fields["track"][rr, cc] = 0.0
        changed[rr, cc] = True
    return changed


def surface_maps(surfaces: SurfaceScene, index: int, camera: Any, sky: np.ndarray, *,
                 sky_alpha: np.ndarray | None = None, solid: np.ndarray | None = None) -> SurfaceMaps:
    """The completed surface maps of frame ``index`` seen by ``camera`` (see the module docstring).

    Parameters
    ----------
    surfaces : SurfaceScene
    index : int
        Frame (places the moving nodes and the frame's own dynamic returns).
    camera : wcbench.scenes.scene.Camera
        The view, at the size the maps are wanted.
    sky : ndarray [H, W] bool
        The view's sky pixels.
    sky_alpha : ndarray [H, W] float, optional
        Its soft matte; default the mask itself.
    solid : ndarray [H, W] bool, optional
        Pixels a lidar return lands in: never shown as sky (their matte stays under one half).

    Returns
    -------
    SurfaceMaps
    """
    cloud, attrs = surfaces.at_frame(index)
    values, alpha, depth = _rasterize(cloud, attrs, camera)
    rays, z_per_m = _rays(camera)
    up = surfaces.up
    center = np.asarray(camera.center, np.float64)
    sky = np.asarray(sky, bool)
    covered = (alpha > _COVERED) & ~sky
    distance = np.where(covered, depth / np.maximum(z_per_m, 1e-9), np.inf)
    normal = values[..., :3]
    normal = normal / np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-6)
    fields = {name: np.clip(values[..., 3 + i], 0.0, 1.0)
              for i, name in enumerate(("ground", "open", "puddle", "track"))}
    boxed = _box_shells(surfaces, index, camera, rays, center, distance, normal, fields, sky)
    covered |= boxed
    ground_h = float(surfaces.ground_height(center[None])[0])
    distance, kind, _ = complete_distance(distance, covered, sky, rays, center, up, ground_h,
                                          forward=np.asarray(camera.camera_to_world, np.float64)[:3, 2],
                                          ground_at=surfaces.ground_height, facades=surfaces.facades)
    fill_ground = kind == FILL_GROUND
    if np.any(fill_ground):  # attributes evaluated where the ray meets the ground: anchored in the world
        hit = center + rays[fill_ground] * np.where(np.isfinite(distance[fill_ground]), distance[fill_ground],
                                                     1e4)[:, None]
        normal[fill_ground] = up
        fields["ground"][fill_ground] = 1.0
        fields["open"][fill_ground] = 1.0
        fields["puddle"][fill_ground] = surfaces.puddle_field(hit)
        fields["track"][fill_ground] = surfaces.track_field(hit)
    wall = kind == FILL_WALL
    if np.any(wall):  # a vertical wall facing the camera across the surface it rises from
        rr, cc = np.nonzero(wall)
        flat = rays[rr, cc] - np.outer(rays[rr, cc] @ up, up)
        flat /= np.maximum(np.linalg.norm(flat, axis=1, keepdims=True), 1e-9)
        normal[rr, cc] = -flat
        for name in fields:
            fields[name][rr, cc] = 0.0
    matte = sky.astype(np.float32) if sky_alpha is None else np.asarray(sky_alpha, np.float32).copy()
    unreached = (kind == FILL_SKY) & ~sky  # nothing below to rise from: infinitely far, seen as sky
    matte[unreached] = 1.0
    sky = sky | unreached
    if solid is not None:
        matte = np.where(solid, np.minimum(matte, 0.49), matte).astype(np.float32)
    normal[sky] = -rays[sky]
    for name in fields:
        fields[name][sky] = 0.0
    return SurfaceMaps(normal=normal.astype(np.float32), distance=distance.astype(np.float32),
                       ground=fields["ground"], open=fields["open"], puddle=fields["puddle"], track=fields["track"],
                       sky=sky, sky_alpha=np.asarray(matte, np.float32), covered=covered, rays=rays.astype(np.float32),
                       ground_height=ground_h)


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
