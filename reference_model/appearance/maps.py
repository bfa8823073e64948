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
  is fitted, else the closing's depth), facing the camera horizontally, at least as far as the
  lidar reaches where the lidar swept across it and heard nothing (``reach``), its distance
  smoothed along the frame: structure above the lidar's reach keeps its appearance, nothing
  settles on it.

:func:`mirror_distance` renders the non-ground surfaces mirrored about that ground plane: how far
the reflected ray of each pixel travels to the scene; :func:`screen_reflection` takes the colour of
what is met there from the frame itself (what the camera sees above the road), never from the
lidar's colours.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
import torch

from wcbench.reference_model._numba_backend import load_numba_kernels
from wcbench.reference_model.appearance.box_shells import box_shells, moving_pixels
from wcbench.reference_model.appearance.surfaces import SurfaceScene
from wcbench.reference_model.guided_filter import guided_filter
from wcbench.reference_model.model.sky import view_directions
from wcbench.reference_model.raster.rasterizer import rasterize_image
from wcbench.reference_model.scene_graph.completion import FILL_GROUND, FILL_SKY, FILL_WALL, complete_distance
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.weather.particle_geometry import quat_from_axis_to

__all__ = ["FIELDS", "HIT_FILLED", "HIT_SEEN", "HIT_SKY", "NO_HIT", "SurfaceMaps", "facing_view", "glossy_blur",
           "mirror_distance", "refine", "screen_reflection", "surface_maps"]

#: The surface attributes the maps can composite beside the normal (:data:`~.surfaces.ATTRIBUTES`
#: after the normal's three), in the order of their channels.
FIELDS = ("ground", "open", "puddle", "track")

# A pixel's state in the rain's reflection lookup (:func:`_reflection_lookup` and its kernel,
# :mod:`.reflection_kernels`, which reads them from here: they live beside the numpy reference so
# that the editor imports without numba and falls back to it).
#: The pixel's ray does not meet the ground plane.
NO_HIT = 0
#: The reflected ray meets a surface the camera sees at the looked-up pixel (or leaves to infinity
#: inside the frame).
HIT_SEEN = 1
#: The reflected ray meets no surface and leaves the frame: the sky in the mirrored direction.
HIT_SKY = 2
#: The reflected point is hidden or out of the frame: its colour is filled from around it.
HIT_FILLED = 3

#: Accumulated opacity above which a pixel counts as covered by the lidar surfaces.
_COVERED = 0.5
#: The maps' compositing stops a pixel once its transmittance has fallen below this (the pair that
#: took it there kept): its normal, fields and depth are the alpha-weighted means of the surfaces
#: it meets, and what lies behind the first 99 % of its light moves them by at most 1 % of their
#: range, while the surfels' overlapping tails past it were 28 % of a frame's pairs (pandaset_002
#: frame 15: 4.40 M pairs at 1e-4, 3.14 M here; docs/findings.md).
_SURFACE_STOP = 1e-2
#: The reflected point counts as what the camera sees at its pixel unless the camera's surface there
#: lies nearer than its distance by more than this fraction of it plus ``_SEEN_SLACK_M`` (occluded).
_SEEN_FRACTION, _SEEN_SLACK_M = 0.1, 0.5
#: Where a reflected ray that meets no surface is put (m along it): far enough that the camera's
#: offset from the plane does not move it in the image.
_AT_INFINITY_M = 1e5


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
        The surface attributes (:data:`~.surfaces.ATTRIBUTES`), in [0, 1]; NaN everywhere for one
        that was not asked for (not in ``fields``).
    sky : ndarray bool
    sky_alpha : ndarray float32
        Soft sky matte in [0, 1] (1 inside the sky, fractional along its edges).
    covered : ndarray bool
        Where the lidar surfaces were drawn (elsewhere the maps are completed).
    rays : ndarray [H, W, 3] float32
        Unit world ray directions.
    ground_height : float
        Height of the ground plane under the camera (m along ``up``).
    fields : tuple of str
        The attributes of :data:`FIELDS` these maps hold (the others are NaN).
    moving : ndarray bool, optional
        Where the surface lies on a moving object (:func:`~.box_shells.moving_pixels`); default
        unknown (none marked).
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
    fields: tuple[str, ...] = FIELDS
    moving: np.ndarray | None = None


