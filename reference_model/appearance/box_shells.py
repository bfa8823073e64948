"""The box shells of the surface maps: where a tracked object's box stands for the object the
lidar sampled sparsely or saw through (docs/design.md §7, "Weather appearance").

:func:`box_shells` runs inside :func:`~.maps.surface_maps`, after its rasterization: inside each
tracked object's silhouette (the hull of its returns, a mover's from the sweep nearest the frame,
or for a car in the lidar's blind zone its box cut at the near plane), a ray that passes through
the body takes the face of the box it enters; a surface on the object beside its silhouette is its
Gaussians' tails and takes the surface beside it, as do the bands over its top and beside its sides
that the frame shows as what lies behind or beside it. :mod:`.shell_kernels` holds the numba kernels of one box;
:func:`_box_shell_pixels` and :func:`_top_band_pixels` are their numpy references.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from wcbench.reference_model._numba_backend import load_numba_kernels
from wcbench.reference_model.appearance.surfaces import UNDERBODY_M, SurfaceScene, in_box

__all__ = ["box_shells"]

#: Camera depth (m) of the near plane; a box with a corner nearer (the camera beside the object)
#: gets the hull of its returns' shell only from this many returns in front of it, its box's
#: outline with fewer (a parked car 3 m off the front-right camera of pandaset_002 has 11, one
#: beside the rear camera 370).
_NEAR_M, _MIN_BESIDE_RETURNS = 0.1, 100
#: A moving object's silhouette is the hull of its frame's own returns from this many (above its
#: floor, in its box grown by 0.1 m); with fewer (no sweep, or the lidar barely saw it), the hull of
#: its Gaussians'.
_MIN_OWN_RETURNS = 20
#: Below its underbody line, a surface on a mover more than this (m) outside its box's footprint
#: is its Gaussians' tails: its node's lowest Gaussians spread 0.11-0.14 m past the car by the
#: boxes' jitter (pandaset_002), while a car's own lower sides lie on its box or within a few
#: centimetres of it (the annotation's margin).
_SPREAD_M = 0.05
#: A tracked object's box face stands for it where the lidar surfaces lie this far behind it (m).
_BOX_SLACK_M = 0.3
#: Share of a box's height below which the body fills it (a car's belt line, ~0.9 m of a 1.45 m
#: sedan: above it the glasshouse narrows and the box holds air over the bonnet and beside the roof).
_BELT_SHARE = 0.6
#: The glasshouse above it: shares of the box's length and width (centred), and the share of the
#: box's height along its top that is air (the roof's curve and the annotation's margin).
_CABIN_SHARE, _ROOF_AIR_SHARE = np.array([0.6, 0.9, 1.0]), 0.1
#: A car beside the camera that the lidar barely saw stands by its box alone; its body there rises
#: to this share of the box's height (a bonnet's, ~0.7 m of a 1.5 m sedan), the glasshouse from it:
#: the belt line's share left a band of bare pavement over the bonnet of a car parked 3 m off the
#: front-right camera of pandaset_002 in the snow, this share a narrower one (docs/findings.md).
_BONNET_SHARE = 0.45
#: How far (pixels of a 270-row frame) an object's Gaussians may reach past the hull of their
#: centres: three of their widths (~0.08 m, a moving car's node on pandaset_002) seen from 10 m
#: with a 480-px-wide PandaSet camera's focal length (~490 px). Past the hull by more than
#: ``_EDGE_PX``, a surface on the object is its Gaussians' tails over what lies beside it.
_SPILL_PX, _EDGE_PX = 12, 1
#: How far (pixels) past the tails their compositing with what lies beyond reaches.
_BLEND_PX = 2
#: An object's top, snapped to the frame (:func:`_top_band_pixels`): how far (pixels of a 270-row frame)
#: below the top of its surface in the maps the frame's edge is looked for (a parked car's roof's
#: Gaussians reach 3-10 px over the roof line a rear camera shows from 12 m, docs/findings.md; a
#: longer search finds a car's stronger edges inside, the roof's against its windows, and loses
#: the weaker roof line to the share below), the colour step (RGB distance, display values in
#: [0, 1], after a 1-px blur) that counts as an edge, and the share of the strongest step of the
#: search it must also reach.
_TOP_SEARCH_PX, _TOP_EDGE_STEP, _TOP_EDGE_SHARE = 10, 0.08, 0.6
#: An object's sides, snapped to the frame the same way (:func:`_side_bands`): how far inside the side
#: of its surface in the maps the frame's edge is looked for, the reach of its surfels past it (m,
#: three of their widths, as ``_SPILL_PX``) seen at the box's nearest depth, at most
#: ``_SIDE_SEARCH_PX`` (pixels of a 270-row frame; none under 2 px: a far car's search would cross
#: it), and over how many pixels before that side its surface may blend into what lies beyond (a
#: parked car's rear 3 m off the right camera of pandaset_002, its surfels 0.067 m wide: its surface
#: in the maps reached 13 px past the frame's edge onto the pavement, through a 4-5 px blend;
#: docs/findings.md).
_SIDE_REACH_M, _SIDE_SEARCH_PX, _SIDE_LOOKBACK_PX = 0.24, 20, 6
#: An object's side runs on along its edge: a run of at most ``2 _SIDE_GAP_PX`` rows (of a 270-row
#: frame) whose search stopped short of the band on both sides of it (a taillight's or an indicator's
#: stronger step inside the car took the share, and the pavement beside it stayed the car's: a dark
#: notch in the snow, docs/findings.md) takes the band its neighbours' close over it; a longer run (a
#: mirror, a wheel arch the frame shows) keeps its own.
_SIDE_GAP_PX = 3


def _slab_interval(origin: np.ndarray, dirs: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """([N] entry, [N] exit) ray parameters of the lines ``origin + t dirs[i]`` through the
    axis-aligned box [lo, hi] (the slab method; ``origin`` [3], ``dirs`` [N, 3], all in the box's
    frame); a line parallel to a slab's planes leaves that slab out (NaN, skipped: ``np.fmax``
    is ``np.nanmax`` of two, without its per-row reduction), so entry > exit means a miss."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - origin) / dirs, (hi - origin) / dirs
    near, far = np.minimum(t1, t2), np.maximum(t1, t2)
    return (np.fmax(np.fmax(near[:, 0], near[:, 1]), near[:, 2]),
            np.fmin(np.fmin(far[:, 0], far[:, 1]), far[:, 2]))


