"""Geometry of the particles: the horizontal basis, particle orientations, view checks and the
opacity compensation of the rasterizer's 2D dilation (docs/design.md §7).

Quaternions are (w, x, y, z); lengths are metres.
"""

from __future__ import annotations

import math

import numpy as np

from wcbench.reference_model.transforms import apply_linear, quat_to_matrix

__all__ = [
    "check_view",
    "horizontal_basis",
    "particle_dilation_compensation",
    "quat_about_z",
    "quat_from_axis_to",
    "random_quaternions",
]


def horizontal_basis(up: np.ndarray, heading: np.ndarray | None = None) -> np.ndarray:
    """Right-handed orthonormal basis (e1, e2, up) with e1, e2 horizontal.

    Parameters
    ----------
    up : ndarray [3]
        Up vector of the world (normalised here).
    heading : ndarray [3], optional
        Direction e1 should follow (projected onto the horizontal plane), e.g. the first
        camera's viewing direction; defaults to the world axis least aligned with ``up``.

    Returns
    -------
    ndarray [3, 3] float64
        Rows e1, e2 = up x e1, up.

    Raises
    ------
    ValueError
        If ``up`` is not a finite non-zero 3-vector.
    """
    u = np.asarray(up, np.float64).reshape(-1)
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u / max(np.abs(u).max(), 1e-300)) < 1e-9:
        raise ValueError(f"up must be a finite non-zero 3-vector, got {up!r}")
    u = u / np.abs(u).max()  # first to ~1: the norm of a huge vector would overflow
    u = u / np.linalg.norm(u)
    candidates = [] if heading is None else [np.asarray(heading, np.float64).reshape(3)]
    candidates.append(np.eye(3)[int(np.argmin(np.abs(u)))])
    for h in candidates:
        e1 = h - (h @ u) * u
        if np.all(np.isfinite(e1)) and np.linalg.norm(e1) > 1e-6:
            e1 = e1 / np.linalg.norm(e1)
            return np.stack([e1, np.cross(u, e1), u])
    raise AssertionError("unreachable: the least aligned axis is never parallel to up")