@functools.lru_cache(maxsize=8)
def _camera_rays(K: bytes, width: int, height: int) -> np.ndarray:
    """Unit camera-frame rays [H, W, 3] float64 of a camera's pixels (``K`` the bytes of its float64
    [3, 3] intrinsics), read-only: the same for every frame of a camera, so each frame only turns them."""
    rays = view_directions(np.eye(4), np.frombuffer(K, np.float64).reshape(3, 3), width, height).astype(np.float64)
    rays.flags.writeable = False
    return rays


def _rays(camera: Any) -> tuple[np.ndarray, np.ndarray]:
    """(unit world rays [H, W, 3] of ``camera``'s pixels, float32 values, the camera depth of each
    unit ray [H, W]), float64: the camera's rays turned by the frame's rotation (a rotation keeps
    them unit: the same rays as :func:`view_directions` of the pose up to float32 rounding)."""
    c2w = np.asarray(camera.camera_to_world, np.float64)
    K = np.ascontiguousarray(camera.K, np.float64)
    rays = (_camera_rays(K.tobytes(), int(camera.width), int(camera.height)) @ c2w[:3, :3].T)
    rays = rays.astype(np.float32).astype(np.float64)
    return rays, rays @ c2w[:3, 2]


def _rasterize(cloud: GaussianCloud, channels: np.ndarray, camera: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(channels / alpha [H, W, C], alpha [H, W], camera depth [H, W]) of ``cloud`` seen by ``camera``
    (the inference kernel: nothing here needs a gradient), each pixel's compositing stopped once
    its transmittance has fallen below ``_SURFACE_STOP``: the maps read the front surface."""
    out = rasterize_image(torch.from_numpy(cloud.means), torch.from_numpy(cloud.quats),
                          torch.from_numpy(cloud.scales), torch.from_numpy(cloud.opacities),
                          torch.from_numpy(np.ascontiguousarray(channels, np.float32)),
                          np.asarray(camera.world_to_camera, np.float64), np.asarray(camera.K, np.float64),
                          int(camera.width), int(camera.height), stop_transmittance=_SURFACE_STOP)
    alpha = out.alpha.numpy()
    assert out.depth is not None
    return out.color.numpy() / np.maximum(alpha, 1e-6)[..., None], alpha, out.depth.numpy()


def facing_view(means: np.ndarray, normals: np.ndarray, turnable: np.ndarray, center: np.ndarray) -> np.ndarray:
    """[N, 3] float32 the surfels' ``normals`` turned toward a view from ``center`` [3] (world, m)
    where ``turnable``.

    A static surfel's normal is turned toward the sequence's nearest camera, which lies below the
    top of a crown or an overhang: there it points into the surface for a camera that sees it from
    afar (the sun's cosine of a crown fell to 0 in a ragged patch, synth_hard_1, docs/findings.md).
    What a view sees of a surface faces it, so a turnable surfel facing away from ``center`` is
    turned (:attr:`~.surfaces.SurfaceScene.view_turned`: not the ground, whose normal, up within
    the lidar's noise, tips past a ray that grazes it and turned would face down; not foliage,
    which has no side).

    Parameters
    ----------
    means : ndarray [N, 3]
        Surfel centres (world, m).
    normals : ndarray [N, 3]
        Their unit normals (world).
    turnable : ndarray [N] bool
    center : ndarray [3]
        The view's centre (world, m).
    """
    out = np.array(normals, np.float32)
    to_view = np.asarray(center, np.float32) - np.asarray(means, np.float32)
    away = np.asarray(turnable, bool) & (np.einsum("ij,ij->i", to_view, out) < 0)
    # negated in place where turned (a sign flip is exact): np.where would build both signs first
    np.negative(out, out=out, where=away[:, None])
    return out


def surface_maps(surfaces: SurfaceScene, index: int, camera: Any, sky: np.ndarray, *,
                 sky_alpha: np.ndarray | None = None, solid: np.ndarray | None = None,
                 fields: tuple[str, ...] = FIELDS, image: np.ndarray | None = None,
                 reach: tuple[float, tuple[float, float]] | None = None) -> SurfaceMaps:
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
    fields : tuple of str
        The attributes of :data:`FIELDS` to composite (default all); the others are left NaN. A
        weather that reads fewer (fog reads none) leaves their channels out of the compositing,
        whose time grows with the channels; the ones asked for are the same to the bit (each
        channel's sums are its own, and where a pixel stops depends on its opacity alone).
    image : ndarray [H, W, 3] float32, optional
        The frame (display RGB): the walls' distances are smoothed along it
        (:func:`~wcbench.reference_model.scene_graph.completion.smooth_walls`); without it, each
        column's guess stays.
    reach : (float, (float, float)), optional
        The lidar's reach (m) and elevation band (degrees): with ``solid``, a wall pixel inside the
        lidar's field that no return lands near lies at least that far
        (:func:`~wcbench.reference_model.scene_graph.completion.beyond_reach`).

    Returns
    -------
    SurfaceMaps

    Raises
    ------
    ValueError
        If ``fields`` names an attribute not in :data:`FIELDS`.
    """
    unknown = [f for f in fields if f not in FIELDS]
    if unknown:
        raise ValueError(f"fields {unknown} unknown: expected names from {FIELDS}")
    wanted = tuple(f for f in FIELDS if f in fields)
    cloud, attrs = surfaces.at_frame(index)
    center = np.asarray(camera.center, np.float64)
    turnable = np.zeros(len(attrs), bool)
    if surfaces.view_turned is not None:  # the static surfels come first
        turnable[:len(surfaces.view_turned)] = surfaces.view_turned
    # the normals and the wanted attributes gathered in one copy, the normals turned in it (np.take
    # gives it in C order: an index list on the second axis gives the transposed layout, which the
    # rasterizer copied again)
    attrs = np.take(attrs, [0, 1, 2] + [3 + FIELDS.index(f) for f in wanted], axis=1)
    attrs[:, :3] = facing_view(cloud.means, attrs[:, :3], turnable, center)
    values, alpha, depth = _rasterize(cloud, attrs, camera)
    rays, z_per_m = _rays(camera)
    up = surfaces.up
    sky = np.asarray(sky, bool)
    covered = (alpha > _COVERED) & ~sky
    distance = np.where(covered, depth / np.maximum(z_per_m, 1e-9), np.inf)
    normal = values[..., :3]
    # the length summed channel by channel: the same sum as np.linalg.norm's, without its reduction
    x, y, z = normal[..., 0], normal[..., 1], normal[..., 2]
    length = np.sqrt(x * x + y * y + z * z)
    normal = normal / np.maximum(length, 1e-6)[..., None]
    planes = {name: np.clip(values[..., 3 + i], 0.0, 1.0) for i, name in enumerate(wanted)}
    # the box shells write every attribute where they stand for an object: the unasked ones get
    # scratch planes, NaN in the maps
    shell_fields = {name: planes.get(name, np.full(distance.shape, np.nan, np.float32)) for name in FIELDS}
    boxed = box_shells(surfaces, index, camera, rays, center, distance, normal, shell_fields, sky, image=image)
    covered |= boxed
    moving = moving_pixels(surfaces, index, camera, rays, distance, boxed)
    ground_h = float(surfaces.ground_height(center[None])[0])
    distance, kind, _ = complete_distance(distance, covered, sky, rays, center, up, ground_h,
                                          forward=np.asarray(camera.camera_to_world, np.float64)[:3, 2],
                                          ground_at=surfaces.ground_height, facades=surfaces.facades, guide=image,
                                          hits=None if solid is None else np.asarray(solid, bool), reach=reach)
    fill_ground = kind == FILL_GROUND
    if np.any(fill_ground):  # attributes evaluated where the ray meets the ground: anchored in the world
        hit = center + rays[fill_ground] * np.where(np.isfinite(distance[fill_ground]), distance[fill_ground],
                                                     1e4)[:, None]
        normal[fill_ground] = up
        if "ground" in planes:
            planes["ground"][fill_ground] = 1.0
        if "open" in planes:
            planes["open"][fill_ground] = surfaces.open_field(hit)
        if "puddle" in planes:
            planes["puddle"][fill_ground] = surfaces.puddle_field(hit)
        if "track" in planes:
            planes["track"][fill_ground] = surfaces.track_field(hit)
    wall = kind == FILL_WALL
    if np.any(wall):  # a vertical wall facing the camera across the surface it rises from
        rr, cc = np.nonzero(wall)
        flat = rays[rr, cc] - np.outer(rays[rr, cc] @ up, up)
        flat /= np.maximum(np.linalg.norm(flat, axis=1, keepdims=True), 1e-9)
        normal[rr, cc] = -flat
        for name in planes:
            planes[name][rr, cc] = 0.0
    matte = sky.astype(np.float32) if sky_alpha is None else np.asarray(sky_alpha, np.float32).copy()
    unreached = (kind == FILL_SKY) & ~sky  # nothing below to rise from: infinitely far, seen as sky
    matte[unreached] = 1.0
    sky = sky | unreached
    if solid is not None:
        matte = np.where(solid, np.minimum(matte, 0.49), matte).astype(np.float32)
    normal[sky] = -rays[sky]
    for name in planes:
        planes[name][sky] = 0.0
    out = {name: planes.get(name, np.full(distance.shape, np.nan, np.float32)) for name in FIELDS}
    return SurfaceMaps(normal=normal.astype(np.float32), distance=distance.astype(np.float32),
                       ground=out["ground"], open=out["open"], puddle=out["puddle"], track=out["track"],
                       sky=sky, sky_alpha=np.asarray(matte, np.float32), covered=covered, rays=rays.astype(np.float32),
                       ground_height=ground_h, fields=wanted, moving=moving & ~sky)


def _mirrored_cloud(surfaces: SurfaceScene, index: int, ground_height: float) -> GaussianCloud:
    """The non-ground Gaussians of frame ``index`` more than 5 cm above the plane at ``ground_height``
    (m along ``up``), mirrored about it: centres, and the surfels' normals (the isotropic ones do
    not turn)."""
    cloud, attrs = surfaces.at_frame(index)
    up = surfaces.up
    # the static rows come sorted by height and mirrored about the plane through the origin once
    # (SurfaceScene.mirrored_static): those above this plane are a slice, shifted by twice its
    # height; only the frame's moving ones are gathered and turned here
    st = surfaces.mirrored_static()
    n_static = len(surfaces.gaussians.static)
    first = int(np.searchsorted(st.heights, ground_height + 0.05, side="right"))
    moving_keep = n_static + np.flatnonzero(attrs[n_static:, 3] < 0.5)
    moving = cloud.means[moving_keep].astype(np.float64)
    h_moving = moving @ up - ground_height
    above_moving = h_moving > 0.05
    # shifted in float64 and written as float32 straight into the cloud's rows (one pass, no copy)
    n_above = len(st.means) - first
    mirrored = np.empty((n_above + int(above_moving.sum()), 3), np.float32)
    np.add(st.means[first:], 2.0 * ground_height * np.asarray(up, np.float64), out=mirrored[:n_above],
           casting="unsafe")
    np.subtract(moving[above_moving], 2.0 * np.outer(h_moving[above_moving], up), out=mirrored[n_above:],
                casting="unsafe")
    # a surfel's normal is mirrored with it (the isotropic ones do not turn)
    normals = attrs[moving_keep[above_moving], :3].astype(np.float64)
    moving_quats = quat_from_axis_to(normals - 2.0 * np.outer(normals @ up, up)).astype(np.float32)
    rows = moving_keep[above_moving]
    return GaussianCloud(means=mirrored, quats=np.concatenate([st.quats[first:], moving_quats]),
                         scales=np.concatenate([st.scales[first:], cloud.scales[rows]]),
                         opacities=np.concatenate([st.opacities[first:], cloud.opacities[rows]]),
                         colors=np.concatenate([st.colors[first:], cloud.colors[rows]]))


def mirror_distance(surfaces: SurfaceScene, index: int, camera: Any, ground_height: float) -> np.ndarray:
    """How far each pixel's ray reflected by the ground plane travels to the non-ground lidar
    surfaces: the length of the unfolded path.

    Rendering the surfaces mirrored about the plane from the real camera gives, at a pixel on the
    plane, what the reflected ray meets (mirroring the centres and the surfels' normals is exact);
    only its depth is needed, since the colour of what is met is taken from the frame itself
    (:func:`screen_reflection`), so one dummy channel is composited. It is rendered at half the
    camera's size (a wet surface blurs its reflection) and resized up by
    :func:`_upsampled_distance`.

    Parameters
    ----------
    surfaces : SurfaceScene
    index : int
    camera : Camera
    ground_height : float
        The plane's height along ``up`` (m).

    Returns
    -------
    ndarray [H, W] float32
        Length of the reflected path from the camera (m; ``inf`` where it meets no surface).
    """
    w, h = int(camera.width), int(camera.height)
    sub = _mirrored_cloud(surfaces, index, ground_height)
    if len(sub) == 0:
        return np.full((h, w), np.inf, np.float32)
    # at half the size: a reflection is blurred by the wet surface (a puddle's sharp one by little)
    half = replace(camera, K=np.diag([0.5, 0.5, 1.0]) @ np.asarray(camera.K, np.float64), width=max(1, w // 2),
                   height=max(1, h // 2))
    half = replace(half, K=np.diag([half.width / (0.5 * w), half.height / (0.5 * h), 1.0]) @ half.K)
    # the compositing's weights and depth do not depend on the channels: one channel of zeros
    _, alpha, depth = _rasterize(sub, np.zeros((len(sub), 1), np.float32), half)
    _, z_per_m = _rays(half)
    return _upsampled_distance(alpha > _COVERED, depth / np.maximum(z_per_m, 1e-9), (w, h))


def _upsampled_distance(covered: np.ndarray, distance: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """[H, W] float32 the ``distance`` [h, w] (m) of the ``covered`` [h, w] bool pixels resized up
    to ``size`` (W, H), ``inf`` elsewhere: a normalised convolution (Knutsson & Westin 1993) by the
    bilinear kernel.

    A pixel takes the covered pixels' distances weighted by their bilinear weights, and is covered
    where they hold at least half its weight: the silhouette runs between the half-size pixels'
    centres, not in their 2 px steps (a puddle's sharp reflection of a car showed the steps), and
    no stand-in for "nothing" mixes into a real distance (a far sentinel interpolated beside a
    surface gave rows of a distance nothing lies at, seen as holes in the reflection).
    """
    up_weight = cv2.resize(np.asarray(covered, np.float32), size, interpolation=cv2.INTER_LINEAR)
    up_known = cv2.resize(np.where(covered, distance, 0.0).astype(np.float32), size, interpolation=cv2.INTER_LINEAR)
    return np.where(up_weight >= 0.5, up_known / np.maximum(up_weight, 1e-6), np.inf).astype(np.float32)


def screen_reflection(source: np.ndarray, camera: Any, maps: SurfaceMaps, mirror_distance: np.ndarray, *,
                      up: np.ndarray, sky: np.ndarray | None = None,
                      fill_sigma_px: float | None = None, fast: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """What the ground plane mirrors at each pixel, in the frame's own colours (screen-space reflection).

    A wet road reflects what stands above it, and what stands above it the camera mostly sees: the
    reflected ray of a pixel leaves the plane at the ray's intersection G along the mirrored
    direction r' = r - 2 (r . up) up and meets the scene at X = G + r' (L - |G - C|), where L is the
    length of the unfolded path to the first mirrored surface (:func:`mirror_distance`), or at
    infinity where it meets none. X projected into the camera gives the pixel whose colour in
    ``source`` is the reflection, when the camera sees X there (its surface at that pixel is not
    nearer than X; an X at infinity is seen wherever it projects). The lidar's own colours (a
    mover's from another frame, a return's from a sweep the camera saw differently) are never
    used. An X at infinity out of the frame (the steep reflected rays of the near road, which
    look up past the frame's top) is the sky the reflected ray sees, ``sky``, where it is given:
    the ray meets nothing, so nothing but the sky is there to mirror. Where X is hidden or out of
    the frame otherwise, the reflection is the normalised convolution (Knutsson & Westin 1993)
    of the known reflections around it (a rough film blurs its reflection anyway), at
    ``fill_sigma_px`` and at four times that.

    Parameters
    ----------
    source : ndarray [H, W, 3] float32
        What the camera sees (the edited frame before any reflection), display RGB.
    camera : Camera
        The view, at the size of ``source``.
    maps : SurfaceMaps
        The view's completed maps (rays, distances, ground plane height).
    mirror_distance : ndarray [H, W] float32
        :func:`mirror_distance`'s path lengths (m; ``inf`` where the reflected ray meets no surface).
    up : ndarray [3]
        The world's up.
    sky : ndarray [H, W, 3] float32, optional
        Display RGB of the sky each pixel's reflected ray sees at infinity (the weather's sky in
        the mirrored direction); without it, such rays out of the frame are filled too.
    fill_sigma_px : float, optional
        Default 6 px at 270 rows.
    fast : bool
        Look the reflected points up with the numba kernel
        (:func:`~.reflection_kernels.reflection_lookup_kernel`, where it compiles and loads), else
        with the numpy reference (:func:`_reflection_lookup`).

    Returns
    -------
    image : ndarray [H, W, 3] float32
        Display RGB of the reflection (``source`` itself where a pixel's ray does not meet the plane).
    seen : ndarray [H, W] bool
        Where the reflection is known (seen directly, or the sky): not filled.
    """
    src = np.asarray(source, np.float32)
    h, w = src.shape[:2]
    if maps.rays.shape[:2] != (h, w) or np.shape(mirror_distance) != (h, w):
        raise ValueError(f"source is {w}x{h}; the maps' rays are {maps.rays.shape[1]}x{maps.rays.shape[0]} "
                         f"and mirror_distance {np.shape(mirror_distance)}")
    if sky is not None and np.shape(sky) != (h, w, 3):
        raise ValueError(f"sky is {np.shape(sky)}; expected the source's shape {(h, w, 3)}")
    lookup = _reflection_lookup
    if fast:
        kernels = load_numba_kernels("appearance.reflection_kernels")
        lookup = _reflection_lookup if kernels is None else functools.partial(_reflection_lookup_fast, kernels)
    map_x, map_y, state = lookup(camera, maps, np.asarray(mirror_distance, np.float32), np.asarray(up, np.float64))
    image = cv2.remap(src, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    hits = state != NO_HIT
    seen = state == HIT_SEEN
    if sky is not None:
        # a reflected ray that meets no surface sees the sky, in the frame or past its edge
        open_sky = state == HIT_SKY
        image[open_sky] = np.asarray(sky, np.float32)[open_sky]
        seen |= open_sky
    missing = hits & ~seen
    if missing.any():
        sigma = fill_sigma_px if fill_sigma_px is not None else 6.0 * h / 270.0
        weight = seen.astype(np.float32)
        filled = image.copy()
        todo = missing.copy()
        stacked = np.dstack([image * weight[..., None], weight])  # blurred per channel, as one image
        # only the rows holding a pixel to fill are blurred (below the horizon: the plane's)
        held = np.flatnonzero(missing.any(axis=1))
        band = slice(int(held[0]), int(held[-1]) + 1)
        for s in (sigma, 4.0 * sigma):
            blurred = _gaussian_blur(stacked, s, rows=band)
            num, den = blurred[..., :3], blurred[..., 3]
            ok = todo[band] & (den > 1e-3)
            filled[band][ok] = num[ok] / den[ok, None]
            todo[band] &= ~ok
            if not todo.any():
                break  # the wider blur is needed only for what the narrower one left unfilled
        # no seen reflection within reach: what the frame shows where the ray points
        image = filled
    return image.astype(np.float32), seen


def _reflection_lookup(camera: Any, maps: SurfaceMaps, mirror_distance: np.ndarray,
                       up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each pixel's reflected ray meets the scene (the numpy reference of
    :func:`~.reflection_kernels.reflection_lookup_kernel`, see :func:`screen_reflection`).

    Returns
    -------
    map_x, map_y : ndarray [H, W] float32
        The pixel (centres at integers) whose colour is the reflection, clipped to the frame; the
        pixel's own where its ray does not meet the plane.
    state : ndarray [H, W] uint8
        :data:`NO_HIT`, ``HIT_SEEN``, ``HIT_SKY`` or ``HIT_FILLED``.
    """
    h, w = maps.distance.shape
    center = np.asarray(camera.center, np.float64)
    rays = maps.rays.astype(np.float64)
    down = rays @ up
    height = center @ up - maps.ground_height
    hits = (down < -1e-3) & (height > 0)
    rr, cc = np.nonzero(hits)
    r = rays[rr, cc]
    t_plane = height / -down[rr, cc]
    ground = center + r * t_plane[:, None]
    mirrored = r - 2.0 * np.outer(r @ up, up)
    rest = np.asarray(mirror_distance, np.float64)[rr, cc] - t_plane
    finite = np.isfinite(rest) & (rest > 0)
    points = ground + mirrored * np.where(finite, rest, _AT_INFINITY_M)[:, None]
    uv, z = camera.project(points)
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5  # pixel centres at +0.5
    inside = (z > 0) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    far = np.linalg.norm(points - center, axis=1)
    xi, yi = np.clip(np.round(x), 0, w - 1).astype(int), np.clip(np.round(y), 0, h - 1).astype(int)
    there = np.asarray(maps.distance, np.float64)[yi, xi]
    seen_at = inside & (~finite | (there >= far * (1.0 - _SEEN_FRACTION) - _SEEN_SLACK_M))
    map_x = np.tile(np.arange(w, dtype=np.float32), (h, 1))
    map_y = np.tile(np.arange(h, dtype=np.float32)[:, None], (1, w))
    map_x[rr, cc] = np.clip(x, 0, w - 1)
    map_y[rr, cc] = np.clip(y, 0, h - 1)
    state = np.full((h, w), NO_HIT, np.uint8)
    state[rr, cc] = np.where(seen_at, HIT_SEEN, np.where(finite, HIT_FILLED, HIT_SKY))
    return map_x, map_y, state


def _reflection_lookup_fast(kernels: Any, camera: Any, maps: SurfaceMaps, mirror_distance: np.ndarray,
                            up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_reflection_lookup` by the numba kernel of ``kernels``."""
    h, w = maps.distance.shape
    map_x, map_y = np.empty((h, w), np.float32), np.empty((h, w), np.float32)
    state = np.empty((h, w), np.uint8)
    kernels.reflection_lookup_kernel(
        np.ascontiguousarray(maps.rays, np.float32), np.ascontiguousarray(maps.distance, np.float32),
        np.ascontiguousarray(mirror_distance, np.float32), np.ascontiguousarray(camera.center, np.float64),
        np.ascontiguousarray(up, np.float64),
        float(maps.ground_height), np.ascontiguousarray(np.asarray(camera.world_to_camera, np.float64)[:3]),
        np.ascontiguousarray(camera.K, np.float64), _SEEN_FRACTION, _SEEN_SLACK_M, _AT_INFINITY_M, map_x, map_y, state)
    return map_x, map_y, state


#: Blurs wider than this (px) are taken on an image a quarter the size (:func:`_gaussian_blur`).
_WIDE_BLUR_PX = 12.0


def _gaussian_blur(image: np.ndarray, sigma_px: float, *, rows: slice | None = None) -> np.ndarray:
    """A Gaussian blur of ``image`` [H, W, C] float32 by ``sigma_px``; a wide one (over 12 px) on a
    quarter-size image, resized back. With ``rows`` (a slice of rows, step 1), only those rows of it.

    A narrow blur of a band of rows is OpenCV's blur of those rows and the kernel's reach (its
    radius, ``round(8 sigma + 1) | 1`` taps for float images, halved) on either side: each output
    pixel sums the same inputs in the same order, so the rows equal the whole image's blur to the bit
    (tests/reference_model/appearance/test_maps.py). A wide one is taken whole (its quarter-size
    grid is the whole image's).

    A 24 px blur is a 193-tap kernel over every pixel; area-averaged to a quarter of the size, the
    same blur is 4 times narrower on 16 times fewer pixels. The averaging adds the variance of a
    4 px box (4^2 / 12 px^2, under 0.3 % of a 24 px blur's) and the bilinear resize back a little
    more: the result is within 1 % of the image's range of the full-size blur away from the frame's
    edges (tests/reference_model/appearance/test_maps.py).
    """
    img = np.asarray(image, np.float32)
    h, w = img.shape[:2]
    r0, r1, _ = (rows if rows is not None else slice(None)).indices(h)
    if sigma_px <= _WIDE_BLUR_PX:
        reach = (round(8.0 * sigma_px + 1.0) | 1) // 2 + 1  # a row more than the kernel's: a tie rounded either way
        lo, hi = max(0, r0 - reach), min(h, r1 + reach)
        return cv2.GaussianBlur(img[lo:hi], (0, 0), sigma_px)[r0 - lo:r1 - lo]
    small = cv2.resize(img, (max(1, round(w / 4)), max(1, round(h / 4))), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), sigma_px * small.shape[1] / w)
    out = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    return out.reshape(img.shape)[r0:r1]


#: Longest vertical stretch of a glossy reflection over its width (a view 7 degrees below the horizon).
_MAX_STRETCH = 8.0


def glossy_blur(image: np.ndarray, weight: np.ndarray, rays: np.ndarray, *, up: np.ndarray,
                sigma_px: float) -> np.ndarray:
    """A rough film's reflection: blurred across by ``sigma_px`` and along the image's vertical by
    ``sigma_px / sin(e)``, e the angle of the pixel's ray below the horizon (at most 8 times longer).

    A facet tilted by d in the plane of incidence turns the reflected ray by 2 d, one tilted across
    it by 2 d sin(e): seen at a grazing angle, the reflections on wet asphalt are streaks drawn
    downward from what they mirror, not blobs of its shape (the glitter geometry of Cox & Munk
    1954). The blur is a normalised convolution over ``weight`` (the ground), so nothing of a car's
    body beside the road's pixels runs into their reflection.

    Parameters
    ----------
    image : ndarray [H, W, 3] float32
        The sharp reflection.
    weight : ndarray [H, W] float32
        Where it is a reflection (the ground), in [0, 1].
    rays : ndarray [H, W, 3] float32
        Unit world rays.
    up : ndarray [3]
    sigma_px : float
        Blur across the plane of incidence (px); 0 returns ``image``.

    Returns
    -------
    ndarray [H, W, 3] float32
    """
    if sigma_px <= 0:
        return np.asarray(image, np.float32)
    wgt = np.clip(np.asarray(weight, np.float32), 0.0, 1.0)
    num = np.asarray(image, np.float32) * wgt[..., None]
    sin_e = np.clip(-(rays @ np.asarray(up, np.float32)), 1.0 / _MAX_STRETCH, 1.0)
    stretch = np.clip(1.0 / sin_e, 1.0, _MAX_STRETCH)
    # the numerator's three channels and the weight blurred as one four-channel image (OpenCV
    # filters each channel alone: the same sums as four separate blurs, in a quarter of the calls)
    across = cv2.GaussianBlur(np.dstack([num, wgt]), (0, 0), sigmaX=sigma_px, sigmaY=1e-3)
    # the numerator and the weight accumulated as one four-channel image: one pass a level
    acc = np.zeros(across.shape, np.float32)
    # stretches 1, 2, 4, 8 and a linear blend in log2 of the stretch between them
    level = np.log2(stretch)
    for i in range(4):
        share = np.clip(1.0 - np.abs(level - i), 0.0, 1.0)
        if not share.any():
            continue
        # the longer blurs on rows averaged 2^i at a time (the same sigma in rows of the coarse
        # image): a few ms a frame, not a kernel of 150 rows
        f = 2 ** i
        rows = max(1, round(num.shape[0] / f))
        small = (num.shape[1], rows)
        nd = cv2.GaussianBlur(cv2.resize(across, small, interpolation=cv2.INTER_AREA), (0, 0), sigmaX=1e-3,
                              sigmaY=sigma_px)
        nd = cv2.resize(nd, (num.shape[1], num.shape[0]), interpolation=cv2.INTER_LINEAR)
        nd *= share[..., None]
        acc += nd
    den_out = acc[..., 3]
    # divided into a new array (in place, into the strided channels, took twice as long), and the
    # sharp reflection kept where no ground is near (a copy of it only)
    out = acc[..., :3] / np.maximum(acc[..., 3:], 1e-6)
    blurred = np.array(image, np.float32)
    np.copyto(blurred, out, where=den_out[..., None] > 1e-4)
    return blurred


def refine(mask: np.ndarray, guide: np.ndarray, *, radius: int, eps: float = 1e-3) -> np.ndarray:
    """A map snapped to the image's edges: the guided filter (He et al. 2013,
    :func:`~wcbench.reference_model.guided_filter.guided_filter`) with the frame as guide.

    Parameters
    ----------
    mask : ndarray [H, W] or [H, W, C] float
        One map, or a stack of up to 4 snapped at once: the filter's statistics of the guide are
        shared and each channel comes out as its own call would give it; two maps stacked take
        about 0.7 of the time of two calls (a random 480x270 frame, docs/findings.md).
    guide : ndarray [H, W, 3] float32
        The raw frame, display RGB in [0, 1].
    radius : int
        Window radius (px); 0 returns ``mask``.
    eps : float
        Regularisation (edges weaker than sqrt(eps) are smoothed over).

    Returns
    -------
    ndarray of ``mask``'s shape, float32 in [0, 1]
    """
    if radius <= 0:
        return np.asarray(mask, np.float32)
    return np.clip(guided_filter(guide, mask, radius=radius, eps=eps), 0.0, 1.0).astype(np.float32)