def _slab_hits(origin: np.ndarray, dirs: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """[N] bool: whether each ray ``origin + t dirs[i]`` (t > 0) meets the axis-aligned box [lo, hi]
    (:func:`_slab_interval`)."""
    t_in, t_out = _slab_interval(origin, dirs, lo, hi)
    return (t_out >= np.maximum(t_in, 0.0)) & (t_out > 0.0)


#: The 8 corners of the unit cube [-1, 1]^3.
_CUBE = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])


def _boxes_miss_view(poses: np.ndarray, halves: np.ndarray, w2c: np.ndarray, K: np.ndarray, width: int,
                     height: int) -> np.ndarray:
    """[B] bool: whether no point of each box (object-to-world ``poses`` [B, 4, 4], half-sizes
    ``halves`` [B, 3], m) with a camera depth over 0.1 m projects into the ``width`` x ``height``
    image, judged by its corners: the depth is linear, so all corners at most 0.1 m deep put every
    point there; a box wholly in front projects into the convex hull of its corners' projections,
    so all corners past one edge of the image put every point past it. Otherwise ``False`` (it may
    be seen)."""
    corners = np.einsum("bij,bcj->bci", poses[:, :3, :3], _CUBE[None] * halves[:, None]) + poses[:, None, :3, 3]
    cam = corners @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[..., 2]
    behind, front = np.all(z <= 0.1, axis=1), np.all(z > 0.1, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * cam[..., 0] / z + K[0, 2]
        v = K[1, 1] * cam[..., 1] / z + K[1, 2]
    outside = (u.max(1) < 0) | (u.min(1) >= width) | (v.max(1) < 0) | (v.min(1) >= height)
    return behind | (front & outside)


def box_shells(surfaces: SurfaceScene, index: int, camera: Any, rays: np.ndarray, center: np.ndarray,
                distance: np.ndarray, normal: np.ndarray, fields: dict[str, np.ndarray], sky: np.ndarray, *,
                image: np.ndarray | None = None, fast: bool = True) -> np.ndarray:
    """Where a pixel inside a tracked object's silhouette sees the lidar surfaces more than 0.3 m
    behind the object's box and its ray passes through the body (the box from 0.3 m above its bottom,
    :data:`~.surfaces.UNDERBODY_M`, below which the road under a car shows, to the belt line, 0.6
    of its height, or the glasshouse above it, the middle 0.6 of the length and 0.9 of the width up
    to 0.1 of the height short of the top: the lidar sampled the object sparsely or saw through
    its glass, and what lies behind or under it shows through), the face the ray enters stands for
    the object, the glasshouse's where the ray meets it through a window (not its top) before the
    body and the lidar's surface (the glass the lidar saw through), else the box's: its distance
    and face normal, open to the sky, not ground; where it sees a lidar surface on the
    object (within 0.3 m of its box), the lidar's own normal stays (a box face chosen per pixel
    flips between roof and side from frame to frame) (``distance``, ``normal`` and ``fields`` are
    updated in place). A car's roof takes snow, its doors and side windows do not, the air over its
    bonnet and beside its glasshouse keeps what lies behind it, and the road under it stays hidden.
    Returns the pixels changed.

    The silhouette is the convex hull of the projections of the surface Gaussians inside the box
    (grown by 0.1 m) above that band (not the road the box reaches down to, nor the static foliage
    of a crown reaching into it: :meth:`~.surfaces.SurfaceScene.inside_boxes`), so the air around a
    car inside its box keeps what lies behind it; for a mover, of its own returns in the sweep nearest
    the frame (within two frames, carried by its box's motion), from 20 of them: its node's
    Gaussians gather every sweep's, spread past the car by the boxes' jitter. The ray's entry into
    the box is found by the slab method in the box frame. Beside the silhouette, a surface on the
    object (above that band; for a mover with its own silhouette also below it, more than 0.05 m
    beside the box's footprint: its lowest Gaussians, not its tyres or the road under it) is its
    Gaussians' tails and takes the surface beside it (:func:`_box_shell_pixels`,
    :func:`_replace_tails`), as do the pixels within ``_BLEND_PX`` past the tails, where the tails
    composite with what lies beyond (their normals half up, half aside). A box the camera is beside
    (a corner behind its near plane, 0.1 m) with fewer than 100 returns in front of it (the lidar's
    blind zone and the frame's edge left a sliver of it in view, whose hull would cut the object in
    two) is outlined by the box itself cut at the near plane (:func:`_clipped_box_outline`), its
    body rising to ``_BONNET_SHARE`` of its height, and stands for the object only where the lidar
    saw nothing through it or saw the object itself (:func:`_on_box`), facing the camera upright.
    Each box's pixels are the numba kernel's (``fast``, where numba imports) or the numpy
    reference's. With the frame (``image`` [H, W, 3], display RGB), the object's top is snapped to
    it (:func:`_top_band_pixels`): where the frame shows what lies behind over the object's top
    edge, the band between is its Gaussians' tails too; so are its sides, once every box's shell is
    drawn (:func:`_side_bands`: a near car's surfels reach past its sides by their width, and the
    hull of its returns fills the hollow of a sloping tailgate).
    """
    changed = np.zeros(distance.shape, bool)
    up = np.asarray(surfaces.up, np.float64)
    boxes = surfaces.boxes_at(index)
    if not boxes or len(surfaces.at_frame(index)[0]) == 0:
        return changed
    h, w = distance.shape
    w2c = np.asarray(camera.world_to_camera, np.float64)
    K = np.asarray(camera.K, np.float64)
    poses = np.stack([np.asarray(T, np.float64) for T, _ in boxes])
    halves = np.stack([np.asarray(size, np.float64) / 2.0 for _, size in boxes])
    # the camera centre in every box's frame; a camera inside its box (the ego vehicle's own
    # track) gets no shell, nor a box none of whose points could be drawn: both judged for every
    # box at once before the neighbour search
    origins = np.einsum("bji,bj->bi", poses[:, :3, :3], center - poses[:, :3, 3])
    shown = ~np.all(np.abs(origins) <= halves, axis=1) & ~_boxes_miss_view(poses, halves + 0.1, w2c, K, w, h)
    poses, halves, origins = poses[shown], halves[shown], origins[shown]
    own, carried = _own_returns(surfaces, index, shown)
    # sorted along their widest axis once: each box tests the slice within its reach on it
    axis = int(np.argmax(np.ptp(own, axis=0))) if len(own) else 0
    own = own[np.argsort(own[:, axis], kind="stable")]
    keys = own[:, axis]
    not_sky = ~sky
    tails, hulls, bands = np.zeros((h, w), bool), np.zeros((h, w), bool), np.zeros((h, w), bool)
    frame = None if image is None else np.ascontiguousarray(image, np.float32)
    steps = None if frame is None else _vertical_steps(frame)
    reach = max(2, round(_TOP_SEARCH_PX * h / 270))
    kernels = load_numba_kernels("appearance.shell_kernels") if fast else None
    shell = _box_shell_pixels if kernels is None else kernels.box_shell_kernel
    sides: list[tuple[Any, ...]] = []
    for b, (T, half, o, pts) in enumerate(zip(poses, halves, origins,
                                              surfaces.inside_boxes(index, poses, halves + 0.1))):
        R, t = T[:3, :3], T[:3, 3]
        vertical = int(np.argmax(np.abs(R.T @ up)))
        floor = -half[vertical] + UNDERBODY_M
        # a mover's silhouette from its own returns where the sweep nearest the frame sampled it: its
        # node's Gaussians gather every sweep's returns in its box's frame, spread by the boxes'
        # jitter past the car the frame shows (a dark ring round a moving car in the snow,
        # docs/findings.md)
        motion = None if carried is None else carried[b]
        mover = own[:0]
        if carried is None or motion is not None:
            # the box where the sweep saw its object (the same box frame: the motion is rigid)
            then = T if motion is None else np.linalg.inv(motion) @ T
            radius = float(np.linalg.norm(half + 0.1))
            lo, hi = np.searchsorted(keys, [then[axis, 3] - radius, then[axis, 3] + radius])
            mover = _in_box_above(own[lo:hi], then[:3, :3], then[:3, 3], half + 0.1, vertical, floor)
            if motion is not None:
                mover = mover @ motion[:3, :3].T + motion[:3, 3]
        own_hull = len(mover) >= _MIN_OWN_RETURNS
        pts = mover if own_hull else _in_box_above(pts, R, t, None, vertical, floor)
        corners = (_CUBE * half) @ R.T + t
        beside = np.any(corners @ w2c[2, :3] + w2c[2, 3] <= _NEAR_M)
        if len(pts) < 3 and not beside:
            continue
        cam = pts @ w2c[:3, :3].T + w2c[:3, 3]
        cam = np.compress(cam[:, 2] > _NEAR_M, cam, axis=0)
        blind = beside and len(cam) < _MIN_BESIDE_RETURNS
        if blind:
            # the camera beside the object (a corner of its box behind the near plane): the lidar's
            # blind zone and the frame's edge may leave a sliver of its returns in view, whose hull
            # would cut the object in two (a bare triangle of bonnet in the snow); the box clipped
            # at the near plane outlines it instead
            uv = _clipped_box_outline(corners, w2c, K)
        elif len(cam) < 3:
            continue
        else:
            uv = np.stack([K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2], K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]], 1)
        if len(uv) < 3 or uv[:, 0].max() < 0 or uv[:, 0].min() >= w or uv[:, 1].max() < 0 or uv[:, 1].min() >= h:
            continue
        hull = cv2.convexHull(np.clip(np.round(uv - 0.5), -4 * w, 4 * w).astype(np.int32))
        region = _spill_region(hull, h, w)
        if region is None:
            continue
        x0, y0, x1, y1 = region
        filled = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.fillConvexPoly(filled, hull - np.array([x0, y0], np.int32), 1)
        grown = cv2.dilate(filled, np.ones((2 * _EDGE_PX + 1, 2 * _EDGE_PX + 1), np.uint8))
        # the lidar's surfaces show through the object (it sampled it sparsely, or its glass) where
        # the ray passes through its body: the box below the belt line, or the glasshouse above it
        # (the middle of the length, most of the width, short of the box's top); a ray through the
        # box's air, over the bonnet or the boot or along the top of the roof, sees what it sees
        belt = -half[vertical] + 2.0 * _BELT_SHARE * half[vertical]
        body_lo, body_hi = -half.copy(), half.copy()
        body_lo[vertical], body_hi[vertical] = floor, belt  # under the body, air: the road shows
        cabin_lo, cabin_hi = -half * _CABIN_SHARE, half * _CABIN_SHARE
        cabin_lo[vertical], cabin_hi[vertical] = belt, half[vertical] - 2.0 * _ROOF_AIR_SHARE * half[vertical]
        allowed, mine = not_sky, changed
        if blind:
            bonnet = -half[vertical] + 2.0 * _BONNET_SHARE * half[vertical]
            body_hi[vertical], cabin_lo[vertical] = bonnet, bonnet
            # the box outlines the car it stands for loosely (it also holds air over the bonnet and
            # beside the cabin): where the lidar saw a surface off the object through it, nothing
            # stood in between, and that surface stays
            allowed = not_sky & ~np.isfinite(distance)
            allowed[y0:y1, x0:x1] |= not_sky[y0:y1, x0:x1] & _on_box(
                rays[y0:y1, x0:x1], distance[y0:y1, x0:x1], center, R, t, half + _BOX_SLACK_M)
            mine = np.zeros_like(changed)
        shell(filled, grown, x0, y0, rays, distance, normal, fields["ground"], fields["open"], fields["puddle"],
              fields["track"], allowed, tails, hulls, mine, R, t, o, half, vertical, floor, center, body_lo,
              body_hi, cabin_lo, cabin_hi, _BOX_SLACK_M, _SPREAD_M if own_hull else np.inf)
        if blind:
            # which face of a loose box a ray enters, or the normal of one of a few returns, says
            # little of the surface there: what the box stands for faces the camera upright, as a
            # wall does (no snow settles on it; the rain wets it as it wets a door)
            rr, cc = np.nonzero(mine)
            flat = rays[rr, cc] - np.outer(rays[rr, cc] @ up, up)
            normal[rr, cc] = -flat / np.maximum(np.linalg.norm(flat, axis=1, keepdims=True), 1e-9)
            changed |= mine
        if frame is not None and steps is not None and not blind:
            top = _top_band_pixels if kernels is None else kernels.top_band_kernel
            top(x0, y0, x1 - x0, y1 - y0, rays, distance, center, R, t, half, _BOX_SLACK_M, vertical, floor, frame,
                steps, reach, _TOP_EDGE_STEP, _TOP_EDGE_SHARE, 1, bands)
            # the surfels reach past a side by their own width: at the box's nearest depth, in pixels
            nearest = max(float(np.min(corners @ w2c[2, :3] + w2c[2, 3])), _NEAR_M)
            sides.append((region, R, t, half, vertical, floor, round(_SIDE_REACH_M * K[0, 0] / nearest)))
    if frame is not None and sides:
        _side_bands(sides, rays, distance, center, frame, bands, kernels)
    replaced = (tails & ~hulls) | bands
    # the pixels just past the tails composite them with what lies beyond (a normal half up, half
    # aside): they take what lies beyond too, and give nothing
    ring = (cv2.dilate(replaced.view(np.uint8), np.ones((2 * _BLEND_PX + 1,) * 2, np.uint8)).view(bool)
            & ~replaced & ~hulls & not_sky & np.isfinite(distance))
    _replace_tails(replaced | ring, ~(tails | hulls | bands | ring) & not_sky & np.isfinite(distance), distance,
                   normal, fields)
    return changed


