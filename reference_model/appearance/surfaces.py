"""The surfaces a scene's lidar shows, as Gaussians with per-Gaussian attributes for weather appearance.

From the scene's lidar initialisation
(:func:`~wcbench.reference_model.scene_graph.lidar_init.init_scene_from_lidar`: static Gaussians
plus one rigid node per moving track) each Gaussian gets, anchored in the world
(so that what is drawn from them does not flicker from frame to frame):

* a **normal** (the smallest principal axis of its 16 nearest neighbours, turned toward the
  cameras' path; a node's in its box frame, turned outward; on a boxed object's side,
  :func:`object_sides`, never facing up);
* **ground** (1 where the normal points up, more than sideways, and the Gaussian lies on the local
  ground height);
* **open** (1 where no return that overhangs it, facing up or down, lies half a metre higher within
  half a metre sideways, nor any return within 0.15 m: open to the sky, so snow settles and rain
  falls; 0 under a car or a roof, half under a tree's crown (foliage by the spread of its returns
  or, where the scene ships lidar semantics, by their label), which holds part of the fall and
  lets the rest through, while a wall shelters none of the ground beside it, and a parked track's
  body only the ground inside its box's footprint),
  averaged with the normals over the 8 nearest Gaussians (real lidar is noisy at a voxel's scale);
  the ground's spread over the ground plane instead (:class:`~.open_ground.OpenGround`), which the
  ground the lidar missed reads too;
* **puddle**: a smooth noise field over the ground plane (two octaves of value noise, 4 m and
  1.5 m), thresholded by the editor at the rain's puddle fraction;
* **track**: closeness to the wheel paths of the traffic (the ego vehicle's path and every moving
  vehicle's, extended along the lane; people and cyclists leave none), where snow is compacted and water splashed away.

The static Gaussians are drawn as surfels, flat on their surface; one whose returns lie on a line
in the air (a wire) is as wide across that line as its returns spread (:func:`~.line_surfels.line_surfels`).

Only the static scene becomes surfaces: returns of things that move without a box, people and
noise (:mod:`wcbench.reference_model.scene_analysis.motion`) are left out of the static cloud, and
a frame's own dynamic returns are drawn at that frame only (no normal facing the sky, nothing
settles on them; those on the road's surface or alone are noise, not drawn), so nothing is
painted where a pedestrian or an untracked car once was.
Only what a real scene has is read: lidar, poses, tracks (docs/design.md §7).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from wcbench.reference_model.appearance.ground_cells import CELL_M, cell_heights, connected_ground
from wcbench.reference_model.appearance.line_surfels import line_surfels
from wcbench.reference_model.appearance.open_ground import OpenGround
from wcbench.reference_model.appearance.value_noise import value_noise
from wcbench.reference_model.scene_analysis.analysis import SceneAnalysis
from wcbench.reference_model.scene_analysis.normals import pca_normals, principal_frames
from wcbench.reference_model.scene_graph.completion import Facades, fit_facades
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.scene_graph.lidar_init import (
    LidarInitOptions,
    init_scene_from_lidar,
    sample_image,
    voxel_downsample,
)
from wcbench.reference_model.scene_graph.nodes import SceneGaussians
from wcbench.reference_model.weather.particle_geometry import quat_from_axis_to

__all__ = ["ATTRIBUTES", "UNDERBODY_M", "MirroredStatic", "SurfaceScene", "build_surfaces", "in_box", "kerb_faces",
           "lane_paths", "object_sides", "open_to_sky"]

#: Attribute channels, in order.
ATTRIBUTES = ("nx", "ny", "nz", "ground", "open", "puddle", "track")

#: Half the distance between a car's wheels (m), and the spread of a wheel path (m): a tyre's half-width
#: (0.11 m) and the lateral wander of traffic in a lane (standard deviation ~0.25 m, as pavement
#: engineering measures it for rutting studies) added in quadrature.
_HALF_TRACK_M, _WHEEL_PATH_SIGMA_M = 0.8, float(np.hypot(0.11, 0.25))
#: How far a lane's wheel paths are extended beyond the observed path, each way (m): earlier traffic
#: drove the same lane.
_LANE_EXTENSION_M = 120.0
#: Classes (:data:`wcbench.core.classes.CLASSES`) whose tracks leave wheel paths of a car's track.
_WHEELED = ("vehicle",)
#: Shelter from falling snow and rain (m): a return higher by ``_SHELTER_RISE_M`` within
#: ``_SHELTER_REACH_M`` sideways shelters a point when it faces up or down (a roof, a canopy, a car's
#: body over the road), within ``_SHELTER_WALL_M`` (about a voxel and a half) whatever it faces: a
#: vertical wall does not overhang the ground beside it.
_SHELTER_RISE_M, _SHELTER_REACH_M, _SHELTER_WALL_M = 0.5, 0.5, 0.15
#: Up-component of a return's normal from which it overhangs what lies below it.
_OVERHANG_UP = 0.3
#: A tree's crown lets part of the fall through: returns scattered through a volume (their surface
#: variation over ``_FOLIAGE_VARIATION``: foliage, not a roof, a wall or a car's body) intercept
#: ``_CROWN_INTERCEPTION`` of the fall (a share of the snowfall a canopy holds, growing with its
#: leaf area; Hedstrom & Pomeroy 1998).
_FOLIAGE_VARIATION, _CROWN_INTERCEPTION = 0.1, 0.5
#: A static surfel off the ground is turned toward each view unless this share of its this many
#: nearest returns is foliage (:attr:`SurfaceScene.view_turned`).
_TURN_NEIGHBOURS, _TURN_MAX_FOLIAGE = 16, 0.1
#: A static surfel's thickness (standard deviation along its normal) over its width: a few cm at
#: the 0.1 m voxel, the noise of a lidar return's range.
_SURFEL_THICKNESS = 0.25
#: Voxel (m) of a frame's own dynamic returns.
_DYNAMIC_VOXEL_M = 0.1
#: A frame's dynamic return is drawn only if it stands this far above the ground (m; lower it is
#: the road's own surface, misread as moving) and has other dynamic returns within
#: ``_DYNAMIC_NEIGHBOUR_M``: a tenth of what a patch that wide facing the sensor gives at its
#: distance d, on a grid of 0.2 x 0.6 degrees (a spinning lidar's column step and its coarsest beam
#: spacing; PandaSet's Pandar64 and Waymo's top lidar are finer), 6,800 / d^2, at least 3 and at
#: most 20: a person or a car is sampled by many beams, a few returns floating in the air are spray
#: or noise.
_DYNAMIC_ABOVE_GROUND_M, _DYNAMIC_NEIGHBOUR_M = 0.2, 0.5
_DYNAMIC_PATCH_RETURNS_M2, _DYNAMIC_SHARE, _DYNAMIC_NEIGHBOURS = 6800.0, 0.1, (3, 20)
#: A ground cell (2 m) gives the height within this distance of its centre (m); beyond, the plane.
_CELL_REACH_M = 4.0
#: Static balls :meth:`SurfaceScene.near` keeps (a scene has about a thousand distinct box poses).
_BALL_MEMO = 4096
#: Queries of fewer points than this run on one thread: starting the k-d tree's threads costs more
#: than they save (0.7 ms for 100 points, measured on the 2-core machine; docs/findings.md).
_THREADED_QUERY = 10_000
#: An object's side: inside its box (grown by ``_SIDE_MARGIN_M`` sideways, for the annotation's fit),
#: from ``_SIDE_MARGIN_M`` above the box's bottom (the road under it, with a lidar return's range
#: noise) up to ``_SIDE_SHARE`` of its height all round (a car's bonnet and boot lie higher, the
#: bonnet at ~0.6 of a sedan's 1.45 m: below, its doors, wheels and bumpers), and up to
#: ``_SIDE_TOP_SHARE`` within ``_SIDE_BAND_M`` of its long faces (a door and a side window, with the
#: glasshouse's slope inward; the roof keeps its edges). There the surface is vertical or faces down,
#: whatever the PCA normals of a few returns say (docs/design.md §7).
_SIDE_SHARE, _SIDE_TOP_SHARE, _SIDE_BAND_M, _SIDE_MARGIN_M = 0.5, 0.85, 0.25, 0.1
#: Height above a box's bottom (m) below which an object has no surface facing up and the space under
#: it is air: a car's sills and bumpers lie higher, so an upward return there is the road it stands on
#: (a moving car's node carried a patch of road, its normal turned outward, facing down, frame after
#: frame), and a ray through that band alone passes under the body.
UNDERBODY_M = 0.3
#: The fewest returns above :data:`UNDERBODY_M` in a parked box that outline the ground its body
#: shelters (fewer, and its whole footprint does: a car the lidar barely saw).
_OUTLINE_RETURNS = 20
#: Up-component (box frame) above which a return counts as facing up for :data:`UNDERBODY_M`.
_FACING_UP = 0.8
#: A static Gaussian is ground when it lies within ``_GROUND_WITHIN_M`` of the local ground height
#: and its normal's up-component exceeds ``_GROUND_UP``: at a kerb the normals of the road, the face
#: and the sidewalk blend into a slope of 0.5-0.6, which at 0.8 left a bare dark band between two
#: snowed surfaces (the PandaSet right camera, docs/findings.md); a wheel or a wall's foot faces
#: sideways.
_GROUND_UP, _GROUND_WITHIN_M = 0.3, 0.3
#: A return facing sideways within ``_GROUND_WITHIN_M`` of the ground is a kerb's face, ground too,
#: when no solid return (foliage left out) between that height and ``_KERB_TALL_M`` over the ground
#: lies within ``_KERB_REACH_M`` of it along the ground: near the camera the lidar resolves a kerb's face as
#: vertical (normals' up-component 0.1-0.25, under ``_GROUND_UP``), and it stayed a bare dark band
#: beside a parked car where the rest of the kerb, blended into a slope, took snow (PandaSet right
#: camera, docs/findings.md); a wall's foot, a pole's or a wheel has its structure rising above it.
_KERB_REACH_M, _KERB_TALL_M = 0.3, 2.0


def open_to_sky(points: np.ndarray, normals: np.ndarray, *, up: np.ndarray,
                shelters: np.ndarray | None = None, porous: np.ndarray | None = None) -> np.ndarray:
    """How much of the falling snow and rain reaches each point, in [0, 1].

    A return 0.5 m higher that overhangs the point (its normal's up-component above 0.3 in
    magnitude: a roof, a canopy, a car's body) within 0.5 m sideways, or any return within 0.15 m,
    among the returns that may shelter (``shelters``), shelters it: 0. Where most of them are
    ``porous`` (a tree's crown: foliage, which holds part of the fall and lets the rest through),
    0.5. Otherwise 1. The fall is taken as vertical, so a wall shelters none of the
    ground beside it, while the ground under a car or a roof stays dry and under a tree gets half.

    Parameters
    ----------
    points : ndarray [N, 3]
        World positions (m).
    normals : ndarray [N, 3]
        Unit normals (unoriented).
    up : ndarray [3]
        Unit up vector.
    shelters : ndarray [N] bool, optional
        The returns that may shelter others (default all).
    porous : ndarray [N] bool, optional
        The returns that let part of the fall through (default none).

    Returns
    -------
    ndarray [N] float64
        1 open, 0.5 under mostly porous shelter, 0 sheltered.
    """
    points = np.asarray(points, np.float64)
    up = np.asarray(up, np.float64)
    n = len(points)
    for name, mask in (("shelters", shelters), ("porous", porous)):
        if mask is not None and np.shape(mask) != (n,):
            raise ValueError(f"{name} has shape {np.shape(mask)}; ({n},) was expected, one per point")
    if n == 0:
        return np.zeros(0)
    xy = points @ _plane_axes(up).T
    height = points @ up
    dist, idx = cKDTree(xy).query(xy, k=min(32, n), distance_upper_bound=_SHELTER_REACH_M, workers=-1)
    idx = np.asarray(idx).reshape(n, -1)
    dist = np.asarray(dist).reshape(n, -1)
    other = np.minimum(idx, n - 1)
    overhang = (np.abs(np.asarray(normals, np.float64)[other] @ up) > _OVERHANG_UP) | (dist <= _SHELTER_WALL_M)
    if shelters is not None:
        overhang &= np.asarray(shelters, bool)[other]
    above = (idx < n) & (height[other] - height[:, None] > _SHELTER_RISE_M) & overhang
    sheltered = above.any(axis=1)
    if porous is None:
        return np.where(sheltered, 0.0, 1.0)
    # foliage where most of the shelter is (a leaf seen flat among them makes no roof)
    foliage = np.count_nonzero(above & np.asarray(porous, bool)[other], axis=1) * 2 > np.count_nonzero(above, axis=1)
    return np.where(~sheltered, 1.0, np.where(foliage, 1.0 - _CROWN_INTERCEPTION, 0.0))


def object_sides(points: np.ndarray, boxes: list[tuple[np.ndarray, np.ndarray]], *,
                 up: np.ndarray) -> np.ndarray:
    """Which points lie on the side of a boxed object: inside a box (grown by 0.1 m sideways), from
    0.1 m above its bottom up to half its height all round (a car's doors, wheels and bumpers, below
    its bonnet and boot), and up to 0.85 of its height within 0.25 m of its long faces (its doors and
    side windows, below the roof); the constants ``_SIDE_*``.

    Parameters
    ----------
    points : ndarray [N, 3]
        World positions (m).
    boxes : list of (ndarray [4, 4], ndarray [3])
        Object-to-world poses (box x along the length) and sizes [l, w, h] (m).
    up : ndarray [3]
        Unit up vector.

    Returns
    -------
    ndarray [N] bool
    """
    return _box_parts(points, boxes, up=up)[0]


def _box_parts(points: np.ndarray, boxes: list[tuple[np.ndarray, np.ndarray]], *,
               up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """[N] bool masks of ``points`` [N, 3]: on a box's side (:func:`object_sides`), on its body
    (inside it grown by 0.1 m sideways, more than 0.1 m above its bottom) and under it (inside its
    footprint, not grown, up to 0.1 m above its bottom: the road under a car) and, where at least
    ``_OUTLINE_RETURNS`` of the points stand in the box above :data:`UNDERBODY_M` (the body, not
    the road or a kerb), inside their outline on the ground (the convex hull of their positions
    across the box): an annotated box is a rectangle round a car's rounded corners and mirrors,
    and the ground in its corners beside a bumper is open to the fall (a dark, bare lobe at a
    parked car's corner in the snow, docs/findings.md)."""
    points = np.asarray(points, np.float64)
    out = np.zeros(len(points), bool)
    body, under = out.copy(), out.copy()
    if not len(points) or not boxes:
        return out, body, under
    tree = cKDTree(points)
    up = np.asarray(up, np.float64)
    for T, size in boxes:
        T, half = np.asarray(T, np.float64), np.asarray(size, np.float64) / 2.0
        near = np.asarray(tree.query_ball_point(T[:3, 3], float(np.linalg.norm(half + _SIDE_MARGIN_M))), np.int64)
        if near.size == 0:
            continue
        local = (points[near] - T[:3, 3]) @ T[:3, :3]
        vertical = int(np.argmax(np.abs(T[:3, :3].T @ up)))
        rise = local[:, vertical] * np.sign((T[:3, :3].T @ up)[vertical]) + half[vertical]  # above the bottom
        flat = [i for i in range(3) if i != vertical]
        across = np.all(np.abs(local[:, flat]) <= half[flat] + _SIDE_MARGIN_M, axis=1)
        lateral = flat[int(np.argmin(half[flat]))]  # across the width: the long faces' axis
        height = 2.0 * half[vertical]
        low = rise < _SIDE_SHARE * height
        flank = (np.abs(local[:, lateral]) > half[lateral] - _SIDE_BAND_M) & (rise < _SIDE_TOP_SHARE * height)
        out[near[across & (rise > _SIDE_MARGIN_M) & (low | flank)]] = True
        body[near[across & (rise > _SIDE_MARGIN_M) & (rise <= height + _SIDE_MARGIN_M)]] = True
        footprint = np.all(np.abs(local[:, flat]) <= half[flat], axis=1)
        held = across & (rise > UNDERBODY_M) & (rise <= height + _SIDE_MARGIN_M)
        if held.sum() >= _OUTLINE_RETURNS:
            footprint &= _inside_outline(local[:, flat], local[held][:, flat])
        under[near[footprint & (rise <= _SIDE_MARGIN_M) & (rise > -_SIDE_MARGIN_M - 0.3)]] = True
    return out, body, under


def _inside_outline(points: np.ndarray, outline: np.ndarray) -> np.ndarray:
    """[N] bool: which ``points`` [N, 2] lie in the convex hull of ``outline`` [M, 2] (all, when the
    hull is degenerate: the returns on one line or one spot outline nothing)."""
    try:
        hull = ConvexHull(outline)
    except QhullError:
        return np.ones(len(points), bool)
    return np.all(points @ hull.equations[:, :2].T + hull.equations[:, 2] <= 1e-9, axis=1)


def kerb_faces(xy: np.ndarray, above: np.ndarray, up_component: np.ndarray, solid: np.ndarray) -> np.ndarray:
    """[N] bool: the returns that face sideways (``up_component`` [N] of their normals within
    ``_GROUND_UP`` of 0) within ``_GROUND_WITHIN_M`` of the ground (``above`` [N], m over the local
    ground height) with no ``solid`` [N] bool return (not foliage: a street tree's lowest branches
    hang over the kerb) of a taller structure (from ``_GROUND_WITHIN_M`` to ``_KERB_TALL_M`` over
    the ground) within ``_KERB_REACH_M`` of them along the ground (``xy`` [N, 2], m): the face of a
    kerb, not the foot of a wall, a pole or a wheel."""
    xy, above, up_component = np.asarray(xy, np.float64), np.asarray(above), np.asarray(up_component)
    low = (above < _GROUND_WITHIN_M) & (np.abs(up_component) <= _GROUND_UP)
    tall = (above >= _GROUND_WITHIN_M) & (above < _KERB_TALL_M) & np.asarray(solid, bool)
    if not low.any() or not tall.any():
        return low
    distance, _ = cKDTree(xy[tall]).query(xy[low], k=1, distance_upper_bound=_KERB_REACH_M,
                                          workers=_workers(int(low.sum())))
    out = np.zeros(len(xy), bool)
    out[np.flatnonzero(low)[~np.isfinite(distance)]] = True
    return out


def _level(normals: np.ndarray, where: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``normals`` [N, 3] with the upward component of those at ``where`` [N] removed, renormalised
    (one pointing straight up has no horizontal part to keep and is left as it is)."""
    out = np.asarray(normals, np.float64).copy()
    n = out[where]
    rise = np.maximum(n @ up, 0.0)
    n = n - np.outer(rise, up)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    out[where] = np.where(norm > 1e-6, n / np.maximum(norm, 1e-9), out[where])
    return out


def _distinct_poses(poses: np.ndarray, sizes: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (pose [4, 4], size [3]) of a track's boxes [M, 4, 4], [M, 3], each kept once unless it
    moved by 5 cm or more (a parked car's box is annotated at every frame, in the same place)."""
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for T, size in zip(np.asarray(poses, np.float64), np.asarray(sizes, np.float64)):
        if out and np.abs(T[:3, :] - out[-1][0][:3, :]).max() < 0.05 and np.abs(size - out[-1][1]).max() < 0.05:
            continue
        out.append((T, size))
    return out


def _plane_axes(up: np.ndarray) -> np.ndarray:
    """[2, 3] two unit axes spanning the plane perpendicular to ``up``."""
    a = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(up, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(up, e1)])


def lane_paths(scene: Any, *, up: np.ndarray, step_m: float = 0.1) -> np.ndarray:
    """[M, 3] points along every wheel path of the traffic (world, m), on the plane of each path.

    The ego vehicle's path is the cameras' (its wheels half a track to each side, at the ground
    below the camera: the height is not used, distances are taken in the ground plane); each
    moving vehicle track's is its box centres' path (people and cyclists leave no wheel path).
    Each path is extended straight by ``_LANE_EXTENSION_M`` at both ends along its end headings.
    """
    paths = [np.stack([f.camera.center for f in scene.frames])]
    for track in scene.tracks:
        if track.class_name not in _WHEELED:
            continue  # people and cyclists walk and ride where cars do not (a sidewalk keeps its snow)
        centers = np.asarray(track.object_to_world, np.float64)[:, :3, 3]
        if len(centers) > 1 and np.linalg.norm(centers[-1] - centers[0]) > 2.0:
            paths.append(centers)
    out = []
    for path in paths:
        path = np.asarray(path, np.float64)
        flat = path - np.outer(path @ up, up)
        seg = np.diff(flat, axis=0)
        keep = np.linalg.norm(seg, axis=1) > 1e-3
        if not np.any(keep):
            continue
        h0 = seg[keep][0] / np.linalg.norm(seg[keep][0])
        h1 = seg[keep][-1] / np.linalg.norm(seg[keep][-1])
        ext = np.arange(step_m, _LANE_EXTENSION_M, step_m)[:, None]
        line = np.concatenate([flat[0] - ext[::-1] * h0, flat, flat[-1] + ext * h1])
        # resample the observed part densely too
        dense = [line[:len(ext)]]
        for a, b in itertools.pairwise(flat):
            n = max(1, int(np.ceil(np.linalg.norm(b - a) / step_m)))
            dense.append(a + (b - a) * (np.arange(n)[:, None] / n))
        dense.append(line[len(ext) + len(flat):])
        center = np.concatenate(dense)
        tangent = np.gradient(center, axis=0)
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-9)
        side = np.cross(up, tangent)
        out += [center + _HALF_TRACK_M * side, center - _HALF_TRACK_M * side]
    return np.concatenate(out) if out else np.zeros((0, 3))


def _workers(n: int) -> int:
    """The k-d tree's ``workers`` for a query of ``n`` points: every core for a large one, one for a
    small one (:data:`_THREADED_QUERY`)."""
    return -1 if n >= _THREADED_QUERY else 1


def in_box(local: np.ndarray, half: np.ndarray) -> np.ndarray:
    """[N] bool: whether each point of ``local`` [N, 3] (a box's frame) lies within ``half`` [3] of its
    centre on every axis (three column tests: ``np.all(..., axis=1)`` over three columns costs several
    times more)."""
    a = np.abs(local)
    return (a[:, 0] <= half[0]) & (a[:, 1] <= half[1]) & (a[:, 2] <= half[2])


@dataclass(frozen=True)
class MirroredStatic:
    """The static non-ground Gaussians as the ground's mirror image needs them
    (:meth:`SurfaceScene.mirrored_static`).

    Attributes
    ----------
    rows : ndarray [M] int
        Their indices among the static Gaussians, in the order of ``heights``.
    means : ndarray [M, 3] float64
        World centres mirrored about the plane through the origin normal to ``up`` (m): the mirror
        image about the plane at height g is these plus ``2 g up``.
    heights : ndarray [M] float64
        Their heights ``means @ up`` before mirroring (m), ascending: the Gaussians above a plane are a
        suffix of the arrays (a slice, not a gather).
    quats : ndarray [M, 4] float32
        Orientations of the surfels with their normals mirrored about the plane normal to ``up``.
    scales, opacities, colors : ndarray
        Their rows of the static cloud's arrays.
    """

    rows: np.ndarray
    means: np.ndarray
    heights: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    colors: np.ndarray


@dataclass
class SurfaceScene:
    """A scene's lidar Gaussians with surface attributes (see the module docstring).

    Attributes
    ----------
    gaussians : SceneGaussians
        Static Gaussians and rigid nodes (clear-weather colours from the frames).
    static_attributes : ndarray [N, 7] float32
        :data:`ATTRIBUTES` of the static Gaussians (world normals).
    node_attributes : list of ndarray [M_i, 7] float32
        Those of each node, normals in the node's box frame.
    up : ndarray [3]
        Unit up vector.
    plane_axes : ndarray [2, 3]
        Axes of the ground plane coordinates of the noise fields.
    ground_cells : (cKDTree, ndarray)
        Ground height per 2 m cell of the plane: a tree over the cell centres and their heights.
    lanes : cKDTree or None
        Over the wheel-path points (plane coordinates).
    noise_seed : int
    facts : dict
        Counts (Gaussians, ground, open, in wheel paths) for ``info.json``.
    ground_plane : ndarray [3]
        (a, b, c): the ground's height a + b x + c y over the plane coordinates, least squares over
        the cells (where no cell is near, the ground continues this plane).
    analysis : SceneAnalysis, optional
        Where the frames' own dynamic returns come from.
    boxes : list of (ndarray [K] int, ndarray [K, 4, 4], ndarray [K, 3])
        Every track's annotated frames, object-to-world poses and box sizes [l, w, h] (parked and
        moving alike): the solid shell of an object the lidar samples sparsely (:meth:`boxes_at`).
    moving : ndarray [len(boxes)] bool
        The boxes of the tracks whose object moves (a node's); default none.
    facades : Facades, optional
        Vertical planes fitted to the static returns above a car's height
        (:func:`~wcbench.reference_model.scene_graph.completion.fit_facades`): what a wall above
        the lidar's reach continues.
    view_turned : ndarray [N] bool, optional
        The static surfels whose normal each view turns toward itself
        (:func:`~.maps.facing_view`): surfaces off the ground, not foliage. Default none.
    open_ground : OpenGround, optional
        The ground's openness to the fall as a smooth field over the ground plane
        (:meth:`open_field`); default open everywhere.
    """

    gaussians: SceneGaussians
    static_attributes: np.ndarray
    node_attributes: list[np.ndarray]
    up: np.ndarray
    plane_axes: np.ndarray
    ground_cells: tuple[cKDTree, np.ndarray]
    lanes: cKDTree | None
    noise_seed: int
    facts: dict[str, Any]
    ground_plane: np.ndarray = field(default_factory=lambda: np.zeros(3))
    analysis: SceneAnalysis | None = None
    boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)
    facades: Facades | None = None
    view_turned: np.ndarray | None = None
    moving: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    open_ground: OpenGround | None = None

    def boxes_at(self, index: int, *, moving_only: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
        """The (object-to-world [4, 4], size [3]) of every box annotated at frame ``index`` (with
        ``moving_only``, of the moving objects' only: :attr:`moving`)."""
        out = []
        for b, (frames, poses, sizes) in enumerate(self.boxes):
            hit = np.nonzero(frames == index)[0]
            if hit.size and (not moving_only or (b < len(self.moving) and self.moving[b])):
                out.append((poses[int(hit[0])], sizes[int(hit[0])]))
        return out

    def ground_height(self, points: np.ndarray) -> np.ndarray:
        """[N] height (along ``up``) of the ground below ``points`` [N, 3] (m): the nearest 2 m cell's
        within 4 m, else the fitted plane's."""
        tree, heights = self.ground_cells
        xy = np.asarray(points, np.float64) @ self.plane_axes.T
        d, i = tree.query(xy, workers=_workers(len(xy)))
        plane = self.ground_plane[0] + xy @ self.ground_plane[1:]
        return np.where(np.asarray(d) <= _CELL_REACH_M, np.asarray(heights[i]), plane)

    def puddle_field(self, points: np.ndarray) -> np.ndarray:
        """[N] the puddle noise in [0, 1] at ``points`` [N, 3] (world)."""
        xy = np.asarray(points, np.float64) @ self.plane_axes.T
        coarse = value_noise(xy, cell_m=4.0, seed=self.noise_seed)
        fine = value_noise(xy, cell_m=1.5, seed=self.noise_seed + 1)
        return 0.7 * coarse + 0.3 * fine

    def track_field(self, points: np.ndarray) -> np.ndarray:
        """[N] closeness to the nearest wheel path in [0, 1] (1 on it) at ``points`` [N, 3]."""
        if self.lanes is None:
            return np.zeros(len(points))
        d, _ = self.lanes.query(np.asarray(points, np.float64) @ self.plane_axes.T, workers=_workers(len(points)))
        return np.exp(-0.5 * (np.asarray(d) / _WHEEL_PATH_SIGMA_M) ** 2)

    def open_field(self, points: np.ndarray) -> np.ndarray:
        """[N] how open to the falling snow and rain the ground is at ``points`` [N, 3] (world), in
        [0, 1] (:class:`~.open_ground.OpenGround`; 1 everywhere without one): what the ground the
        lidar missed reads, as the ground Gaussians do."""
        if self.open_ground is None:
            return np.ones(len(np.asarray(points).reshape(-1, 3)))
        return self.open_ground.at(np.asarray(points, np.float64).reshape(-1, 3) @ self.plane_axes.T)

    def at_frame(self, index: int) -> tuple[GaussianCloud, np.ndarray]:
        """The Gaussians of frame ``index`` (world) and their attributes [N, 7] (world normals); the
        last frame's are kept (a view's maps and its reflection both ask)."""
        memo = getattr(self, "_frame_memo", None)
        if memo is not None and memo[0] == index:
            return memo[1], memo[2]
        parts, attrs = [self.gaussians.static], [self.static_attributes]
        for node, a in zip(self.gaussians.nodes, self.node_attributes):
            cloud = node.at_frame(index)
            if cloud is None:
                continue
            hit = int(np.nonzero(np.asarray(node.frames) == index)[0][0])
            R = np.asarray(node.object_to_world[hit], np.float64)[:3, :3]
            posed = a.copy()
            posed[:, :3] = a[:, :3] @ R.T.astype(np.float32)
            parts.append(cloud)
            attrs.append(posed)
        dyn = self._frame_dynamic(index)
        if dyn is not None:
            parts.append(dyn[0])
            attrs.append(dyn[1])
        cloud = parts[0] if len(parts) == 1 else GaussianCloud.concatenate(parts)
        # cast part by part (the frame's dynamic returns' rows come as float64): the same values as
        # one float64 copy of every row cast back, at an eighth of the time (pandaset_002: 9.4 -> 1.1 ms)
        out = np.concatenate(attrs, dtype=np.float32, casting="same_kind")
        self._frame_memo = (index, cloud, out)
        return cloud, out

    def mirrored_static(self) -> MirroredStatic:
        """The static Gaussians that are not ground, gathered once, sorted by height, with their
        centres and their surfels' normals mirrored about the plane through the origin normal to
        ``up``: the mirror's height only shifts the centres, so a frame slices the rows above its
        plane and shifts them instead of gathering them from the whole cloud again."""
        memo = getattr(self, "_mirror_memo", None)
        if memo is None:
            up = np.asarray(self.up, np.float64)
            keep = np.flatnonzero(self.static_attributes[:, 3] < 0.5)
            heights = np.asarray(self.gaussians.static.means)[keep].astype(np.float64) @ up
            order = np.argsort(heights, kind="stable")
            keep, heights = keep[order], heights[order]
            normals = np.asarray(self.static_attributes, np.float32)[keep, :3].astype(np.float64)
            st = self.gaussians.static
            means = np.asarray(st.means)[keep].astype(np.float64)
            memo = MirroredStatic(
                rows=keep, means=means - 2.0 * np.outer(heights, up), heights=heights,
                quats=quat_from_axis_to(normals - 2.0 * np.outer(normals @ up, up)).astype(np.float32),
                scales=np.asarray(st.scales)[keep], opacities=np.asarray(st.opacities)[keep],
                colors=np.asarray(st.colors)[keep])
            self._mirror_memo = memo
        return memo

    def near(self, index: int, centers: np.ndarray, radii: np.ndarray) -> list[np.ndarray]:
        """For each of ``centers`` [B, 3], the indices into :meth:`at_frame`'s Gaussians of frame
        ``index`` within its ``radii`` [B] (m).

        The static ones come from a k-d tree made once, each ball's kept (most boxes are parked
        cars', asked for again at every frame with the same centre); the frame's moving ones from
        their centres sorted along x once per frame, each ball testing only the slab of them
        within its radius along x.
        """
        tree = getattr(self, "_static_tree", None)
        if tree is None:
            tree = cKDTree(np.asarray(self.gaussians.static.means, np.float64))
            self._static_tree = tree
            self._ball_memo: dict[bytes, np.ndarray] = {}
        centers = np.asarray(centers, np.float64).reshape(-1, 3)
        radii = np.asarray(radii, np.float64).reshape(-1)
        memo = self._ball_memo
        keys = [c.tobytes() + r.tobytes() for c, r in zip(centers, radii)]
        todo = [i for i, key in enumerate(keys) if key not in memo]
        if todo:
            for i, hits in zip(todo, tree.query_ball_point(centers[todo], radii[todo], workers=_workers(len(todo)))):
                memo[keys[i]] = np.sort(np.asarray(hits, np.int64))
            while len(memo) > _BALL_MEMO:  # the oldest first (dicts keep insertion order)
                memo.pop(next(iter(memo)))
        n = len(self.gaussians.static)
        moving = getattr(self, "_moving_by_x", None)
        if moving is None or moving[0] != index:
            cloud, _ = self.at_frame(index)
            pts = np.asarray(cloud.means[n:], np.float64)
            order = np.argsort(pts[:, 0])  # any order of ties: each ball sorts what it keeps
            moving = (index, pts[order], order)
            self._moving_by_x = moving
        _, by_x, order = moving
        out = []
        for c, r, key in zip(centers, radii, keys):
            lo = int(np.searchsorted(by_x[:, 0], c[0] - r, side="left"))
            hi = int(np.searchsorted(by_x[:, 0], c[0] + r, side="right"))
            slab = by_x[lo:hi] - c
            close = np.sort(order[lo:hi][np.einsum("ij,ij->i", slab, slab) <= r * r])
            out.append(np.concatenate([memo[key], n + close]))
        return out

    def inside_boxes(self, index: int, poses: np.ndarray, halves: np.ndarray) -> list[np.ndarray]:
        """For each box, the centres of :meth:`at_frame`'s Gaussians of frame ``index`` inside it.

        A box is an object-to-world pose ``poses[b]`` [4, 4] and half-sizes ``halves[b]`` [3] (m); a
        point is inside when it lies within the half-size of the centre on each of the box's axes.
        The candidates are :meth:`near`'s ball around the box. A box asked for again with the same
        pose and size (a parked car's, at every frame) keeps its static points: only the frame's
        moving Gaussians are tested again. Static foliage is left out (:meth:`_foliage`): a crown
        reaching into a parked car's box is not the car.

        Parameters
        ----------
        index : int
        poses : ndarray [B, 4, 4] float64
        halves : ndarray [B, 3] float64

        Returns
        -------
        list of ndarray [P_b, 3] float64
            World centres (m): the static Gaussians first, then the frame's moving ones, each in the
            order of :meth:`at_frame`.
        """
        poses = np.asarray(poses, np.float64).reshape(-1, 4, 4)
        halves = np.asarray(halves, np.float64).reshape(-1, 3)
        neighbours = self.near(index, poses[:, :3, 3], np.linalg.norm(halves, axis=1))
        cloud, _ = self.at_frame(index)
        n = len(self.gaussians.static)
        memo = getattr(self, "_inside_memo", None)
        if memo is None:
            memo = {}
            self._inside_memo: dict[bytes, np.ndarray] = memo
        out = []
        for T, half, near in zip(poses, halves, neighbours):
            R, t = T[:3, :3], T[:3, 3]
            split = int(np.searchsorted(near, n))
            key = T.tobytes() + half.tobytes()
            static = memo.get(key)
            if static is None:
                pts = np.take(cloud.means, near[:split], axis=0).astype(np.float64)
                inside = np.flatnonzero(in_box((pts - t) @ R, half))
                static = pts[inside[~self._foliage(near[:split][inside])]]
                memo[key] = static
                while len(memo) > _BALL_MEMO:  # the oldest first (dicts keep insertion order)
                    memo.pop(next(iter(memo)))
            pts = np.take(cloud.means, near[split:], axis=0).astype(np.float64)
            out.append(np.concatenate([static, np.compress(in_box((pts - t) @ R, half), pts, axis=0)]))
        return out

    def _foliage(self, static: np.ndarray) -> np.ndarray:
        """[K] bool: whether the static Gaussians of indices ``static`` [K] are foliage by the analysis'
        semantics (:meth:`~wcbench.reference_model.scene_analysis.motion.LidarReturns.foliage_at`),
        each asked once (a moving box's are met again at every frame's pose); none without one."""
        if self.analysis is None:
            return np.zeros(len(static), bool)
        known = getattr(self, "_foliage_known", None)
        if known is None:
            known = self._foliage_known = np.full(len(self.gaussians.static), -1, np.int8)
        todo = static[known[static] < 0]
        known[todo] = self.analysis.returns.foliage_at(np.asarray(self.gaussians.static.means)[todo])
        return known[static] == 1

    def _frame_dynamic(self, index: int) -> tuple[GaussianCloud, np.ndarray] | None:
        """The untracked dynamic returns of frame ``index`` as Gaussians (colours from the frame at
        the analysis size) and their attributes: PCA normals turned toward the camera, nothing else
        (not ground, not open: nothing settles on a passer-by); ``None`` without any."""
        a = self.analysis
        if a is None:
            return None
        pts = a.returns.frame_dynamic(index, tracked=False)
        if len(pts) < 3:
            return None
        # a mover stands on the ground and is sampled by several beams: what lies on the road's own
        # surface or alone would be drawn as a blob on the road, not wetted, mirrored or snowed on
        above = pts @ self.up - self.ground_height(pts) > _DYNAMIC_ABOVE_GROUND_M
        counts = np.asarray(cKDTree(pts).query_ball_point(pts, _DYNAMIC_NEIGHBOUR_M, return_length=True)) - 1
        d2 = np.maximum(np.sum((pts - a.views.center(index)) ** 2, axis=1), 1.0)
        needed = np.clip(_DYNAMIC_SHARE * _DYNAMIC_PATCH_RETURNS_M2 / d2, *_DYNAMIC_NEIGHBOURS)
        pts = pts[above & (counts >= needed)]
        if len(pts) < 3:
            return None
        views = a.views
        _, _, inside = views.project(pts, index)
        pts = pts[inside]
        if len(pts) < 3:
            return None
        w2c = views.world_to_camera(index)
        cam = pts @ w2c[:3, :3].T + w2c[:3, 3]
        uv = np.stack([views.K[index][0, 0] * cam[:, 0] / cam[:, 2] + views.K[index][0, 2],
                       views.K[index][1, 1] * cam[:, 1] / cam[:, 2] + views.K[index][1, 2]], -1)
        colors = sample_image(views.images[index], uv)
        means, rgb, _ = voxel_downsample(pts, colors, _DYNAMIC_VOXEL_M)
        n = len(means)
        normals = pca_normals(means.astype(np.float64))
        to_cam = views.center(index) - means
        normals[np.einsum("ij,ij->i", to_cam, normals) < 0] *= -1.0
        cloud = GaussianCloud.isotropic(means, 0.6 * _DYNAMIC_VOXEL_M, rgb, 0.9)
        attrs = np.zeros((n, len(ATTRIBUTES)), np.float32)
        attrs[:, :3] = normals
        return cloud, attrs


def _road_under(local: np.ndarray, box_size: np.ndarray) -> np.ndarray:
    """[N] bool: which of a node's Gaussians (box-frame centres [N, 3], z up) are the road it stands on:
    within :data:`UNDERBODY_M` of its box's bottom and facing up (their normals from those points alone
    among the node's, unoriented)."""
    local = np.asarray(local, np.float64)
    bottom = -float(np.median(np.asarray(box_size, np.float64).reshape(-1, 3)[:, 2])) / 2.0
    low = local[:, 2] < bottom + UNDERBODY_M
    road = np.zeros(len(local), bool)
    if np.count_nonzero(low) >= 3:
        road[low] = np.abs(pca_normals(local[low])[:, 2]) > _FACING_UP
    return road


def build_surfaces(scene: Any, *, voxel_m: float = 0.2, noise_seed: int = 0,
                   analysis: SceneAnalysis | None = None) -> SurfaceScene:
    """The scene's lidar Gaussians and their surface attributes (see the module docstring).

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
        Must have lidar.
    voxel_m : float
        Voxel of the lidar Gaussians (m).
    noise_seed : int
        Seed of the puddle field (the weather's particle seed does not move the puddles).
    analysis : SceneAnalysis, optional
        The scene's analysis: its dynamic and noise returns are left out of the static surfaces
        (the tracked movers' stay, for their nodes) and each frame draws its own dynamic returns.
        Without it every return is used.

    Returns
    -------
    SurfaceScene

    Raises
    ------
    InputError
        If no lidar point projects into any frame.
    """
    keep = None
    if analysis is not None:
        r = analysis.returns
        keep = {k: r.static_mask(k) | (r.tracked[k] & ~r.noise[k]) for k in r.points}
    # wider and more opaque than training's start: the surfaces carry attributes, not looks, and a car
    # the lidar samples sparsely must not let the road behind it show through
    options = LidarInitOptions(voxel_m=voxel_m, scale_factor=1.0, opacity=0.98)
    gaussians = init_scene_from_lidar(scene, options, keep=keep)
    up = np.asarray(scene.up, np.float64)
    up = up / np.linalg.norm(up)
    axes = _plane_axes(up)
    means = gaussians.static.means.astype(np.float64)
    spread, frames = principal_frames(means)
    normals = frames[:, :, 0]
    variation = spread[:, 0] / np.maximum(spread.sum(axis=1), 1e-12)
    cams = np.stack([np.asarray(f.camera.center, np.float64) for f in scene.frames])
    _, near_cam = cKDTree(cams).query(means, workers=-1)
    flip = np.einsum("ij,ij->i", cams[near_cam] - means, normals) < 0
    normals[flip] *= -1.0
    height = means @ up
    xy = means @ axes.T

    # ground height per 2 m cell, kept where the cells join the ground under the camera path (a
    # parked car's roof or a ghost below the road is a step off it: ground_cells.py)
    flat = normals @ up > 0.9
    cam_xy = cams @ axes.T
    keys, heights = cell_heights(xy[flat], height[flat], cell_m=CELL_M)
    kept = connected_ground(keys, heights, cam_xy, cell_m=CELL_M)
    dropped = int((~kept).sum())
    keys, heights = keys[kept], heights[kept]
    if not len(keys):  # no flat return at all: the ground lies below the cameras at a car's height
        keys, first = np.unique(np.floor(cam_xy / CELL_M).astype(np.int64), axis=0, return_index=True)
        heights = (cams @ up)[first] - 1.6
    centers = (keys + 0.5) * CELL_M
    ground_tree = cKDTree(centers)
    # the ground beyond the cells continues their least-squares plane (a street is not level)
    design = np.concatenate([np.ones((len(centers), 1)), centers], axis=1)
    plane = (np.linalg.lstsq(design, heights, rcond=None)[0] if len(centers) >= 3
             else np.array([float(np.mean(heights)), 0.0, 0.0]))

    moving = {node.track_id for node in gaussians.nodes}
    lanes_pts = lane_paths(scene, up=up)
    lanes = cKDTree(lanes_pts @ axes.T) if len(lanes_pts) else None
    surf = SurfaceScene(gaussians=gaussians, static_attributes=np.zeros((0, len(ATTRIBUTES)), np.float32),
                        node_attributes=[], up=up, plane_axes=axes, ground_cells=(ground_tree, heights), lanes=lanes,
                        noise_seed=int(noise_seed), facts={}, ground_plane=plane, analysis=analysis,
                        boxes=[(np.asarray(t.frames, np.int64), np.asarray(t.object_to_world, np.float64),
                                np.asarray(t.box_size, np.float64)) for t in scene.tracks],
                        moving=np.array([str(t.id) in moving for t in scene.tracks], bool))
    above = height - surf.ground_height(means)
    ground = (normals @ up > _GROUND_UP) & (above < _GROUND_WITHIN_M)

    # a parked object's returns are static (a moving one's are its node's, below); its body shelters
    # the ground under it, its box's footprint, not the ground beside it: the downward normals of
    # its sills and bumpers within 0.5 m sideways left dark holes in the snow along the parked
    # cars of the PandaSet side cameras
    parked = [(T, size) for t in scene.tracks if str(t.id) not in moving
              for T, size in _distinct_poses(t.object_to_world, t.box_size)]
    side, body, under = _box_parts(means, parked, up=up)
    # foliage by its shape (returns spread in every direction) or, where the scene ships lidar
    # semantics, by its label: a crown's underside is smooth enough to pass for a roof, and sheltered
    # the pavement under a street tree from all the snow (dark patches, docs/findings.md)
    porous = (variation > _FOLIAGE_VARIATION) | surf._foliage(np.arange(len(means)))
    ground |= kerb_faces(xy, above, normals @ up, ~porous)
    open_sky = open_to_sky(means, normals, up=up, shelters=~body, porous=porous)
    open_ = open_sky * ~under
    # real lidar is noisy at a voxel's scale: normals and openness are averaged over the 8 nearest
    # Gaussians (about half a metre), so that what is drawn from them is not speckled; a neighbour
    # counts by how much its normal agrees (cos^4), so a car's roof and side, or a kerb's top and
    # face, do not blend into a slope that takes snow
    _, near = cKDTree(means).query(means, k=min(8, len(means)), workers=-1)
    near = np.asarray(near).reshape(len(means), -1)
    agree = np.clip(np.einsum("nkj,nj->nk", normals[near], normals), 0.0, 1.0) ** 4
    smooth = np.einsum("nk,nkj->nj", agree, normals[near])
    normals = smooth / np.maximum(np.linalg.norm(smooth, axis=1, keepdims=True), 1e-9)
    # a parked object's side faces no sky, whatever its few returns beside the road give its PCA
    # normal (tilted up, they took snow in stripes along a car's doors)
    normals = _level(normals, side, up)
    ground &= ~side

    # surfels: each static Gaussian flattened onto its surface (local z along the normal), so that a
    # surface seen edge-on covers the thin band it fills in the image (a car's roof seen from just
    # above its height does not spread its normal and openness over the side below it and the air
    # above it; Pfister et al. 2000, "Surfels"; Huang et al. 2024, "2D Gaussian splatting")
    st = gaussians.static
    scales = np.asarray(st.scales, np.float32).copy()
    scales[:, 2] = _SURFEL_THICKNESS * scales[:, 0]
    quats, scales[:, 1] = line_surfels(normals, spread, frames[:, :, 2], scales[:, 0], means)
    gaussians.static = GaussianCloud(means=st.means, quats=quats, scales=scales, opacities=st.opacities,
                                     colors=st.colors)

    static = np.zeros((len(means), len(ATTRIBUTES)), np.float32)
    static[:, :3] = normals
    static[:, 3] = ground
    # a surface's seen side faces the view, which may not be the nearest camera's side (the top of a
    # crown); the ground's noisy normals would turn face down where a ray grazes them, and foliage
    # has no side: nor has a return among foliage that happens to lie on a local plane (a bush's
    # outer leaves; turned, the PandaSet bushes' tops took snow in grey tufts, docs/findings.md)
    _, near16 = cKDTree(means).query(means, k=min(_TURN_NEIGHBOURS, len(means)), workers=-1)
    foliage_near = (variation > _FOLIAGE_VARIATION)[np.asarray(near16).reshape(len(means), -1)].mean(axis=1)
    surf.view_turned = ~ground & (foliage_near < _TURN_MAX_FOLIAGE)
    static[:, 4] = open_[near].mean(axis=1)
    # the ground reads the field its Gaussians spread over the plane (soft shelters, no stripes
    # along the rings under a crown), the lidar's gaps too (maps.surface_maps); a parked box's
    # footprint stays dry to its edge
    surf.open_ground = OpenGround.from_ground(xy[ground], open_sky[ground])
    static[ground, 4] = surf.open_field(means[ground]) * ~under[ground]
    static[:, 5] = surf.puddle_field(means)
    static[:, 6] = np.where(ground, surf.track_field(means), 0.0)
    node_attrs = []
    tracks = {str(t.id): t for t in scene.tracks}
    for node in gaussians.nodes:
        track = tracks.get(node.track_id)
        if track is not None and len(node.cloud):
            node.cloud = node.cloud.subset(~_road_under(node.cloud.means, track.box_size))
        local = node.cloud.means.astype(np.float64)
        n_local = pca_normals(local)
        if len(local):  # a node with no lidar return inside its box has no Gaussian to orient
            out = np.einsum("ij,ij->i", local - local.mean(axis=0), n_local) < 0
            n_local[out] *= -1.0
        if track is not None and len(local):  # its side faces no sky (as a parked one's, above)
            box_up = np.array([0.0, 0.0, 1.0])  # the box frame's z
            box = (np.eye(4), np.median(np.asarray(track.box_size, np.float64), axis=0))
            n_local = _level(n_local, object_sides(local, [box], up=box_up), box_up)
        a = np.zeros((len(local), len(ATTRIBUTES)), np.float32)
        a[:, :3] = n_local
        a[:, 4] = 1.0  # a moving object is open to the sky (its roof takes snow)
        node_attrs.append(a)
    surf.static_attributes, surf.node_attributes = static, node_attrs
    surf.facades = fit_facades(means, normals, height - surf.ground_height(means), up)
    surf.facts = {"voxel_m": float(voxel_m), "gaussians": len(gaussians), "static": len(means),
                  "nodes": len(gaussians.nodes), "ground_fraction": round(float(ground.mean()), 4),
                  "open_fraction": round(float(open_.mean()), 4), "wheel_path_points": len(lanes_pts),
                  "ground_slope": round(float(np.hypot(plane[1], plane[2])), 4), "ground_cells": len(heights),
                  "ground_cells_off_the_ground": dropped, "facades": len(surf.facades)}
    return surf
