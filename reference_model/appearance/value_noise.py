"""Smooth value noise on the ground plane: the seeded field that places the puddles
(:meth:`.surfaces.SurfaceScene.puddle_field`), anchored in the world so they stay put from frame to
frame."""

from __future__ import annotations

import numpy as np

__all__ = ["value_noise"]


def value_noise(xy: np.ndarray, *, cell_m: float, seed: int) -> np.ndarray:
    """Smooth value noise in [0, 1] at 2D points: hashed lattice values, smoothstep-interpolated.

    Parameters
    ----------
    xy : ndarray [N, 2]
        Plane coordinates (m).
    cell_m : float
        Lattice spacing (m): the size of the features.
    seed : int

    Returns
    -------
    ndarray [N] float64
    """
    p = np.asarray(xy, np.float64) / cell_m
    i0 = np.floor(p).astype(np.int64)
    f = p - i0
    u = f * f * (3.0 - 2.0 * f)

    def lattice(ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
        h = (ix * 73856093) ^ (iy * 19349663) ^ (seed * 83492791)
        h = (h ^ (h >> 13)) * 1274126177
        return ((h ^ (h >> 16)) & 0xFFFFFF).astype(np.float64) / float(0xFFFFFF)

    a, b = lattice(i0[:, 0], i0[:, 1]), lattice(i0[:, 0] + 1, i0[:, 1])
    c, d = lattice(i0[:, 0], i0[:, 1] + 1), lattice(i0[:, 0] + 1, i0[:, 1] + 1)
    return (a + (b - a) * u[:, 0]) * (1 - u[:, 1]) + (c + (d - c) * u[:, 0]) * u[:, 1]