def moving_pixels(surfaces: SurfaceScene, index: int, camera: Any, rays: np.ndarray, distance: np.ndarray,
                  candidates: np.ndarray) -> np.ndarray:
    """[H, W] bool: the pixels of ``candidates`` (:func:`box_shells`' changed pixels) whose surface,
    ``distance`` [H, W] (m) along ``rays`` [H, W, 3] from ``camera``'s centre, lies on a moving
    object at frame ``index``: inside a moving track's box (:meth:`~.surfaces.SurfaceScene.boxes_at`,
    ``moving_only``; ``_BOX_SLACK_M`` of slack, as its shell's) above its underbody line
    (:data:`~.surfaces.UNDERBODY_M`: the road under a car is no part of it). Each box tests only
    the pixels inside its corners' projected bounds (the whole frame where it reaches behind the
    camera)."""
    h, w = np.shape(distance)
    out = np.zeros((h, w), bool)
    boxes = surfaces.boxes_at(index, moving_only=True)
    if not boxes:
        return out
    asked = np.asarray(candidates, bool) & np.isfinite(distance)
    center = np.asarray(camera.center, np.float64)
    w2c, K = np.asarray(camera.world_to_camera, np.float64), np.asarray(camera.K, np.float64)
    up = np.asarray(surfaces.up, np.float64)
    for T, size in boxes:
        T = np.asarray(T, np.float64)
        R, half = T[:3, :3], np.asarray(size, np.float64) / 2.0 + _BOX_SLACK_M
        cam = ((_CUBE * half) @ R.T + T[:3, 3]) @ w2c[:3, :3].T + w2c[:3, 3]
        if np.all(cam[:, 2] <= _NEAR_M):
            continue  # behind the camera
        x0, y0, x1, y1 = 0, 0, w, h
        if np.all(cam[:, 2] > _NEAR_M):
            u = K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2]
            v = K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]
            x0, x1 = max(0, int(np.floor(u.min())) - 1), min(w, int(np.ceil(u.max())) + 1)
            y0, y1 = max(0, int(np.floor(v.min())) - 1), min(h, int(np.ceil(v.max())) + 1)
            if x0 >= x1 or y0 >= y1:
                continue
        rr, cc = np.nonzero(asked[y0:y1, x0:x1] & ~out[y0:y1, x0:x1])
        if rr.size == 0:
            continue
        rr, cc = rr + y0, cc + x0
        local = (center + rays[rr, cc].astype(np.float64) * distance[rr, cc, None] - T[:3, 3]) @ R
        vertical = int(np.argmax(np.abs(R.T @ up)))
        on = in_box(local, half) & (local[:, vertical] >= -half[vertical] + _BOX_SLACK_M + UNDERBODY_M)
        out[rr[on], cc[on]] = True
    return out


