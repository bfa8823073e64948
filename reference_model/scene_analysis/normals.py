"""Surface normals of a point cloud from its local principal axes (Hoppe et al. 1992, "Surface
reconstruction from unorganized points", SIGGRAPH), unoriented: the caller turns them toward
whatever saw the surface."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["pca_normals", "principal_axes"]


def pca_normals(points: np.ndarray, k: int = 16) -> np.ndarray:
    """Unit normals: the smallest principal axis of the ``k`` nearest points (unoriented).

    Parameters
    ----------
    points : ndarray [N, 3]
    k : int

    Returns
    -------
    ndarray [N, 3] float64
        +z for fewer than 3 points.
    """
    return principal_axes(points, k)[0]


def principal_axes(points: np.ndarray, k: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """(:func:`pca_normals`, the surface variation [N]: the smallest eigenvalue of the ``k``
    nearest points' covariance over their sum, 0 on a plane, 1/3 for points scattered through a
    volume; Pauly, Gross & Kobbelt 2002, "Efficient simplification of point-sampled surfaces")."""
    n = len(points)
    if n < 3:
        out = np.zeros((n, 3))
        out[:, 2] = 1.0
        return out, np.zeros(n)
    _, idx = cKDTree(points).query(points, k=min(k, n), workers=-1)
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    w, v = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    return v[:, :, 0], w[:, 0] / np.maximum(w.sum(axis=1), 1e-12)
