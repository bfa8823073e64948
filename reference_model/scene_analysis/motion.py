"""Which lidar returns belong to the static scene: moving things without boxes, people and noise out.

A street's sweeps hold returns of things that are not there in the other frames: cars moving with
no track box, pedestrians, a scooter, exhaust. Accumulated over the sequence they become walls,
trails and blotches in every frame. :func:`classify_returns` labels every return of every sweep
(docs/design.md §7, "Beyond the lidar"):

* **tracked movers**: inside the box of a track that moves, at its own frame, grown by 0.2 m (the
  scene graph's rigid nodes hold them); *trailing* returns, outside it but within how far the box
  moves in a frame along each of its axes, are dynamic too (a sweep takes a frame's time, and its
  box stands at one instant of it: a car's bumper pulling away), and in no node;
* **people and transients by semantics**, where the scene ships per-point classes: pedestrians,
  cyclists and animals (even standing, they are not surfaces to weather), smoke, exhaust, spray
  and the ghost returns labelled as reflections;
* **free-space evidence** (the idea of Kim & Kim 2020, "Remove, then revert", IROS, on the frames'
  own camera views): a return of sweep j at camera depth z is *seen through* in another frame k
  when frame k's lidar has a return farther than z + max(0.5 m, 5 % of z) along the same camera
  ray (the nearest return within a 3 x 3 neighbourhood at half the analysis size), and
  *confirmed* when it has one within that margin (every other frame at least two frames away
  votes, once per 0.1 m voxel of the sweep). A return seen through in at least two frames and
  more often than it is confirmed was not there: it is dynamic; so is a return seen through once
  that at most one sweep four frames away or more has a return near (in its 0.6 m voxel): a car
  ahead moving with the camera is seen through only in the frames after it has moved on, a
  pedestrian stays in a voxel for a few frames, a wall for all. Each label is then put to the vote
  of the return's neighbours within 0.3 m (up to 12, at least 3) in its own sweep, so an object is
  dynamic as a whole (a parked car's silhouette edges, seen past by a moving camera, are not; a
  pedestrian's returns are not outvoted by the pavement's);
* **noise**: returns of the static scene whose 0.3 m voxel holds fewer than 3 returns over all
  sweeps (birds, spray droplets, multipath).

The static scene is everything else; a frame's own dynamic returns are still what that frame
shows (:meth:`LidarReturns.frame_points`), except the *ghosts*: the transients by semantics that
are no surface at all (smoke, exhaust, spray, and the returns labelled as reflections, which a
lidar places behind a mirror-like surface, often in open sky). No frame shows a surface there: on
``pandaset_002`` they were 28 of the 75 pixels where the trained model showed sky at a return its
frame trusted (docs/findings.md, "Ghost returns"). Returns of a foliage class are marked too
(:meth:`LidarReturns.foliage_at`): a street tree's crown reaching into a parked car's box is not
the car whose silhouette the box draws.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from scipy.spatial import cKDTree

from wcbench.core.classes import canonical_class
from wcbench.reference_model.scene_analysis.views import AnalysisViews, pixel_indices
from wcbench.reference_model.scene_graph.lidar_init import moving_tracks
from wcbench.reference_model.transforms import apply_linear

__all__ = ["LidarReturns", "classify_returns", "foliage_classes", "transient_classes"]

#: Shared classes (:mod:`wcbench.core.classes`) whose returns are never static surfaces.
_MOVER_CLASSES = frozenset({"pedestrian", "cyclist", "animal"})
#: Lidar semantic class names (lower case) of returns that are not surfaces at all.
_TRANSIENT_NAMES = frozenset({"smoke", "exhaust", "spray or rain", "reflection"})
#: Lidar semantic class names (lower case) of foliage: a crown reaching into a parked car's box is
#: not the car (:meth:`LidarReturns.foliage_at`).
_FOLIAGE_NAMES = frozenset({"vegetation", "tree", "trees", "foliage"})
#: :meth:`LidarReturns.foliage_at`: the static returns (at most, within a radius in m) put to the vote.
_FOLIAGE_K, _FOLIAGE_RADIUS_M = 8, 0.2
#: Free-space margin: max(_MARGIN_M, _MARGIN_REL * depth) (m).
_MARGIN_M, _MARGIN_REL = 0.5, 0.05
#: Frames closer than this to a return's own frame give no free-space vote (they see the same);
#: of the others, every ``_FRAME_STRIDE``-th votes (frames 0.2 s apart see nearly the same).
_MIN_FRAME_GAP, _FRAME_STRIDE = 2, 2
#: Returns are tested once per voxel of this size (m) of their sweep.
_TEST_VOXEL_M = 0.1
#: A return with returns of at most this many sweeps at least _ALONE_GAP frames away in its voxel
#: (m) is alone: one sighting through it makes it dynamic (a car ahead moving with the camera is
#: seen through only late; a pedestrian stays in a voxel for a few frames, a wall for all).
_SUPPORT_VOXEL_M, _ALONE_SWEEPS, _ALONE_GAP = 0.6, 1, 4
#: Neighbours (at most, within a radius in m) whose labels a return's label is put to the vote of.
_VOTE_K, _VOTE_RADIUS_M = 12, 0.3
#: Noise: returns whose voxel (m) holds fewer than this many returns over the sequence.
_NOISE_VOXEL_M, _NOISE_MIN_COUNT = 0.3, 3


def transient_classes(class_names: dict[int, str], *, people: bool = True) -> np.ndarray:
    """[256] bool lookup over semantic class ids: people, cyclists, animals (unless ``people`` is
    false) and transients (smoke, exhaust, spray, reflections), by the scene's class names
    (``Scene.class_names``)."""
    out = np.zeros(256, bool)
    for cid, name in class_names.items():
        low = str(name).strip().lower()
        mover = canonical_class(low) in _MOVER_CLASSES or low.startswith("animals")
        if 0 <= int(cid) < 256 and (low in _TRANSIENT_NAMES or (people and mover)):
            out[int(cid)] = True
    return out


def foliage_classes(class_names: dict[int, str]) -> np.ndarray:
    """[256] bool lookup over semantic class ids: foliage (vegetation, trees), by the scene's class
    names (``Scene.class_names``)."""
    out = np.zeros(256, bool)
    for cid, name in class_names.items():
        if 0 <= int(cid) < 256 and str(name).strip().lower() in _FOLIAGE_NAMES:
            out[int(cid)] = True
    return out


@dataclass
class LidarReturns:
    """Every sweep's returns and what each is (see the module docstring).

    Attributes
    ----------
    points : dict of int to ndarray [N, 3] float64
        World points (m) of each frame that has a sweep.
    dynamic : dict of int to ndarray [N] bool
        Not part of the static scene (tracked movers, people and transients, free-space evidence).
    tracked : dict of int to ndarray [N] bool
        The dynamic returns inside a moving track's box (the scene graph's rigid nodes hold them).
    noise : dict of int to ndarray [N] bool
        Isolated static returns.
    facts : dict
        Counts per reason, for ``info.json``.
    ghost : dict of int to ndarray [N] bool
        Dynamic returns that are no surface (smoke, exhaust, spray, reflections' ghosts), left out
        of what their frame shows; a sweep missing here has none.
    foliage : dict of int to ndarray [N] bool
        Returns of a foliage class (the scene's semantics); a sweep missing here has none.
    """

    points: dict[int, np.ndarray]
    dynamic: dict[int, np.ndarray]
    tracked: dict[int, np.ndarray]
    noise: dict[int, np.ndarray]
    facts: dict[str, Any] = field(default_factory=dict)
    ghost: dict[int, np.ndarray] = field(default_factory=dict)
    foliage: dict[int, np.ndarray] = field(default_factory=dict)

    def static_mask(self, k: int) -> np.ndarray:
        """[N] bool: the returns of frame ``k``'s sweep that belong to the static scene."""
        return ~self.dynamic[k] & ~self.noise[k]

    def static_points(self) -> np.ndarray:
        """[M, 3] the static returns of every sweep, in frame order."""
        parts = [p[self.static_mask(k)] for k, p in sorted(self.points.items())]
        return np.concatenate(parts) if parts else np.zeros((0, 3))

    def nearest_sweep(self, k: int, *, max_gap: int = 2) -> int | None:
        """The frame with a sweep nearest to ``k`` (``k`` itself when it has one) within ``max_gap``
        frames, or ``None``."""
        best = min(self.points, key=lambda j: (abs(j - k), j), default=None)
        return best if best is not None and abs(best - k) <= max_gap else None

    def frame_dynamic(self, k: int, *, tracked: bool = True) -> np.ndarray:
        """[M, 3] the dynamic returns of frame ``k`` (of the nearest sweep within two frames when
        ``k`` has none: things move little in 0.2 s), without noise nor ghosts and, unless
        ``tracked``, without the tracked movers' returns; empty without a sweep."""
        j = self.nearest_sweep(k)
        if j is None:
            return np.zeros((0, 3))
        keep = self.dynamic[j] & ~self.noise[j]
        if j in self.ghost:
            keep &= ~self.ghost[j]
        if not tracked:
            keep &= ~self.tracked[j]
        return self.points[j][keep]

    def own_tracked(self, k: int) -> np.ndarray:
        """[M, 3] the returns of frame ``k``'s own sweep inside a moving track's box, without noise
        nor ghosts: where a tracked mover was when the frame was taken (a node's Gaussians gather
        every sweep's in its box's frame, spread by the boxes' jitter); empty without a sweep (a
        neighbour's would put a mover where it was a frame apart)."""
        if k not in self.points:
            return np.zeros((0, 3))
        keep = self.tracked[k] & self.dynamic[k] & ~self.noise[k]
        if k in self.ghost:
            keep &= ~self.ghost[k]
        return self.points[k][keep]

    def foliage_at(self, points: np.ndarray) -> np.ndarray:
        """[N] bool: whether most of the static returns (of every sweep) within 0.2 m of each of
        ``points`` [N, 3] (world, m), its 8 nearest at most, are foliage; ``False`` where none is
        near, and everywhere for a scene without foliage in its semantics."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        if not any(f.any() for f in self.foliage.values()) or not len(points):
            return np.zeros(len(points), bool)
        memo = getattr(self, "_foliage_tree", None)
        if memo is None:
            order = sorted(self.points)
            keep = [self.static_mask(k) for k in order]
            flags = np.concatenate([self.foliage.get(k, np.zeros(len(self.points[k]), bool))[m]
                                    for k, m in zip(order, keep)])
            memo = (cKDTree(np.concatenate([self.points[k][m] for k, m in zip(order, keep)])), flags)
            self._foliage_tree = memo
        tree, flags = memo
        dist, nb = tree.query(points, k=_FOLIAGE_K, distance_upper_bound=_FOLIAGE_RADIUS_M)
        found = np.isfinite(np.asarray(dist).reshape(len(points), -1))
        votes = np.where(found, flags[np.minimum(np.asarray(nb).reshape(len(points), -1), len(flags) - 1)], False)
        return votes.sum(axis=1) * 2 > found.sum(axis=1)

    def frame_points(self, k: int) -> np.ndarray:
        """[M, 3] what frame ``k`` shows: the static scene and its own dynamic returns."""
        return np.concatenate([self.static_points(), self.frame_dynamic(k)])


def _travel(track: Any, i: int) -> np.ndarray:
    """[3] m: how far the box of ``track`` moves along each of its own axes between its annotation
    ``i`` and the neighbouring ones (the larger per axis, per frame apart)."""
    T = np.asarray(track.object_to_world, np.float64)
    frames = np.asarray(track.frames)
    out = np.zeros(3)
    for j in (i - 1, i + 1):
        if 0 <= j < len(frames) and frames[j] != frames[i]:
            step = np.abs(T[i, :3, :3].T @ (T[j, :3, 3] - T[i, :3, 3])) / abs(int(frames[j]) - int(frames[i]))
            out = np.maximum(out, step)
    return out


def _tracked(points: np.ndarray, frame: int, tracks: list[Any], margin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """([N] bool, [N] bool): ``points`` inside the box of any of ``tracks`` at ``frame`` grown by
    ``margin_m``, and those outside it but inside the box grown further, along each of its axes,
    by how far it moves in a frame (*trailing*): a spinning lidar's sweep takes a frame's time, and
    the box annotated for it stands at one instant of it (the rear bumper of a car pulling away on
    pandaset_002 lies 0.21 m behind its box at frame 5, where the box moves 0.2-0.6 m a frame).
    Candidates are those within each box's bounding sphere, from a k-d tree of the sweep."""
    inside = np.zeros(len(points), bool)
    grown = np.zeros(len(points), bool)
    tree = None
    for track in tracks:
        hit = np.nonzero(np.asarray(track.frames) == frame)[0]
        if hit.size == 0:
            continue
        T = np.asarray(track.object_to_world[int(hit[0])], np.float64)
        half = np.asarray(track.box_size[int(hit[0])], np.float64) / 2 + margin_m
        reach = half + _travel(track, int(hit[0]))
        tree = tree or cKDTree(points)
        idx = np.asarray(tree.query_ball_point(T[:3, 3], float(np.linalg.norm(reach))), np.int64)
        if idx.size == 0:
            continue
        local = np.abs(apply_linear(points[idx] - T[:3, 3], T[:3, :3]))
        inside[idx[np.all(local <= half, axis=1)]] = True
        grown[idx[np.all(local <= reach, axis=1)]] = True
    return inside, grown & ~inside


def _nearest_depth(views: AnalysisViews, points: np.ndarray, k: int, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(the nearest-return camera depth per pixel of frame ``k`` at ``scale`` x the analysis size,
    eroded over 3 x 3 (inf without a return), the scaled intrinsics)."""
    w, h = max(1, round(views.width * scale)), max(1, round(views.height * scale))
    K = np.diag([w / views.width, h / views.height, 1.0]) @ views.K[k]
    u, v, z, ok = pixel_indices(points, views.world_to_camera(k), K, (w, h))
    depth = np.full((h, w), np.float32(1e9), np.float32)
    np.minimum.at(depth, (v[ok], u[ok]), z[ok].astype(np.float32))
    depth = cv2.erode(depth, np.ones((3, 3), np.uint8))
    return depth, K


def _sweep_support(points: dict[int, np.ndarray]) -> Any:
    """A function (frame j, points [N, 3]) -> [N] int: how many sweeps at least ``_ALONE_GAP`` frames
    from j have a return in the same ``_SUPPORT_VOXEL_M`` voxel as each point (a bit mask of the
    sweeps per voxel, frames modulo 63)."""
    keys, bits = [], []
    for k, p in points.items():
        key = _voxel_keys(p)
        keys.append(np.unique(key))
        bits.append(np.full(len(keys[-1]), np.int64(1) << np.int64(k % 63)))
    if not keys:
        return lambda j, p: np.zeros(len(p), np.int64)
    key = np.concatenate(keys)
    order = np.argsort(key, kind="stable")
    key, bit = key[order], np.concatenate(bits)[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    table_keys, table_bits = key[starts], np.bitwise_or.reduceat(bit, starts)

    def support(j: int, p: np.ndarray) -> np.ndarray:
        q = _voxel_keys(p)
        i = np.clip(np.searchsorted(table_keys, q), 0, len(table_keys) - 1)
        near_j = np.int64(0)
        for k in range(j - _ALONE_GAP + 1, j + _ALONE_GAP):  # the sweeps close in time do not count
            near_j |= np.int64(1) << np.int64(k % 63)
        found = np.where(table_keys[i] == q, table_bits[i], 0) & ~near_j
        # population count of 63-bit masks
        count = np.zeros(len(q), np.int64)
        for _ in range(63):
            count += found & 1
            found = found >> 1
            if not found.any():
                break
        return count

    return support


def _voxel_keys(p: np.ndarray) -> np.ndarray:
    """[N] int64 keys of the ``_SUPPORT_VOXEL_M`` voxels of world points (re-based scenes stay within
    +-2^20 voxels on every axis)."""
    ijk = np.floor(np.asarray(p, np.float64) / _SUPPORT_VOXEL_M).astype(np.int64) + (1 << 20)
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


def classify_returns(scene: Any, views: AnalysisViews, *, moving_threshold_m: float = 0.5,
                     box_margin_m: float = 0.2) -> LidarReturns:
    """Label every lidar return of ``scene`` (see the module docstring).

    Parameters
    ----------
    scene : wcbench.scenes.scene.Scene
        Or any object with its attributes (frames, ``lidar(k)``, tracks, ``class_names``).
    views : AnalysisViews
        The scene's frames (their cameras carry the free-space test).
    moving_threshold_m : float
        A track whose box centre moves more than this is a mover (m), as in the lidar
        initialisation.
    box_margin_m : float
        Growth of the track boxes (m).

    Returns
    -------
    LidarReturns
    """
    points: dict[int, np.ndarray] = {}
    labels: dict[int, np.ndarray | None] = {}
    for k, f in enumerate(scene.frames):
        sweep = scene.lidar(f)
        if sweep is not None and len(sweep.points):
            points[k] = np.asarray(sweep.points, np.float64)
            labels[k] = None if sweep.labels is None else np.asarray(sweep.labels)
    tracks = moving_tracks(scene, moving_threshold_m)
    class_names = dict(getattr(scene, "class_names", {}) or {})
    lookup, no_surface = transient_classes(class_names), transient_classes(class_names, people=False)
    leafy = foliage_classes(class_names)
    tracked, trailing, semantic, ghost, foliage = {}, {}, {}, {}, {}
    for k, p in points.items():
        tracked[k], trailing[k] = _tracked(p, k, tracks, box_margin_m)
        lab = labels[k]
        ids = np.clip(lab.astype(np.int64), 0, 255) if lab is not None else None
        semantic[k] = lookup[ids] if ids is not None and lookup.any() else np.zeros(len(p), bool)
        ghost[k] = no_surface[ids] if ids is not None and no_surface.any() else np.zeros(len(p), bool)
        if ids is not None and leafy.any():
            foliage[k] = leafy[ids]

    # free space: the nearest return per pixel of every frame, at half the analysis size
    depth = {k: _nearest_depth(views, p, k, 0.5) for k, p in points.items()}
    support = _sweep_support(points)
    seen_through = {}
    for j, p_all in points.items():
        # only what is not labelled yet, one test per 0.1 m voxel of the sweep (labels broadcast back)
        todo = np.nonzero(~tracked[j] & ~trailing[j] & ~semantic[j])[0]
        key = np.floor(p_all[todo] / _TEST_VOXEL_M).astype(np.int64)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        p = p_all[todo[first]]
        through = np.zeros(len(p), np.int32)
        confirmed = np.zeros(len(p), np.int32)
        for k, (dmap, K) in depth.items():
            if abs(k - j) < _MIN_FRAME_GAP or (k - j) % _FRAME_STRIDE:
                continue
            h, w = dmap.shape
            u, v, z, ok = pixel_indices(p, views.world_to_camera(k), K, (w, h))
            d = np.full(len(p), np.float32(1e9), np.float32)
            d[ok] = dmap[v[ok], u[ok]]
            seen = ok & (d < 1e8)
            margin = np.maximum(_MARGIN_M, _MARGIN_REL * z)
            through += seen & (d > z + margin)
            confirmed += seen & (np.abs(d - z) <= margin)
        # a return no other sweep has a return near (a thing that moved on) needs one sighting through
        alone = support(j, p) <= _ALONE_SWEEPS
        flag = np.zeros(len(p_all), bool)
        flag[todo] = (((through >= 2) & (through > confirmed)) | (alone & (through >= 1)))[inverse.ravel()]
        seen_through[j] = flag

    dynamic, counts = {}, {"tracked": 0, "trailing": 0, "semantic": 0, "free_space": 0, "returns": 0}
    for k, p in points.items():
        raw = seen_through[k] & ~tracked[k] & ~semantic[k]
        if len(p) > _VOTE_K and raw.any():
            # the vote of the neighbours within reach (a pedestrian's own returns, not the pavement's)
            dist, nb = cKDTree(p).query(p, k=_VOTE_K, distance_upper_bound=_VOTE_RADIUS_M, workers=-1)
            found = np.isfinite(dist)
            votes = np.where(found, raw[np.minimum(nb, len(p) - 1)], False).sum(axis=1)
            n = found.sum(axis=1)
            raw = np.where(n >= 3, votes > 0.5 * n, raw)
        dynamic[k] = tracked[k] | trailing[k] | semantic[k] | raw
        counts["tracked"] += int(tracked[k].sum())
        counts["trailing"] += int((trailing[k] & ~semantic[k]).sum())
        counts["semantic"] += int((semantic[k] & ~tracked[k]).sum())
        counts["free_space"] += int((raw & ~tracked[k] & ~trailing[k] & ~semantic[k]).sum())
        counts["returns"] += len(p)

    # noise: sparse voxels of the static scene over the whole sequence
    noise = {k: np.zeros(len(p), bool) for k, p in points.items()}
    if points:
        order = sorted(points)
        stat = np.concatenate([points[k][~dynamic[k]] for k in order])
        if len(stat):
            ijk = np.floor(stat / _NOISE_VOXEL_M).astype(np.int64)
            ijk -= ijk.min(axis=0)
            dims = ijk.max(axis=0) + 1
            key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
            _, inverse, cnt = np.unique(key, return_inverse=True, return_counts=True)
            sparse = cnt[inverse] < _NOISE_MIN_COUNT
            start = 0
            for k in order:
                n = int((~dynamic[k]).sum())
                noise[k][~dynamic[k]] = sparse[start:start + n]
                start += n
    counts["noise"] = int(sum(v.sum() for v in noise.values()))
    counts["ghost"] = int(sum(v.sum() for v in ghost.values()))
    return LidarReturns(points=points, dynamic=dynamic, tracked=tracked, noise=noise, facts=counts, ghost=ghost,
                        foliage=foliage)
