"""The sky lookup (numba): a bilinear ``grid_sample`` of small maps and its gradient to the maps.

``F.grid_sample`` (bilinear, border padding, ``align_corners=False``) looks every pixel up in the
sky's environment maps, a few thousand texels read by a frame's hundred thousand pixels. PyTorch's
CPU backward scatters into the map one batch item at a time, so with one image it runs on one
thread (7 ms a training step at 480x270 with four weathers, docs/design.md §8). Here each thread
owns whole channels of the map, so the scatter needs no atomics, and the corner weights are
PyTorch's (``grid_sampler_compute_source_index`` and the four bilinear weights), in float32. A
non-finite grid entry sends no gradient (PyTorch's CPU backward crashed on a NaN one here, torch
2.13). The forward, single-threaded in PyTorch for one image too, runs here over image rows with
the same corners and weights; it reads 0 where a grid entry is not finite.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["grid_sample_map", "grid_sample_map_grad"]


@njit(cache=True, inline="always", error_model="numpy")
def _source_index(coord: np.float32, size: int) -> np.float32:
    """Unnormalised, border-clipped source coordinate (PyTorch, align_corners=False)."""
    x = ((coord + np.float32(1.0)) * np.float32(size) - np.float32(1.0)) / np.float32(2.0)
    return min(np.float32(size - 1), max(x, np.float32(0.0)))


@njit(parallel=True, cache=True, error_model="numpy")
def grid_sample_map(maps: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """``grid_sample(maps, grid)`` [C, H, W] float32 (bilinear, border padding, align_corners=False).

    Parameters
    ----------
    maps : ndarray [C, rows, cols] float32
    grid : ndarray [H, W, 2] float32
        x (columns) and y (rows) in [-1, 1].
    """
    c_count, rows, cols = maps.shape
    h, w = grid.shape[0], grid.shape[1]
    out = np.zeros((c_count, h, w), np.float32)
    one = np.float32(1.0)
    for r in prange(h):
        for j in range(w):
            if not (np.isfinite(grid[r, j, 0]) and np.isfinite(grid[r, j, 1])):
                continue
            ix = _source_index(grid[r, j, 0], cols)
            iy = _source_index(grid[r, j, 1], rows)
            x0, y0 = int(np.floor(ix)), int(np.floor(iy))
            a, b = ix - np.float32(x0), iy - np.float32(y0)
            right, down = x0 + 1 < cols, y0 + 1 < rows
            for c in range(c_count):
                v = (one - a) * (one - b) * maps[c, y0, x0]
                if right:
                    v += a * (one - b) * maps[c, y0, x0 + 1]
                if down:
                    v += (one - a) * b * maps[c, y0 + 1, x0]
                    if right:
                        v += a * b * maps[c, y0 + 1, x0 + 1]
                out[c, r, j] = v
    return out


@njit(parallel=True, cache=True, error_model="numpy")
def grid_sample_map_grad(grid: np.ndarray, grad_out: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """dL/dmap [C, rows, cols] float32 of ``grid_sample(map, grid)`` given dL/dout.

    Parameters
    ----------
    grid : ndarray [H, W, 2] float32
        x (columns) and y (rows) in [-1, 1].
    grad_out : ndarray [C, H, W] float32
    rows, cols : int
        The map's size.
    """
    c_count, h, w = grad_out.shape
    n = h * w
    # the corners and weights once per pixel (every channel reads them)
    corner = np.empty(n, np.int64)
    tx = np.empty(n, np.float32)
    ty = np.empty(n, np.float32)
    for r in prange(h):
        for j in range(w):
            p = r * w + j
            if not (np.isfinite(grid[r, j, 0]) and np.isfinite(grid[r, j, 1])):
                corner[p] = -1  # PyTorch reads nothing there, so nothing flows back
                tx[p] = ty[p] = 0.0
                continue
            ix = _source_index(grid[r, j, 0], cols)
            iy = _source_index(grid[r, j, 1], rows)
            x0, y0 = int(np.floor(ix)), int(np.floor(iy))
            corner[p] = y0 * cols + x0
            tx[p] = ix - np.float32(x0)
            ty[p] = iy - np.float32(y0)
    out = np.zeros((c_count, rows * cols), np.float32)
    one = np.float32(1.0)
    for c in prange(c_count):
        flat = grad_out[c].reshape(-1)
        for p in range(n):
            k, a, b, g = corner[p], tx[p], ty[p], flat[p]
            if k < 0:
                continue
            right, down = (k % cols) + 1 < cols, k // cols + 1 < rows
            out[c, k] += (one - a) * (one - b) * g
            if right:
                out[c, k + 1] += a * (one - b) * g
            if down:
                out[c, k + cols] += (one - a) * b * g
                if right:
                    out[c, k + cols + 1] += a * b * g
    return out.reshape(c_count, rows, cols)
