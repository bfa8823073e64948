"""Surface normals of a point cloud from its local principal axes (Hoppe et al. 1992, "Surface
reconstruction from unorganized points", SIGGRAPH), unoriented: the caller turns them toward
whatever saw the surface."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["pca_normals", "principal_axes", "principal_frames"]


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
    values, axes = principal_frames(points, k)
    return axes[:, :, 0], values[:, 0] / np.maximum(values.sum(axis=1), 1e-12)


def principal_frames(points: np.ndarray, k: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """The local covariance of each point's ``k`` nearest points (itself included), decomposed.

    Parameters
    ----------
    points : ndarray [N, 3]
        Positions (m).
    k : int
        Neighbourhood size (fewer when there are fewer points).

    Returns
    -------
    values : ndarray [N, 3] float64
        The covariance's eigenvalues (m^2), ascending: about (0, 0, s^2) along a wire, (0, a, b) on
        a surface.
    axes : ndarray [N, 3, 3] float64
        Their unit eigenvectors as columns (``axes[:, :, 0]`` the normal of a surface).
        Fewer than 3 points: zero variances and the identity (normal +z).
    """
    n = len(points)
    if n < 3:
        return np.zeros((n, 3)), np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    m = min(k, n)
    _, idx = cKDTree(points).query(points, k=m, workers=-1)
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    w, v = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb) / m)
    return np.maximum(w, 0.0), v
