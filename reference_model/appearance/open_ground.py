"""How open the ground is to the falling snow and rain: a smooth field over the ground plane.

The ground's Gaussians each know whether a return overhangs them (:func:`~.surfaces.open_to_sky`),
but a crown's returns are sampled along the lidar's rings, so the Gaussians under it are sheltered
or not from one ring to the next, and the ground the lidar missed (the band a pole or a trunk
shades from it, the road below its lowest beam) knows nothing. :class:`OpenGround` bins the ground
Gaussians' openness into cells of the ground plane and spreads it by a normalised convolution
(Knutsson & Westin 1993) with a Gaussian of ``spread_m``: a flake falling at about 1 m/s
(Locatelli & Hobbs 1974) drifts by tens of centimetres in the turbulence under a crown 2-4 m up,
so a shelter's edge on the ground is soft. Every ground pixel, seen by the lidar or not, reads the
same field (docs/findings.md: the snow under a street tree had been striped along the rings and the
gaps).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: The field's cell (m) and the spread of a shelter's edge on the ground (m, the Gaussian's sigma).
CELL_M, SPREAD_M = 0.25, 0.5
#: The most cells along a side: a longer drive gets larger cells (memory stays under 20 MB).
_MAX_CELLS = 2048


@dataclass(frozen=True)
class OpenGround:
    """Openness in [0, 1] over the ground plane: 1 open to the sky, 0 under a roof.

    Attributes
    ----------
    origin : ndarray [2]
        Plane coordinates (m) of the corner of cell (0, 0).
    cell_m : float
        Cell side (m).
    field : ndarray [X, Y] float32
        The spread openness at each cell's centre; 1 where no ground Gaussian lies within reach.
    """

    origin: np.ndarray
    cell_m: float
    field: np.ndarray

    @classmethod
    def from_ground(cls, xy: np.ndarray, openness: np.ndarray, *, cell_m: float = CELL_M,
                    spread_m: float = SPREAD_M) -> OpenGround:
        """The field of the ground Gaussians at plane coordinates ``xy`` [N, 2] (m) with their
        ``openness`` [N] in [0, 1].

        Raises
        ------
        ValueError
            If the shapes disagree or ``cell_m`` or ``spread_m`` is not positive.
        """
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        openness = np.asarray(openness, np.float64).reshape(-1)
        if len(openness) != len(xy):
            raise ValueError(f"openness has {len(openness)} values; {len(xy)} were expected, one per point")
        if not (cell_m > 0 and spread_m > 0):
            raise ValueError(f"cell_m and spread_m must be positive, got {cell_m} and {spread_m}")
        if not len(xy):
            return cls(origin=np.zeros(2), cell_m=float(cell_m), field=np.ones((1, 1), np.float32))
        margin = 3.0 * spread_m
        lo = xy.min(axis=0) - margin
        extent = xy.max(axis=0) + margin - lo
        cell = max(float(cell_m), float(extent.max()) / _MAX_CELLS)
        shape = tuple(int(v) for v in np.ceil(extent / cell).astype(np.int64) + 1)
        ij = np.floor((xy - lo) / cell).astype(np.int64)
        flat = np.ravel_multi_index((ij[:, 0], ij[:, 1]), shape)
        size = shape[0] * shape[1]
        sums = np.bincount(flat, weights=openness, minlength=size).reshape(shape).astype(np.float32)
        counts = np.bincount(flat, minlength=size).reshape(shape).astype(np.float32)
        sigma = spread_m / cell
        spread_sums = cv2.GaussianBlur(sums, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
        spread_counts = cv2.GaussianBlur(counts, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
        reached = spread_counts > 1e-4
        field = np.where(reached, spread_sums / np.where(reached, spread_counts, 1.0), 1.0)
        return cls(origin=lo, cell_m=cell, field=np.clip(field, 0.0, 1.0).astype(np.float32))

    def at(self, xy: np.ndarray) -> np.ndarray:
        """[N] float64: the field at plane coordinates ``xy`` [N, 2] (m), bilinear between the
        cells' centres; 1 outside the field."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        u = (xy - self.origin) / self.cell_m - 0.5  # in cells, from the first cell's centre
        i0 = np.floor(u).astype(np.int64)
        t = u - i0
        X, Y = self.field.shape
        out = np.zeros(len(xy))
        for di in (0, 1):
            for dj in (0, 1):
                i, j = i0[:, 0] + di, i0[:, 1] + dj
                w = (t[:, 0] if di else 1.0 - t[:, 0]) * (t[:, 1] if dj else 1.0 - t[:, 1])
                inside = (i >= 0) & (i < X) & (j >= 0) & (j < Y)
                out += w * np.where(inside, self.field[np.clip(i, 0, X - 1), np.clip(j, 0, Y - 1)], 1.0)
        return out