def _own_returns(surfaces: SurfaceScene, index: int,
                 shown: np.ndarray) -> tuple[np.ndarray, list[np.ndarray | None] | None]:
    """(the movers' returns [M, 3] of the sweep nearest frame ``index`` within two frames, empty
    without one; ``None`` when that sweep is the frame's own, else for each box of
    :meth:`~.surfaces.SurfaceScene.boxes_at` kept by ``shown`` [B] bool the rigid motion [4, 4]
    that carries its object from the sweep's frame to ``index``, ``None`` where it has no box
    there): a frame without a sweep (PandaSet's logs miss some) takes its neighbour's, moved with
    each box, so its movers' silhouettes do not jump back to their Gaussians' hull for a frame."""
    returns = None if surfaces.analysis is None else surfaces.analysis.returns
    sweep = None if returns is None else returns.nearest_sweep(index)
    if returns is None or sweep is None:
        return np.zeros((0, 3)), None
    if sweep == index:
        return returns.own_tracked(index), None
    motions = _box_motions(surfaces.boxes, index, sweep)
    return returns.own_tracked(sweep), [m for m, keep in zip(motions, shown) if keep]


def _box_motions(boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray]], index: int,
                 other: int) -> list[np.ndarray | None]:
    """For each of ``boxes`` (:attr:`~.surfaces.SurfaceScene.boxes`: frames, poses, sizes) annotated
    at frame ``index``, in :meth:`~.surfaces.SurfaceScene.boxes_at`'s order, the rigid motion [4, 4]
    (world to world) that carries a point on its object at frame ``other`` to where it is at
    ``index`` (its pose at ``index`` times the inverse of its pose at ``other``); ``None`` for a box
    not annotated at ``other``."""
    out: list[np.ndarray | None] = []
    for frames, poses, _ in boxes:
        hit = np.nonzero(frames == index)[0]
        if not hit.size:
            continue
        then = np.nonzero(frames == other)[0]
        out.append(None if not then.size else poses[int(hit[0])] @ np.linalg.inv(poses[int(then[0])]))
    return out


