"""The street's ground as a grid of cells: a height per 2 m cell from the upward-facing returns in
it, kept only where the cells join the ground the cameras drove over.

A cell's height is a low percentile of its flat returns, which is the road's where the road is
seen, but a parked car's roof, an awning or a flat roof where only they are (the road under a car
beside a side camera is hidden from the lidar), and a few returns below the road (multipath
ghosts) where only they are. On PandaSet's side cameras such cells put "the ground" 1.6 m up on a
parked SUV's roof next to the camera: the rain's mirror plane, the ground the editor continues
where the lidar does not reach, and the wheel paths met by those rays all followed it
(docs/findings.md). Two tests, both local to the street's own slope:

* **connected**: cells join their neighbours within ``_JOIN_CELLS`` when their heights differ by
  less than ``_STEP_M`` plus ``_GRADE`` of their distance; the component the camera path runs over
  is the ground (a flat roof or a ghost is a step off it);
* **lowest**: a parked car's cells climb in such steps (1.1, 1.0 and 0.3 m under PandaSet's right
  camera beside one, the road 1.8 m), so each cell's height over the street's least-squares
  plane is compared with its neighbours' within ``_ENVELOPE_CELLS``, and a cell more than
  ``_STEP_M`` plus ``_ENVELOPE_GRADE`` of their distance above one of them stands on the ground, not
  on it: the lower envelope of progressive morphological ground filters (Zhang et al. 2003, "A
  progressive morphological filter for removing nonground measurements from airborne LIDAR
  data"), on cells rather than a raster.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["CELL_M", "cell_heights", "connected_ground"]

#: Side of a ground cell (m).
CELL_M = 2.0
#: A cell's height: this percentile of the heights of its upward-facing returns (the road's, under
#: a few returns of what stands on it).
_CELL_PERCENTILE = 10.0
#: Two cells of one ground differ in height by at most ``_STEP_M`` (a kerb, with the percentile's
#: noise) plus ``_GRADE`` of the distance between them (a 12 % street; a sedan's roof, 1.2-1.5 m over
#: the road, stays a step off it at the widest join, 0.78 m over 4 m).
_STEP_M, _GRADE = 0.3, 0.12
#: Cells join their neighbours up to this many cells away (a missing cell, a car's lidar shadow,
#: does not cut the ground in two).
_JOIN_CELLS = 2
#: The lowest test (see the module docstring): cells within this many cells, and the grade (of
#: their distance) a ground's height may change by over the street's plane (its bends and crown).
_ENVELOPE_CELLS, _ENVELOPE_GRADE = 3, 0.08
#: The ground kept is the component with the most cells within this distance (m, sideways) of a
#: camera: the road the vehicle drove on, and the pavement beside it.
_PATH_NEAR_M = 8.0


def cell_heights(xy: np.ndarray, heights: np.ndarray, *, cell_m: float = CELL_M) -> tuple[np.ndarray, np.ndarray]:
    """Per cell of a square grid, a low percentile of the heights of the points in it.

    Parameters
    ----------
    xy : ndarray [N, 2]
        Upward-facing returns in plane coordinates (m).
    heights : ndarray [N]
        Their heights along up (m).
    cell_m : float
        Cell side (m).

    Returns
    -------
    keys : ndarray [C, 2] int64
        Each occupied cell's grid index (``floor(xy / cell_m)``), sorted.
    cell_height : ndarray [C] float64
        Its height (m): the ``_CELL_PERCENTILE`` percentile of its points'.
    """
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    h = np.asarray(heights, np.float64).reshape(-1)
    if len(xy) != len(h):
        raise ValueError(f"xy [{len(xy)}, 2] and heights [{len(h)}] must have one height per point")
    if len(h) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    keys = np.floor(xy / cell_m).astype(np.int64)
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.lexsort((h, inverse))  # by cell, then by height within it
    starts = np.searchsorted(inverse[order], np.arange(len(unique)))
    counts = np.bincount(inverse, minlength=len(unique))
    out = np.empty(len(unique))
    for c, (s, n) in enumerate(zip(starts, counts)):
        out[c] = np.percentile(h[order[s:s + n]], _CELL_PERCENTILE)
    return unique, out


def connected_ground(keys: np.ndarray, heights: np.ndarray, anchors: np.ndarray, *,
                     cell_m: float = CELL_M) -> np.ndarray:
    """[C] bool: the cells of the ground the cameras drove over: connected to the camera path and
    the lowest around them (see the module docstring).

    Parameters
    ----------
    keys : ndarray [C, 2] int
        Grid indices of the cells (:func:`cell_heights`).
    heights : ndarray [C]
        Their heights along up (m).
    anchors : ndarray [F, 2]
        The cameras' centres in plane coordinates (m).
    cell_m : float
        Cell side (m).

    Returns
    -------
    ndarray [C] bool
        Of the component with the most cells within ``_PATH_NEAR_M`` of an anchor (the largest when
        none is near one; ties to the larger), the cells no neighbour lies a step below.
    """
    keys = np.asarray(keys, np.int64).reshape(-1, 2)
    h = np.asarray(heights, np.float64).reshape(-1)
    n = len(keys)
    if n == 0:
        return np.zeros(0, bool)
    tree = cKDTree(keys.astype(np.float64))
    pairs = tree.query_pairs(_JOIN_CELLS + 1e-9, output_type="ndarray")
    if len(pairs):
        d = cell_m * np.linalg.norm(keys[pairs[:, 0]] - keys[pairs[:, 1]], axis=1)
        pairs = pairs[np.abs(h[pairs[:, 0]] - h[pairs[:, 1]]) <= _STEP_M + _GRADE * d]
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])) if len(pairs) else ([], ([], [])),
                       shape=(n, n))
    _, label = connected_components(graph, directed=False)
    size = np.bincount(label)
    centers = (keys + 0.5) * cell_m
    anchors = np.asarray(anchors, np.float64).reshape(-1, 2)
    near = np.zeros(n, bool)
    if len(anchors):
        dist, _ = cKDTree(anchors).query(centers)
        near = np.asarray(dist) <= _PATH_NEAR_M
    score = np.bincount(label, weights=near.astype(np.float64), minlength=len(size))
    best = int(np.lexsort((size, score))[-1])  # most cells near the path, then the largest
    kept = label == best
    # twice: the plane refitted without what the first pass found standing on the ground
    lowest = kept
    for _ in range(2):
        lowest = kept & ~_above_neighbours(keys, h - _plane_through(centers[lowest], h[lowest])(centers), kept,
                                           cell_m=cell_m)
    return lowest


def _plane_through(centers: np.ndarray, heights: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The least-squares plane ``a + b x + c y`` through the cells (level through their mean when
    fewer than three), as a function of centres [M, 2]."""
    if len(centers) >= 3:
        design = np.concatenate([np.ones((len(centers), 1)), centers], axis=1)
        coef = np.linalg.lstsq(design, heights, rcond=None)[0]
    else:
        coef = np.array([float(np.mean(heights)) if len(heights) else 0.0, 0.0, 0.0])
    return lambda xy: coef[0] + np.asarray(xy, np.float64) @ coef[1:]


def _above_neighbours(keys: np.ndarray, residual: np.ndarray, among: np.ndarray, *, cell_m: float) -> np.ndarray:
    """[C] bool: the cells of ``among`` whose ``residual`` height lies more than ``_STEP_M`` plus
    ``_ENVELOPE_GRADE`` of the distance above another cell of ``among`` within ``_ENVELOPE_CELLS``."""
    idx = np.nonzero(among)[0]
    out = np.zeros(len(keys), bool)
    if len(idx) < 2:
        return out
    pairs = cKDTree(keys[idx].astype(np.float64)).query_pairs(_ENVELOPE_CELLS + 1e-9, output_type="ndarray")
    if not len(pairs):
        return out
    i, j = idx[pairs[:, 0]], idx[pairs[:, 1]]
    tol = _STEP_M + _ENVELOPE_GRADE * cell_m * np.linalg.norm(keys[i] - keys[j], axis=1)
    rise = residual[i] - residual[j]
    out[i[rise > tol]] = True
    out[j[-rise > tol]] = True
    return out
