"""Geometry of the synthetic street: rotations and poses, the street centreline, and flat surface
Gaussians with the materials the weathers act on (boxes tiled with Gaussians, box-filtered
stripes; docs/design.md §3)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from wcbench.reference_model.transforms import quat_from_matrices, quat_multiply, quat_to_matrix
from wcbench.scenes.synth.layout import OPACITY, SIGMA_OF_SPACING, THIN_M

__all__ = ["AlbedoFn", "Cloud", "GlassFn", "Part", "Street", "band_fraction", "box_surface", "cell_grid",
           "gaussian_normals", "hash01", "pulse_fraction", "rigid_transform", "rot_y", "rot_z", "solid_albedo"]


def rot_z(angle: np.ndarray | float) -> np.ndarray:
    """[..., 3, 3] rotations about +z by ``angle`` (rad)."""
    a = np.asarray(angle, np.float64)
    c, s = np.cos(a), np.sin(a)
    out = np.zeros((*a.shape, 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1], out[..., 2, 2] = c, -s, s, c, 1.0
    return out


def rot_y(angle: float) -> np.ndarray:
    """[3, 3] rotation about +y by ``angle`` (rad); positive turns +x towards -z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rigid_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[4, 4] rigid transform from a rotation [3, 3] and a translation [3]."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def gaussian_normals(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Normals of flat Gaussians: the rotated axis of each Gaussian's smallest scale.

    Parameters
    ----------
    quats : ndarray [N, 4]
        Rotations (w, x, y, z).
    scales : ndarray [N, 3]
        Standard deviations along the local axes (m).

    Returns
    -------
    ndarray [N, 3] float64
        Unit normals in world axes. The sign is the rotated local axis' own: the surfaces of this
        module put that axis outwards.
    """
    R = quat_to_matrix(quats)
    axis = np.argmin(np.asarray(scales), axis=1)
    return R[np.arange(len(R)), :, axis]


@dataclass(frozen=True)
class Street:
    """A street centreline of constant curvature through the origin along +x, z up.

    A point at arc length ``s`` and lateral offset ``d`` (m, positive to the left) sits at
    c(s) + d n(s), where n is the left normal.
    """

    curvature: float

    def heading(self, s: np.ndarray | float) -> np.ndarray:
        """Heading angle (rad, counter-clockwise from +x) at arc length ``s``."""
        return self.curvature * np.asarray(s, np.float64)

    def point(self, s: Any, d: Any, z: Any = 0.0) -> np.ndarray:
        """[..., 3] world point at arc length ``s``, lateral offset ``d`` and height ``z`` (m)."""
        s, d, z = np.broadcast_arrays(np.asarray(s, np.float64), np.asarray(d, np.float64),
                                      np.asarray(z, np.float64))
        th = self.heading(s)
        if self.curvature == 0.0:
            cx, cy = s, np.zeros_like(s)
        else:
            cx, cy = np.sin(th) / self.curvature, (1.0 - np.cos(th)) / self.curvature
        return np.stack([cx - d * np.sin(th), cy + d * np.cos(th), z], -1)

    def frame(self, s: Any) -> np.ndarray:
        """[..., 3, 3] rotations whose columns are the tangent, the left normal and up at ``s``."""
        return rot_z(self.heading(s))

    def coords(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(s, d) street coordinates of world points (x, y) (m)."""
        if self.curvature == 0.0:
            return np.asarray(x, np.float64), np.asarray(y, np.float64)
        k = self.curvature
        px, py = np.asarray(x, np.float64), np.asarray(y, np.float64) - 1.0 / k  # from the centre of curvature
        d = 1.0 / k - np.sign(k) * np.hypot(px, py)
        scale = d - 1.0 / k
        return np.arctan2(-px / scale, py / scale) / k, d


# --------------------------------------------------------------------------------------------
# Gaussians with materials


@dataclass
class Cloud:
    """Surface Gaussians with the material attributes the weathers act on.

    means [N, 3] (m), quats [N, 4] (w, x, y, z), scales [N, 3] (m), opacities [N], albedo [N, 3]
    (RGB in [0, 1]), snow [N] (how much settling snow a Gaussian facing up takes, 0-1), wet [N]
    (albedo factor of the wet surface), sheen [N] (weight of the wet sky reflection, 0-1), gloss [N]
    (share of window glass, which mirrors the sky where a profile has mirror windows, 0-1).
    """

    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    albedo: np.ndarray
    snow: np.ndarray
    wet: np.ndarray
    sheen: np.ndarray
    gloss: np.ndarray

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @staticmethod
    def make(means: np.ndarray, quats: np.ndarray, scales: np.ndarray, albedo: np.ndarray, *,
             snow: Any = 1.0, wet: Any = 0.85, sheen: Any = 0.0, gloss: Any = 0.0, opacity: Any = OPACITY) -> Cloud:
        n = len(means)

        def col(v: Any) -> np.ndarray:
            return np.broadcast_to(np.asarray(v, np.float64), (n,)).copy()

        return Cloud(np.asarray(means, np.float64), np.broadcast_to(quats, (n, 4)).copy(),
                      np.broadcast_to(scales, (n, 3)).copy(), col(opacity),
                      np.clip(np.broadcast_to(albedo, (n, 3)), 0.0, 1.0).astype(np.float64),
                      col(snow), col(wet), col(sheen), col(gloss))

    @staticmethod
    def concat(clouds: list[Cloud]) -> Cloud:
        return Cloud(**{f.name: np.concatenate([getattr(c, f.name) for c in clouds]) for f in fields(Cloud)})

    def posed(self, T: np.ndarray) -> Cloud:
        """The cloud moved by the rigid transform ``T`` [4, 4]."""
        q = quat_from_matrices(T[:3, :3])[0]
        return Cloud(self.means @ T[:3, :3].T + T[:3, 3], quat_multiply(q, self.quats), self.scales, self.opacities,
                      self.albedo, self.snow, self.wet, self.sheen, self.gloss)