def _in_box_above(points: np.ndarray, R: np.ndarray, t: np.ndarray, half: np.ndarray | None, vertical: int,
                  floor: float) -> np.ndarray:
    """The ``points`` [N, 3] (world, m) at least ``floor`` above the centre ``t`` of the box with
    rotation ``R`` along its axis ``vertical`` (the object, not the road its box reaches down to)
    and, given ``half`` [3], within those half-sizes of the centre on every axis."""
    if half is None:
        return np.compress((points - t) @ R[:, vertical] >= floor, points, axis=0)
    local = (points - t) @ R
    return np.compress((local[:, vertical] >= floor) & np.all(np.abs(local) <= half, axis=1), points, axis=0)


def _vertical_steps(image: np.ndarray) -> np.ndarray:
    """[H, W] float32: the colour step from each pixel's upper neighbour to it (RGB distance of the
    frame blurred by 1 px; 0 on the top row)."""
    blurred = cv2.GaussianBlur(np.asarray(image, np.float32), (3, 3), 0.8)
    out = np.zeros(blurred.shape[:2], np.float32)
    d = blurred[1:] - blurred[:-1]
    # the three squares added channel by channel: np.sum's order over an axis of three, to the bit,
    # without its reduction over a short last axis (a tenth of the time)
    out[1:] = np.sqrt(np.square(d[..., 0]) + np.square(d[..., 1]) + np.square(d[..., 2]))
    return out


