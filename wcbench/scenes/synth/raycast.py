"""Rays against the analytic shapes of a synthetic street: oriented boxes (buildings, trunks, cars,
pedestrians' limbs) and spheres (tree canopies). The lidar casts its sweeps with them, and the sun
its shadows (:mod:`.lidar`, :mod:`.sunlight`; docs/design.md §3)."""

from __future__ import annotations

import numpy as np

__all__ = ["RayBundle", "box_entry", "sphere_entry"]


def box_entry(o: np.ndarray, d: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Distance along rays to where they enter a box (the slab method), in the box's frame.

    Parameters
    ----------
    o : ndarray [..., 3] or [3]
        Ray origins in the box frame (m; the box is centred at 0 with axes x, y, z).
    d : ndarray [..., 3]
        Ray directions in the box frame (unit for metric distances).
    half : ndarray [3]
        Half size of the box (m).

    Returns
    -------
    ndarray [...]
        The entry distance (units of ``d``); inf where the ray misses the box, and where it starts
        inside it or enters it behind its origin.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - o) / d, (half - o) / d
        t_near = np.fmax(np.fmax(np.fmin(t1[..., 0], t2[..., 0]), np.fmin(t1[..., 1], t2[..., 1])),
                         np.fmin(t1[..., 2], t2[..., 2]))
        t_far = np.fmin(np.fmin(np.fmax(t1[..., 0], t2[..., 0]), np.fmax(t1[..., 1], t2[..., 1])),
                        np.fmax(t1[..., 2], t2[..., 2]))
        return np.where((t_far >= t_near) & (t_near > 0), t_near, np.inf)


def sphere_entry(oc: np.ndarray, dirs: np.ndarray, radius: float) -> np.ndarray:
    """Distance along rays to where they enter a sphere.

    Parameters
    ----------
    oc : ndarray [3] or [..., 3]
        The sphere's centre minus the ray origin (m): one origin for every ray, or one per ray.
    dirs : ndarray [..., 3]
        Unit ray directions.
    radius : float
        Sphere radius (m).

    Returns
    -------
    ndarray [...]
        Entry distance (m); inf where the ray misses, starts inside or passes behind its origin.
    """
    if oc.ndim == 1:  # one origin (a lidar sweep): a matrix-vector product
        b, c2 = dirs @ oc, oc @ oc
    else:
        b, c2 = np.einsum("...i,...i->...", dirs, oc), np.einsum("...i,...i->...", oc, oc)
    disc = b * b - (c2 - radius**2)
    t = np.where(disc >= 0, b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
    return np.where(t > 0, t, np.inf)


class RayBundle:
    """Rays that all run close to one direction (a sun's), culled per shape in the plane across it.

    The origins are sorted along one axis of the plane across ``axis``; each shape's outline in that
    plane (widened by the ``margin`` the rays may stray) then selects a slice of them, and only
    those rays are tested exactly. A query costs the rays near each shape, not rays x shapes, and
    the sort is kept: a bundle is queried with the static shapes once and with the moving ones
    every frame.

    Parameters
    ----------
    points : ndarray [N, 3]
        Ray origins (m).
    dirs : ndarray [N, 3]
        Unit directions, each within ``margin`` / (distance to a shape) of ``axis``.
    axis : ndarray [3]
        The common direction (unit).
    margin : float
        How far (m), across ``axis``, a ray may stray from its origin's line along ``axis`` before
        it meets a shape.
    """

    def __init__(self, points: np.ndarray, dirs: np.ndarray, axis: np.ndarray, margin: float) -> None:
        e1 = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        self.basis = np.stack([e1, np.cross(axis, e1), axis], 1)  # columns: across 1, across 2, along
        self.points, self.dirs, self.margin = points, dirs, float(margin)
        self.plane = points @ self.basis
        self.order = np.argsort(self.plane[:, 0], kind="stable")
        self._a = self.plane[self.order, 0]
        self._extent = (self.plane.min(0), self.plane.max(0)) if len(points) else (np.zeros(3), np.zeros(3))

    def __len__(self) -> int:
        return len(self.points)

    def _near(self, lo: np.ndarray, hi: np.ndarray, done: np.ndarray) -> np.ndarray:
        """Indices of the rays not yet ``done`` whose origin lies in the plane box [lo, hi] (3 axes)."""
        sel = self.order[np.searchsorted(self._a, lo[0]):np.searchsorted(self._a, hi[0], side="right")]
        p = self.plane[sel]
        return sel[(p[:, 1] >= lo[1]) & (p[:, 1] <= hi[1]) & (p[:, 2] <= hi[2]) & ~done[sel]]

    def blocked(self, boxes: tuple[np.ndarray, np.ndarray, np.ndarray], spheres: np.ndarray,
                out: np.ndarray | None = None) -> np.ndarray:
        """Which rays meet a box or a sphere ahead of their origin.

        Parameters
        ----------
        boxes : tuple of ndarray
            Centres [M, 3], rotations [M, 3, 3] (box-to-world) and half sizes [M, 3] (m).
        spheres : ndarray [K, 4]
            Centres and radii (m).
        out : ndarray [N] bool, optional
            Rays already known to be blocked (not tested again); updated in place.

        Returns
        -------
        ndarray [N] bool
        """
        out = np.zeros(len(self.points), bool) if out is None else out
        if not len(self.points):
            return out
        # each shape's outline in the plane (and its far end along the axis), all at once; shapes
        # clear of every origin are skipped without a loop
        centers, rotations, halves = boxes
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)
        corners = (np.einsum("kj,mij->mki", signs, rotations * halves[:, None, :]) + centers[:, None]) @ self.basis
        box_lo, box_hi = corners.min(1) - self.margin, corners.max(1) + self.margin
        sphere_c = spheres[:, :3] @ self.basis
        radius = spheres[:, 3:] + self.margin
        lo, hi = np.concatenate([box_lo, sphere_c - radius]), np.concatenate([box_hi, sphere_c + radius])
        p_lo, p_hi = self._extent
        near = np.all(lo[:, :2] <= p_hi[:2], axis=1) & np.all(hi[:, :2] >= p_lo[:2], axis=1) & (hi[:, 2] >= p_lo[2])
        for m in np.nonzero(near)[0]:
            sel = self._near(lo[m], hi[m], out)
            if not len(sel):
                continue
            if m < len(centers):
                c, R = centers[m], rotations[m]
                out[sel] = np.isfinite(box_entry((self.points[sel] - c) @ R, self.dirs[sel] @ R, halves[m]))
            else:
                s = spheres[m - len(centers)]
                out[sel] = np.isfinite(sphere_entry(s[:3] - self.points[sel], self.dirs[sel], float(s[3])))
        return out