def cell_grid(half_u: float, half_v: float, spacing_u: float, spacing_v: float
          ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Cell centres (u, v) [M] of a grid over [-half_u, half_u] x [-half_v, half_v] and the cell sizes."""
    nu = max(1, math.ceil(2 * half_u / spacing_u - 1e-9))
    nv = max(1, math.ceil(2 * half_v / spacing_v - 1e-9))
    du, dv = 2 * half_u / nu, 2 * half_v / nv
    u, v = np.meshgrid(-half_u + (np.arange(nu) + 0.5) * du, -half_v + (np.arange(nv) + 0.5) * dv, indexing="ij")
    return u.ravel(), v.ravel(), du, dv


#: ``albedo(face, local, cell)``: RGB [M, 3] of the Gaussians of a box face from their box-frame
#: positions ``local`` [M, 3] (m) and the grid cell size along each box axis ``cell`` [3] (m, 0 along
#: the face normal), so that stripes can be box-filtered over a cell.
AlbedoFn = Callable[[str, np.ndarray, np.ndarray], np.ndarray]
#: ``glass(face, local, cell)``: share [M] of window glass of the Gaussians of a box face, from the
#: same arguments as an :data:`AlbedoFn`.
GlassFn = Callable[[str, np.ndarray, np.ndarray], np.ndarray]
#: A solid part of an object for the lidar: box centre [3], rotation [3, 3] and half size [3] (m).
Part = tuple[np.ndarray, np.ndarray, np.ndarray]


def solid_albedo(color: Any) -> AlbedoFn:
    """An albedo function of one colour."""
    rgb = np.asarray(color, np.float64)
    return lambda face, local, cell: np.tile(rgb, (len(local), 1))


def box_surface(center: np.ndarray, R: np.ndarray, half: np.ndarray, faces: tuple[str, ...], spacing: float,
         albedo: AlbedoFn, *, stretch_x: float = 1.0, glass: GlassFn | None = None, **material: Any) -> Cloud:
    """Flat Gaussians tiling faces of a box.

    ``faces`` names outward normals of the box frame (``"+x"``, ``"-z"``...); ``albedo`` colours them
    (:data:`AlbedoFn`) and ``glass``, when given, says how much of each is window glass
    (:data:`GlassFn`, the Cloud's ``gloss``). Along the box's
    x axis the spacing is ``stretch_x`` times larger (a facade seen at a grazing angle along it).
    """
    clouds = []
    for face in faces:
        k, sign = "xyz".index(face[1]), (1.0 if face[0] == "+" else -1.0)
        i, j = (a for a in range(3) if a != k)
        F = np.zeros((3, 3))
        F[i, 0], F[j, 1], F[k, 2] = 1.0, 1.0, sign
        if np.linalg.det(F) < 0:  # keep a right-handed frame: swap the in-plane axes
            F[:, [0, 1]] = F[:, [1, 0]]
            i, j = j, i
        u, v, du, dv = cell_grid(half[i], half[j], spacing * (stretch_x if i == 0 else 1.0),
                             spacing * (stretch_x if j == 0 else 1.0))
        local = u[:, None] * F[:, 0] + v[:, None] * F[:, 1] + half[k] * F[:, 2]
        frame = R @ F
        cell = np.zeros(3)
        cell[i], cell[j] = du, dv
        if glass is not None:
            material["gloss"] = glass(face, local, cell)
        clouds.append(Cloud.make(center + local @ R.T, quat_from_matrices(frame),
                                  np.array([SIGMA_OF_SPACING * du, SIGMA_OF_SPACING * dv, THIN_M]),
                                  albedo(face, local, cell), **material))
    return Cloud.concat(clouds)


def band_fraction(x: np.ndarray, cell: float, lo: float, hi: float) -> np.ndarray:
    """Fraction of each cell [x - cell/2, x + cell/2] inside [lo, hi] (a box-filtered stripe: no aliasing)."""
    return np.clip((np.minimum(x + cell / 2, hi) - np.maximum(x - cell / 2, lo)) / cell, 0.0, 1.0)


def pulse_fraction(x: np.ndarray, cell: float, period: float, start: float, width: float) -> np.ndarray:
    """Fraction of each cell covered by the pulses [start + i period, start + i period + width)."""

    def integral(y: np.ndarray) -> np.ndarray:
        return np.floor(y / period) * width + np.minimum(np.mod(y, period), width)

    y = np.asarray(x, np.float64) - start
    return (integral(y + cell / 2) - integral(y - cell / 2)) / cell


def hash01(*keys: np.ndarray) -> np.ndarray:
    """A deterministic pseudo-random number in [0, 1) per integer key tuple (window colours)."""
    acc = np.zeros(np.broadcast(*keys).shape, np.uint64)
    for k in keys:
        acc = (acc ^ np.asarray(k).astype(np.int64).astype(np.uint64)) * np.uint64(0x9E3779B97F4A7C15)
        acc ^= acc >> np.uint64(31)
    return (acc >> np.uint64(11)).astype(np.float64) / float(1 << 53)