def _side_bands(boxes: list[tuple[Any, ...]], rays: np.ndarray, distance: np.ndarray, center: np.ndarray,
                frame: np.ndarray, bands: np.ndarray, kernels: Any) -> None:
    """The bands beside each box's left and right edges that the frame shows as what lies beside it,
    marked in ``bands`` [H, W] bool: :func:`_top_band_pixels` run on the frame turned so that a side
    is its top (transposed for the left edge, mirrored and transposed for the right), on the maps as
    every box's shell left them, each side's bands closed along it over gaps of up to
    ``2 _SIDE_GAP_PX`` rows. ``boxes``: per box its region (x0, y0, x1, y1), rotation, centre,
    half-size, vertical axis, floor and its surfels' reach (pixels)."""
    h, w = distance.shape
    cap, lookback = max(2, round(_SIDE_SEARCH_PX * h / 270)), max(1, round(_SIDE_LOOKBACK_PX * h / 270))
    # closed along the side (the turned frame's rows are the frame's columns): a gap of rows between
    # two rows of band is filled to the shorter of their reaches
    along = np.ones((1, 2 * max(1, round(_SIDE_GAP_PX * h / 270)) + 1), np.uint8)
    top = _top_band_pixels if kernels is None else kernels.top_band_kernel
    # transposed once; the mirrored side's arrays are their rows reversed (a copy, not a transpose
    # again), and its steps the transposed frame's reversed: the 3 x 3 blur of a flipped image is the
    # flipped blur to the bit and a step's square does not change sign (only a transpose rounds
    # the separable blur's sums differently)
    turned_rays = np.ascontiguousarray(rays.transpose(1, 0, 2))
    turned_distance = np.ascontiguousarray(distance.T)
    turned_frame = np.ascontiguousarray(frame.transpose(1, 0, 2))
    turned_steps = _vertical_steps(turned_frame)
    for mirrored in (False, True):
        cols = slice(None, None, -1) if mirrored else slice(None)
        if mirrored:
            turned_rays, turned_distance, turned_frame = (np.ascontiguousarray(a[::-1]) for a in
                                                          (turned_rays, turned_distance, turned_frame))
            turned_steps = np.concatenate([turned_steps[:1], turned_steps[:0:-1]])
        turned_bands = np.zeros((w, h), bool)
        for (x0, y0, x1, y1), R, t, half, vertical, floor, reach in boxes:
            if reach < 2:  # a far object's surfels reach past it by less than a pixel
                continue
            start = w - x1 if mirrored else x0
            top(y0, start, y1 - y0, x1 - x0, turned_rays, turned_distance, center, R, t, half, _BOX_SLACK_M,
                vertical, floor, turned_frame, turned_steps, min(reach, cap), _TOP_EDGE_STEP, _TOP_EDGE_SHARE, lookback,
                turned_bands)
        turned_bands = cv2.morphologyEx(turned_bands.view(np.uint8), cv2.MORPH_CLOSE, along).view(bool)
        bands |= turned_bands.T[:, cols]


def _top_band_pixels(x0: int, y0: int, rw: int, rh: int, rays: np.ndarray, distance: np.ndarray, center: np.ndarray,
                     R: np.ndarray, t: np.ndarray, half: np.ndarray, slack: float, vertical: int, floor: float,
                     image: np.ndarray, steps: np.ndarray, reach: int, step_min: float, share: float,
                     lookback: int, bands: np.ndarray) -> None:
    """The bands over one box's top that the frame shows as what lies behind it, marked in ``bands``
    [H, W] bool (the numpy reference of :func:`~.shell_kernels.top_band_kernel`).

    Over the ``rw`` x ``rh`` region from column ``x0``, row ``y0``, the object's surface is where
    the surface each pixel sees (``rays`` [H, W, 3] from ``center``, ``distance`` [H, W] m) lies in
    its box (rotation ``R``, centre ``t``, half-size ``half`` grown by ``slack``) above ``floor`` on
    axis ``vertical``. In each column the object's top is its first pixel from the top under a
    pixel whose surface lies more than 1 m farther (one of the ``lookback`` pixels above it: a
    side's blend into what lies beyond takes a few, :func:`_side_bands`): its Gaussians reach past
    its edge by their own width (a parked car's roof's returns spread snow in a band over the roof line,
    docs/findings.md). Below it, within ``reach`` rows, the first colour step of the frame
    (``steps`` [H, W], :func:`_vertical_steps`) of at least ``step_min`` and ``share`` of the
    strongest there is the edge the frame shows (a strong step at the top itself: the frame shows
    the object where the maps put it); the rows between (two at least) are a band when their mean
    colour in the frame (``image`` [H, W, 3], display RGB) is nearer the colour over the top than
    that of the two rows under the edge (what lies behind, textured, may step less than the edge:
    the object's own strip does not pass). Each band's height is at most the median of its column's and
    the four nearest columns' (0 where none; the region's edge columns repeated): one column's
    texture does not cut a notch. Only the band's pixels on the object are marked.
    """
    ys, xs = slice(y0, y0 + rh), slice(x0, x0 + rw)
    seen = distance[ys, xs]
    finite = np.isfinite(seen)
    point = (center - t + rays[ys, xs] * np.where(finite, seen, 0.0)[..., None]) @ R
    on = finite & np.all(np.abs(point) <= half + slack, axis=-1) & (point[..., vertical] >= floor)
    heights, tops = np.zeros(rw, np.int64), np.full(rw, -1, np.int64)
    for c in range(rw):
        for r in np.flatnonzero(on[1:, c] & ~on[:-1, c]) + 1:
            before = seen[max(0, r - lookback):r, c]
            if not np.any(np.isfinite(before) & (before > seen[r, c] + 1.0)):
                continue
            window = steps[y0 + r:y0 + min(rh, r + reach + 1), x0 + c].astype(np.float64)
            if window.size < 3:
                break
            edge = r + int(np.argmax(window >= max(step_min, share * float(window.max()))))
            if edge < r + 2:
                break
            column = image[ys, x0 + c].astype(np.float64)
            band = column[r:edge].mean(axis=0)
            below = column[edge:min(rh, edge + 2)].mean(axis=0)
            if np.sum((band - column[r - 1]) ** 2) < np.sum((band - below) ** 2):
                heights[c], tops[c] = edge - r, r
            break
    for col in np.flatnonzero(tops >= 0):
        neighbours = heights[np.clip(np.arange(col - 2, col + 3), 0, rw - 1)]
        rows = slice(tops[col], tops[col] + min(int(np.median(neighbours)), heights[col]))
        bands[y0 + rows.start:y0 + rows.stop, x0 + col] |= on[rows, col]