def quat_from_axis_to(v: np.ndarray) -> np.ndarray:
    """Quaternions [N, 4] rotating the local z axis onto the line of each ``v`` [N, 3].

    The Gaussian is symmetric, so z is mapped onto +v or -v, whichever needs the smaller turn;
    this avoids the singular 180-degree case for rain falling along -z.
    """
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    d = np.where(n > 1e-12, v / np.maximum(n, 1e-300), np.array([0.0, 0.0, 1.0]))
    d = d * np.where(d[..., 2:3] < 0, -1.0, 1.0)
    # Half-way quaternion between z and d: (1 + z.d, z x d), with z.d >= 0 so never degenerate.
    q = np.stack([1.0 + d[..., 2], -d[..., 1], d[..., 0], np.zeros_like(d[..., 0])], -1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_about_z(angle: np.ndarray) -> np.ndarray:
    """Quaternions [..., 4] of rotations by ``angle`` (rad) about the local z axis."""
    half = 0.5 * np.asarray(angle, np.float64)
    zero = np.zeros_like(half)
    return np.stack([np.cos(half), zero, zero, np.sin(half)], -1)


def random_quaternions(u: np.ndarray) -> np.ndarray:
    """Uniformly random rotations from u [N, 3] in [0, 1) (Shoemake 1992)."""
    a, b, c = u[:, 0], 2 * np.pi * u[:, 1], 2 * np.pi * u[:, 2]
    r1, r2 = np.sqrt(1 - a), np.sqrt(a)
    return np.stack([r2 * np.cos(c), r1 * np.sin(b), r1 * np.cos(b), r2 * np.sin(c)], -1)


def particle_dilation_compensation(
    means: np.ndarray,
    quats: np.ndarray,
    scales: np.ndarray,
    viewmat: np.ndarray,
    K: np.ndarray,
    *,
    eps2d: float,
) -> np.ndarray:
    """Opacity factor sqrt(det Sigma / det(Sigma + eps I)) per Gaussian (gsplat "antialiased").

    The rasterizer dilates every 2D covariance by ``eps2d`` px^2; a raindrop a tenth of a pixel
    wide would grow several-fold in coverage, and by a resolution-dependent amount. Scaling its
    opacity by this factor keeps its integrated coverage.

    Parameters
    ----------
    means : ndarray [M, 3]
        World (m).
    quats : ndarray [M, 4]
        wxyz.
    scales : ndarray [M, 3]
        Standard deviations (m).
    viewmat : ndarray [4, 4]
        World-to-camera (OpenCV axes).
    K : ndarray [3, 3]
        Intrinsics.
    eps2d : float
        The rasterizer's dilation (px^2).

    Returns
    -------
    ndarray [M] float32
        In (0, 1]; 1 where the projection is degenerate (such Gaussians are culled anyway).
    """
    if len(means) == 0:
        return np.zeros(0, np.float32)
    W = np.asarray(viewmat, np.float64)
    cam = apply_linear(np.asarray(means, np.float64), W[:3, :3].T) + W[:3, 3]
    x, y, z = cam[:, 0], cam[:, 1], np.maximum(cam[:, 2], 1e-6)
    fx, fy = K[0, 0], K[1, 1]
    J = np.zeros((len(cam), 2, 3))
    J[:, 0, 0], J[:, 0, 2] = fx / z, -fx * x / z**2
    J[:, 1, 1], J[:, 1, 2] = fy / z, -fy * y / z**2
    M = quat_to_matrix(quats) * np.asarray(scales, np.float64)[:, None, :]
    T = J @ W[:3, :3] @ M
    c00 = np.einsum("ij,ij->i", T[:, 0], T[:, 0])
    c11 = np.einsum("ij,ij->i", T[:, 1], T[:, 1])
    # det(T T^T) as the sum of the squared 2x2 minors of T (Cauchy-Binet), not c00 c11 - c01^2:
    # for a long thin streak that difference is rounding noise of either sign (docs/design.md §9).
    det = ((T[:, 0, 0] * T[:, 1, 1] - T[:, 0, 1] * T[:, 1, 0]) ** 2
           + (T[:, 0, 0] * T[:, 1, 2] - T[:, 0, 2] * T[:, 1, 0]) ** 2
           + (T[:, 0, 1] * T[:, 1, 2] - T[:, 0, 2] * T[:, 1, 1]) ** 2)
    det_d = det + eps2d * (c00 + c11) + eps2d * eps2d
    factor = np.sqrt(det / np.maximum(det_d, 1e-30))
    return np.where(np.isfinite(factor), np.clip(factor, 0.0, 1.0), 1.0).astype(np.float32)


def check_view(view: tuple[np.ndarray, np.ndarray, int, int], near: float) -> None:
    """A view is a finite world-to-camera matrix, finite intrinsics with positive focal lengths and
    a positive integer size; ``near`` is finite (docs/design.md §9)."""
    W, K, width, height = view
    Wm, Km = np.asarray(W, np.float64), np.asarray(K, np.float64)
    if Wm.shape not in ((4, 4), (3, 4)) or not np.all(np.isfinite(Wm)):
        raise ValueError(f"view: the world-to-camera matrix must be finite [4, 4], got shape {Wm.shape}")
    if Km.shape != (3, 3) or not np.all(np.isfinite(Km)) or not (Km[0, 0] > 0 and Km[1, 1] > 0):
        raise ValueError(f"view: K must be finite [3, 3] intrinsics with positive focal lengths, got {Km.tolist()}")
    if int(width) != width or int(height) != height or width < 1 or height < 1:
        raise ValueError(f"view: width and height must be positive integers, got {width} x {height}")
    if not math.isfinite(near):
        raise ValueError(f"near must be finite metres, got {near}")
