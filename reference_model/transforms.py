"""Rigid transforms of point and Gaussian arrays: quaternions (w, x, y, z) and 3x3 linear maps (numpy).

Shared by the scene graph (object poses), the particles (drop and flake orientations) and the
renderers; and the pinhole projection of world points (training views, a scene's lidar depth).
Quaternions are Hamilton, scalar first, as the rasterizer takes them.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "apply_linear",
    "lidar_depth",
    "project_points",
    "quat_from_matrices",
    "quat_from_matrix",
    "quat_multiply",
    "quat_to_matrix",
]


def apply_linear(points: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``points @ M`` for [N, 3] points and a [3, 3] matrix, column by column.

    A tall-skinny ``@`` goes through BLAS, whose threads can take tens of milliseconds on a
    loaded machine for what is three multiply-adds per point.
    """
    p = np.asarray(points)
    M = np.asarray(M)
    out = np.empty((*p.shape[:-1], M.shape[1]), np.result_type(p, M))
    for j in range(M.shape[1]):
        out[..., j] = p[..., 0] * M[0, j] + p[..., 1] * M[1, j] + p[..., 2] * M[2, j]
    return out


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (w, x, y, z) quaternions, broadcast over leading axes."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] of (w, x, y, z) quaternions [..., 4] (normalised here)."""
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of a rotation matrix [3, 3] (Shepperd's method, stable for all angles)."""
    R = np.asarray(R, np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    out = np.array(q)
    return out / np.linalg.norm(out)


def quat_from_matrices(R: np.ndarray) -> np.ndarray:
    """[N, 4] unit quaternions (w, x, y, z) of rotations [N, 3, 3] (or one [3, 3] -> [1, 4]).

    Shepperd's method, vectorised: the branch of the largest of the trace and the diagonal terms
    keeps the square root well away from zero (:func:`quat_from_matrix` is the one-matrix form).
    """
    R = np.asarray(R, np.float64).reshape(-1, 3, 3)
    q = np.empty((len(R), 4))
    diag = np.stack([R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2], R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], -1)
    branch = np.argmax(diag, axis=1)
    sel = branch == 0
    if sel.any():
        r = R[sel]
        s = 2.0 * np.sqrt(1.0 + diag[sel, 0])
        q[sel] = np.stack([0.25 * s, (r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                           (r[:, 1, 0] - r[:, 0, 1]) / s], -1)
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # the largest diagonal term is R[a, a]
        sel = branch == a + 1
        if not sel.any():
            continue
        r = R[sel]
        s = 2.0 * np.sqrt(np.maximum(1.0 + r[:, a, a] - r[:, b, b] - r[:, c, c], 1e-300))
        out = np.empty((len(r), 4))
        out[:, 0] = (r[:, c, b] - r[:, b, c]) / s
        out[:, 1 + a] = 0.25 * s
        out[:, 1 + b] = (r[:, a, b] + r[:, b, a]) / s
        out[:, 1 + c] = (r[:, a, c] + r[:, c, a]) / s
        q[sel] = out
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def project_points(points: np.ndarray, world_to_camera: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates and camera z of world points (pinhole, pixel centers at +0.5).

    Parameters
    ----------
    points : ndarray [N, 3]
        World (m).
    world_to_camera : ndarray [4, 4]
        OpenCV camera axes (x right, y down, z forward).
    K : ndarray [3, 3]
        Intrinsics.

    Returns
    -------
    uv : ndarray [N, 2]
        Pixels (x right, y down); not finite where z = 0.
    z : ndarray [N]
        Depth along the optical axis (m); <= 0 behind the camera.
    """
    p = np.asarray(points, np.float64) @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([p[:, 0] / z * K[0, 0] + K[0, 2], p[:, 1] / z * K[1, 1] + K[1, 2]], 1)
    return uv, z


def lidar_depth(points: np.ndarray, world_to_camera: np.ndarray, K: np.ndarray, width: int,
                height: int) -> np.ndarray:
    """[H, W] float32 z-depth (m) of world points, the nearest per pixel; 0 where none lands."""
    uv, z = project_points(points, world_to_camera, K)
    ij = np.floor(uv).astype(np.int64)
    ok = (z > 0) & (ij[:, 0] >= 0) & (ij[:, 0] < width) & (ij[:, 1] >= 0) & (ij[:, 1] < height)
    ij, z = ij[ok], z[ok]
    order = np.argsort(-z)  # far first: the nearest point is written last
    depth = np.zeros((height, width), np.float32)
    depth[ij[order, 1], ij[order, 0]] = z[order]
    return depth