def _on_box(rays: np.ndarray, distance: np.ndarray, center: np.ndarray, R: np.ndarray, t: np.ndarray,
            reach: np.ndarray) -> np.ndarray:
    """[h, w] bool: whether the surface each pixel sees (``rays`` [h, w, 3] from ``center``,
    ``distance`` [h, w] m, ``inf`` where none) lies inside the box of rotation ``R``, centre ``t`` and
    half-size ``reach`` [3] (m)."""
    finite = np.isfinite(distance)
    local = (center - t + rays * np.where(finite, distance, 0.0)[..., None]) @ R
    return finite & np.all(np.abs(local) <= reach, axis=-1)


#: The 12 edges of the unit cube of :data:`_CUBE`: the pairs of corners that differ on one axis.
_CUBE_EDGES = np.array([(i, j) for i in range(8) for j in range(i + 1, 8)
                        if np.count_nonzero(_CUBE[i] != _CUBE[j]) == 1])


def _clipped_box_outline(corners: np.ndarray, w2c: np.ndarray, K: np.ndarray) -> np.ndarray:
    """[V, 2] pixel positions (u, v) whose convex hull is the image of the box with ``corners`` [8, 3]
    (world, in :data:`_CUBE`'s order) cut at the near plane (camera depth ``_NEAR_M``): its corners in
    front of it and the points where its edges cross it. The cut box is convex, and so is its image:
    the hull of its vertices' images. Empty [0, 2] where no corner lies in front."""
    cam = corners @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2] - _NEAR_M
    a, b = cam[_CUBE_EDGES[:, 0]], cam[_CUBE_EDGES[:, 1]]
    za, zb = z[_CUBE_EDGES[:, 0]], z[_CUBE_EDGES[:, 1]]
    cross = (za > 0) != (zb > 0)
    share = za[cross] / (za[cross] - zb[cross])
    points = np.concatenate([cam[z > 0], a[cross] + share[:, None] * (b[cross] - a[cross])])
    depth = np.maximum(points[:, 2], _NEAR_M)  # on the plane: exactly _NEAR_M up to rounding
    return np.stack([K[0, 0] * points[:, 0] / depth + K[0, 2], K[1, 1] * points[:, 1] / depth + K[1, 2]], 1)


