"""Surfels of the returns that sample a wire or a thin bar: as wide across the line as the returns
spread across it (the surfaces' build, :func:`~.surfaces.build_surfaces`, draws every other static
Gaussian as a disc)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from wcbench.reference_model.transforms import quat_from_matrices
from wcbench.reference_model.weather.particle_geometry import quat_from_axis_to

#: A static Gaussian is a wire's (or a thin bar's) when its neighbourhood's second principal spread
#: is under this share of its first (a street's surfaces: over half); its surfel is then as wide
#: across the line as the returns spread across it, ``_LINE_WIDTH_SIGMAS`` of their standard
#: deviation, and never wider than it was.
_LINE_SHARE, _LINE_WIDTH_SIGMAS = 0.2, 1.0
#: ... and when no return within ``_LINE_CLEAR_M`` of it lies more than ``_LINE_OFF_M`` off that
#: line (m): a wire in the air, not one ring of the lidar across a wall, whose next ring lies beside it.
_LINE_CLEAR_M, _LINE_OFF_M = 0.6, 0.15

def _alone_across(means: np.ndarray, rows: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """[len(rows)] bool: no other point within ``_LINE_CLEAR_M`` of ``means[rows]`` lies more than
    ``_LINE_OFF_M`` off the line through it along ``direction`` (a wire in the air, not one ring of a
    spinning lidar across a wall or the road, whose neighbouring rings lie beside it)."""
    tree = cKDTree(means)
    near = tree.query_ball_point(means[rows], r=_LINE_CLEAR_M, workers=-1)
    out = np.ones(len(rows), bool)
    for i, (p, nb) in enumerate(zip(means[rows], near)):
        off = means[nb] - p
        across = off - np.outer(off @ direction[i], direction[i])
        out[i] = not np.any(np.einsum("ij,ij->i", across, across) > _LINE_OFF_M ** 2)
    return out


def line_surfels(normals: np.ndarray, spread: np.ndarray, direction: np.ndarray,
                 width: np.ndarray, means: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Surfel orientations and widths across a line, for returns that sample a wire or a thin bar.

    A surfel is a disc of ``width`` in its plane. An overhead power line's returns, a few
    centimetres across, were discs as wide as the returns' spacing along it (tens of centimetres):
    dark blobs in the sky and over the facades behind, in every weather, where the wire is a thin
    line in the frame. A Gaussian whose neighbourhood is a line (the second principal spread under
    :data:`_LINE_SHARE` of the first) gets its disc's first axis along the line and its second as
    wide as the returns spread across it (:data:`_LINE_WIDTH_SIGMAS` standard deviations), never
    wider than ``width``: the elongated splat of the anisotropic Gaussians of 3D Gaussian
    splatting (Kerbl et al. 2023) drawn from the returns' own covariance.

    Parameters
    ----------
    normals : ndarray [N, 3]
        Unit surfel normals (its third axis).
    spread : ndarray [N, 3]
        The neighbourhood's principal variances (m^2), ascending
        (:func:`~wcbench.reference_model.scene_analysis.normals.principal_frames`).
    direction : ndarray [N, 3]
        The principal axis of the largest variance (the line's direction where it is one).
    width : ndarray [N]
        The surfel's width (standard deviation in its plane, m).

    Returns
    -------
    quats : ndarray [N, 4] float32
        (w, x, y, z): local z along the normal, local x along the line projected into the
        surfel's plane (where it is no line, the orientation :func:`quat_from_axis_to` gives).
    across : ndarray [N] float32
        Width along local y (m): ``width``, narrowed on a line.
    """
    normals = np.asarray(normals, np.float64)
    width = np.asarray(width, np.float32)
    quats = quat_from_axis_to(normals).astype(np.float32)
    across = width.copy()
    line = spread[:, 1] < _LINE_SHARE ** 2 * spread[:, 2]
    if means is not None and np.any(line):
        line[line] = _alone_across(np.asarray(means, np.float64), np.flatnonzero(line), direction[line])
    if not np.any(line):
        return quats, across
    n = normals[line]
    x = direction[line] - np.einsum("ij,ij->i", direction[line], n)[:, None] * n
    length = np.linalg.norm(x, axis=1)
    # a line along the normal (seen end-on in its own plane) has no direction in the plane to keep
    ok = length > 1e-6
    x = x[ok] / length[ok, None]
    n = n[ok]
    rot = np.stack([x, np.cross(n, x), n], axis=-1)  # columns: the surfel's local axes in the world
    rows = np.flatnonzero(line)[ok]
    quats[rows] = quat_from_matrices(rot).astype(np.float32)
    across[rows] = np.minimum(width[rows], _LINE_WIDTH_SIGMAS * np.sqrt(spread[rows, 1])).astype(np.float32)
    return quats, across
