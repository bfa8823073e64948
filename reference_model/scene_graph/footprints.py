"""Ground laid where a removed object stood: the footprints of the scene's boxes tiled with flat
Gaussians coloured from the road around them (:func:`fill_footprints`, docs/design.md §7,
"Object editing"; :mod:`wcbench.reference_model.editing.vacated` calls it)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.spatial import cKDTree

from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.transforms import quat_from_matrix

__all__ = ["fill_footprints"]


def fill_footprints(means: np.ndarray, colors: np.ndarray, boxes: Sequence[tuple[np.ndarray, np.ndarray]],
                    up: np.ndarray, *, cell_m: float = 0.25, margin_m: float = 0.3, ring_m: float = 1.5,
                    ground_band_m: float = 0.25, seen_m: float = 0.25, thickness_m: float = 0.02, neighbours: int = 8,
                    min_ring: int = 8, min_sides: int = 3, opacity: float = 0.9,
                    colour_at: Callable[[np.ndarray], np.ndarray] | None = None) -> GaussianCloud:
    """Background Gaussians on the ground no lidar return saw under the boxes of the scene's nodes,
    coloured from the road around them: what a removed object leaves behind (docs/design.md §7).

    A node's Gaussians leave the background with its box (a parked car's returns, and the road's
    within the box's margin), and the ground under a car that never moves is seen by no sweep and
    no camera. Each box's footprint (grown by ``margin_m``) is tiled with flat Gaussians on the
    **ground plane fitted** by least squares to the background points within ``ring_m`` around it
    and within ``ground_band_m`` of its bottom face (no fill where fewer than ``min_ring`` are
    found, nothing to colour from, or on fewer than ``min_sides`` of its four sides, a wall's
    foot rather than a road). A tile a background point lies near (sideways within ``seen_m``
    or the ring's median point spacing, whichever is more, and within
    ``ground_band_m`` of the plane: the road seen there, in the frames a mover did not stand on
    it) is left to that point. A tile's colour is
    the inverse-squared-distance mean of its ``neighbours`` nearest ring points (Shepard 1968):
    the road around the footprint as the cameras saw it (``colour_at``), continued inwards, as
    image inpainting continues a hole's border (Bertalmio et al. 2000; Telea 2004) and as
    street-scene graphs complete the ground under removed vehicles (Yan et al. 2024, "Street
    Gaussians"; Chen et al. 2024, "OmniRe"). A tile in a ground cell an earlier box tiled (a
    world grid of ``cell_m``) is not made again (a mover's overlapping boxes).

    Parameters
    ----------
    means : ndarray [N, 3]
        Background Gaussian centres (world, m).
    colors : ndarray [N, 3]
        Their RGB in [0, 1].
    boxes : sequence of (ndarray [4, 4], ndarray [3])
        Each box's object-to-world pose and its size along its own axes (m).
    up : ndarray [3]
        The scene's unit up vector; a box's axis nearest it is its height.
    cell_m : float
        Tile spacing (m); a tile is a flat Gaussian of 0.75 of it as standard deviation sideways and
        ``thickness_m`` across.
    opacity : float
        Of every tile, in (0, 1].
    colour_at : callable, optional
        ``colour_at(points [M, 3]) -> [M, 3]``: RGB of world points as the cameras see them where
        no object stands before them, NaN where no camera does. The ring's colours come from it,
        from the points it colours only (from every ring point's own colour where fewer than
        ``min_ring`` are). A point's colour from its own sweep's frame is the object's where the
        camera sees the object before the road the lidar hit (the two sensors stand apart);
        :func:`~wcbench.reference_model.training.build.build_model` passes
        :func:`~wcbench.reference_model.training.build.seen_colour`.

    Returns
    -------
    GaussianCloud
        World coordinates; empty without boxes or ground around them.

    Raises
    ------
    ValueError
        On arrays whose shapes disagree, or a non-positive ``cell_m``.
    """
    p = np.asarray(means, np.float64)
    c = np.asarray(colors, np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or c.shape != p.shape:
        raise ValueError(f"means [N, 3] and colors [N, 3] were expected, got {p.shape} and {c.shape}")
    if not cell_m > 0:
        raise ValueError(f"cell_m must be > 0 metres, got {cell_m}")
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    tree = cKDTree(p) if len(p) else None
    out_means: list[np.ndarray] = []
    out_colors: list[np.ndarray] = []
    out_quats: list[np.ndarray] = []
    out_scales: list[np.ndarray] = []
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    plane_axes = np.stack([e1, np.cross(u, e1)])
    made: set[tuple[int, int]] = set()  # world ground cells tiled so far
    for pose, size in boxes:
        if tree is None:
            break
        T = np.asarray(pose, np.float64)
        R, t = T[:3, :3], T[:3, 3]
        half = np.asarray(size, np.float64).reshape(3) / 2.0
        v = int(np.argmax(np.abs(R.T @ u)))  # the box's height axis
        s = float(np.sign(R[:, v] @ u))
        a, b = [i for i in range(3) if i != v]
        grown = half[[a, b]] + margin_m
        outer = grown + ring_m
        near = np.asarray(tree.query_ball_point(t, float(np.linalg.norm([*outer, half[v] + 1.0]))), np.int64)
        if near.size == 0:
            continue
        local = (p[near] - t) @ R  # box frame
        height = s * local[:, v] + half[v]  # above the box's bottom face
        fa, fb = local[:, a], local[:, b]
        inside = (np.abs(fa) <= grown[0]) & (np.abs(fb) <= grown[1])
        ring = ~inside & (np.abs(fa) <= outer[0]) & (np.abs(fb) <= outer[1]) & (np.abs(height) <= 2 * ground_band_m)
        if ring.sum() < min_ring:
            continue
        # the ground plane around the footprint: least squares, once more on the points near it (a
        # kerb, a bumper's lowest return)
        design = np.stack([np.ones(int(ring.sum())), fa[ring], fb[ring]], 1)
        coef = np.linalg.lstsq(design, height[ring], rcond=None)[0]
        close = np.abs(design @ coef - height[ring]) <= ground_band_m
        if close.sum() >= min_ring:
            coef = np.linalg.lstsq(design[close], height[ring][close], rcond=None)[0]
        plane = np.stack([np.ones(len(fa)), fa, fb], 1) @ coef
        ground = ring & (np.abs(height - plane) <= ground_band_m)
        along_a, along_b = np.abs(fb) <= grown[1], np.abs(fa) <= grown[0]  # beside a side, not a corner
        sides = [np.any(ground & along_a & (fa < 0)), np.any(ground & along_a & (fa > 0)),
                 np.any(ground & along_b & (fb < 0)), np.any(ground & along_b & (fb > 0))]
        if ground.sum() < min_ring or sum(sides) < min_sides:  # a wall's foot on one side is no road
            continue
        ga = np.arange(-grown[0], grown[0] + 1e-9, cell_m)
        gb = np.arange(-grown[1], grown[1] + 1e-9, cell_m)
        ta, tb = (x.ravel() for x in np.meshgrid(ga - (ga[-1] + ga[0]) / 2, gb - (gb[-1] + gb[0]) / 2))
        th = np.stack([np.ones(len(ta)), ta, tb], 1) @ coef
        # a tile the lidar saw the ground on keeps that return
        seen_pts = np.abs(height - plane) <= ground_band_m
        if np.any(seen_pts):
            # far from the sensor the returns on a road lie in rings a metre apart, and their
            # Gaussians, as wide, cover it between them: seen is within a spacing of the ring's
            ab = np.stack([fa[ground], fb[ground]], 1)
            spacing = float(np.median(cKDTree(ab).query(ab, k=2)[0][:, 1]))
            d, _ = cKDTree(np.stack([fa[seen_pts], fb[seen_pts]], 1)).query(np.stack([ta, tb], 1))
            todo = d > max(seen_m, spacing)
        else:
            todo = np.ones(len(ta), bool)
        tl = np.zeros((len(ta), 3))
        tl[:, a], tl[:, b], tl[:, v] = ta, tb, s * (th - half[v])
        world = tl @ R.T + t
        # one tile per world ground cell: a mover's boxes overlap, each a little shifted
        cells = [tuple(x) for x in np.floor(world @ plane_axes.T / cell_m).astype(np.int64).tolist()]
        first = {}
        for i, key in enumerate(cells):
            if todo[i] and key not in made and key not in first:
                first[key] = i
        todo = np.zeros(len(cells), bool)
        todo[list(first.values())] = True
        made.update(first)
        if not np.any(todo):
            continue
        world, ta, tb = world[todo], ta[todo], tb[todo]
        ring_rgb, ring_ab = c[near[ground]], np.stack([fa[ground], fb[ground]], 1)
        if colour_at is not None:
            seen_rgb = np.asarray(colour_at(p[near[ground]]), np.float64)
            valid = np.all(np.isfinite(seen_rgb), axis=1)
            if valid.sum() >= min_ring:  # only the ring the cameras saw; its sweep's colour without
                ring_rgb, ring_ab = seen_rgb[valid], ring_ab[valid]
        k = min(neighbours, len(ring_ab))
        d, j = cKDTree(ring_ab).query(np.stack([ta, tb], 1), k=k)
        d, j = np.asarray(d).reshape(len(ta), k), np.asarray(j).reshape(len(ta), k)
        wgt = 1.0 / np.maximum(d, 1e-3) ** 2
        rgb = np.einsum("nk,nkc->nc", wgt, ring_rgb[j]) / wgt.sum(1, keepdims=True)
        scale = np.empty((len(world), 3))
        scale[:, [a, b]] = 0.75 * cell_m  # neighbours overlap: no seam shows what lies beneath
        scale[:, v] = thickness_m
        out_means.append(world)
        out_colors.append(rgb)
        out_quats.append(np.tile(_proper_quat(R), (len(world), 1)))
        out_scales.append(scale)
    if not out_means:
        return GaussianCloud(np.zeros((0, 3), np.float32), np.zeros((0, 4), np.float32),
                             np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros((0, 3), np.float32))
    n = sum(len(m) for m in out_means)
    return GaussianCloud(means=np.concatenate(out_means).astype(np.float32),
                         quats=np.concatenate(out_quats).astype(np.float32),
                         scales=np.concatenate(out_scales).astype(np.float32),
                         opacities=np.full(n, opacity, np.float32),
                         colors=np.clip(np.concatenate(out_colors), 0.0, 1.0).astype(np.float32))


def _proper_quat(R: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of ``R``, or of ``R`` with its last axis flipped when it is a reflection (a
    flat Gaussian is symmetric across each of its axes)."""
    M = np.array(R, np.float64)
    if np.linalg.det(M) < 0:
        M[:, 2] *= -1
    return quat_from_matrix(M)