def _spill_region(hull: np.ndarray, h: int, w: int) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1): the bounding rectangle of ``hull`` grown by ``_SPILL_PX`` (at 270 rows),
    clipped to the ``w`` x ``h`` frame; ``None`` where nothing of it is in the frame."""
    reach = max(1, round(_SPILL_PX * h / 270))
    x0, y0, bw, bh = cv2.boundingRect(hull)
    x1, y1 = min(w, x0 + bw + reach), min(h, y0 + bh + reach)
    x0, y0 = max(0, x0 - reach), max(0, y0 - reach)
    return None if x1 <= x0 or y1 <= y0 else (x0, y0, x1, y1)


def _box_shell_pixels(filled: np.ndarray, grown: np.ndarray, x0: int, y0: int, rays: np.ndarray,
                      distance: np.ndarray, normal: np.ndarray, ground: np.ndarray, open_: np.ndarray,
                      puddle: np.ndarray, track: np.ndarray, allowed: np.ndarray, tails: np.ndarray,
                      hulls: np.ndarray, changed: np.ndarray, R: np.ndarray, t: np.ndarray,
                      o: np.ndarray, half: np.ndarray, vertical: int, floor: float, center: np.ndarray,
                      body_lo: np.ndarray, body_hi: np.ndarray, cabin_lo: np.ndarray, cabin_hi: np.ndarray,
                      slack: float, beside: float) -> None:
    """One box of :func:`box_shells`, in place: the numpy reference of
    :func:`~.shell_kernels.box_shell_kernel` (its arguments).

    First the tails: pixels of the region (``filled``, the hull of the object's returns, and
    ``grown``, that hull grown by ``_EDGE_PX``, both [h, w] uint8 from column ``x0``, row ``y0``)
    outside ``grown`` whose surface lies on the object (inside its box, ``slack`` included, above
    ``floor`` on axis ``vertical``, or more than ``beside`` (m, ``inf``: never) outside the box's
    footprint: a mover's Gaussians spread past it) are its Gaussians' tails over the road or the
    facade beside it (a car's roof's upward normals spread snow into the air above it, its sides' a
    dark rim on the road); ``grown`` is added to ``hulls``. Then the shell of every ``filled``
    pixel (see :func:`box_shells`): ``behind`` where the ray enters the box, passes through its body
    (``body_lo`` .. ``body_hi``) or its glasshouse (``cabin_lo`` .. ``cabin_hi``) and sees the
    lidar's surface more than ``slack`` behind the entry; ``on`` where that surface lies on the
    object.
    """
    rh, rw = filled.shape
    inside, hull = grown.astype(bool), filled.astype(bool)
    hulls[y0:y0 + rh, x0:x0 + rw] |= inside
    seen = distance[y0:y0 + rh, x0:x0 + rw]
    rr, cc = np.nonzero(~inside & allowed[y0:y0 + rh, x0:x0 + rw] & np.isfinite(seen))
    if rr.size:
        point = (center - t + rays[rr + y0, cc + x0] * seen[rr, cc, None]) @ R  # in the box frame
        # a mover's Gaussians spread past it: below the underbody line, beside the box's footprint
        spread = np.any(np.delete(np.abs(point) > half + beside, vertical, axis=1), axis=1)
        on = in_box(point, half + slack) & ((point[:, vertical] >= floor) | spread)
        tails[rr[on] + y0, cc[on] + x0] = True
    rr, cc = np.nonzero(hull & allowed[y0:y0 + rh, x0:x0 + rw])
    rr, cc = rr + y0, cc + x0
    if rr.size == 0:
        return
    d = rays[rr, cc] @ R  # ray directions in the box frame
    near, far = _slab_interval(o, d, -half, half)
    enters = (far >= near) & (near > 0.0)
    seen = distance[rr, cc]
    through_body = _slab_hits(o, d, body_lo, body_hi) | _slab_hits(o, d, cabin_lo, cabin_hi)
    behind = enters & (near + slack < seen) & through_body
    on = np.zeros_like(enters)  # the lidar's surface lies on the object
    finite = enters & np.isfinite(seen)
    point = o + d[finite] * seen[finite, None]
    on[finite] = in_box(point, half + slack) & (point[:, vertical] >= floor)
    on &= ~behind
    hit = behind | on
    # through the body, the face the ray enters stands for the surface; on the object, the
    # lidar's own (smoothed) normal stays: a box face chosen per pixel flips between the roof
    # and a side from frame to frame, and the roof the camera looks down through is not the
    # side window the lidar sampled
    br, bc, bnear, bd, bseen = rr[behind], cc[behind], near[behind], d[behind], seen[behind]
    # a ray that meets the glasshouse through a window (a face other than its top), before the
    # body and what the lidar saw, takes that face: the glass the lidar saw through, not the box's
    # top over a windscreen (its top stood over the wall behind a box taller than its car)
    b_in, b_out = _slab_interval(o, bd, body_lo, body_hi)
    c_in, c_out = _slab_interval(o, bd, cabin_lo, cabin_hi)
    hit_b = (b_out >= np.maximum(b_in, 0.0)) & (b_out > 0.0)
    hit_c = (c_out >= np.maximum(c_in, 0.0)) & (c_out > 0.0)
    cabin_axis, cabin_sign = _entry_face(o + bd * c_in[:, None], cabin_lo, cabin_hi)
    cabin = hit_c & (c_in < bseen) & ~(hit_b & (b_in < c_in)) & (cabin_axis != vertical)
    box_axis, box_sign = _entry_face(o + bd * bnear[:, None], -half, half)
    axis, sign = np.where(cabin, cabin_axis, box_axis), np.where(cabin, cabin_sign, box_sign)
    face = np.zeros((br.size, 3))
    face[np.arange(br.size), axis] = sign
    normal[br, bc] = face @ R.T
    distance[br, bc] = np.where(cabin, c_in, bnear)
    rr, cc = rr[hit], cc[hit]
    ground[rr, cc] = 0.0
    open_[rr, cc] = 1.0
    puddle[rr, cc] = 0.0
    track[rr, cc] = 0.0
    changed[rr, cc] = True


def _entry_face(entry: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """([N] axis, [N] sign) of the face of the box [lo, hi] (box frame) each point of ``entry``
    [N, 3] lies on: the first axis of the largest |offset from its middle| / half-size."""
    offset = entry - (lo + hi) / 2.0
    axis = np.argmax(np.abs(offset) / ((hi - lo) / 2.0), axis=1)
    return axis, np.sign(offset[np.arange(len(entry)), axis])


def _replace_tails(tails: np.ndarray, source: np.ndarray, distance: np.ndarray, normal: np.ndarray,
                   fields: dict[str, np.ndarray]) -> None:
    """Give each pixel of ``tails`` [H, W] the surface (distance, normal, attributes) of its nearest
    ``source`` pixel (in place): what lies beside the object, continued under its Gaussians' tails."""
    if not tails.any() or not source.any():
        return
    _, labels = cv2.distanceTransformWithLabels((~source).astype(np.uint8), cv2.DIST_L2, 5,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    flat = np.flatnonzero(source)
    of_label = np.zeros(int(labels.max()) + 1, np.int64)
    of_label[labels.ravel()[flat]] = flat
    rr, cc = np.nonzero(tails)
    src = np.unravel_index(of_label[labels[rr, cc]], tails.shape)
    distance[rr, cc] = distance[src]
    normal[rr, cc] = normal[src]
    for name in fields:
        fields[name][rr, cc] = fields[name][src]
