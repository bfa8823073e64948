"""Numba kernels of :mod:`.box_shells`: one tracked object's shell and its Gaussians' tails, and the
band over its top, pixel by pixel.

:func:`box_shell_kernel` mirrors the numpy reference :func:`wcbench.reference_model.appearance.box_shells.
_box_shell_pixels` (the same float64 arithmetic and NaN rules of the slab method; the reference's
3 x 3 products go through BLAS, which may round them differently, so the tests compare values to
1e-12 and the pixels changed exactly); a frame has dozens of boxes, each a few thousand pixels,
where the reference's dozen numpy passes per box cost more in calls than in arithmetic
(docs/design.md §7). :func:`top_band_kernel` mirrors :func:`wcbench.reference_model.appearance.
box_shells._top_band_pixels` the same way (the maps it leaves compared as the shells'; on
real frames the same bands, docs/findings.md). Compiled on first use and
cached on disk.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["box_shell_kernel"]


@numba.njit(cache=True, inline="always")
def _nan_min(a, b):  # type: ignore[no-untyped-def]  # pragma: no cover
    """``np.minimum``: NaN if either is NaN."""
    if a != a or b != b:
        return a + b
    return a if a <= b else b


@numba.njit(cache=True, inline="always")
def _nan_max(a, b):  # type: ignore[no-untyped-def]  # pragma: no cover
    """``np.maximum``: NaN if either is NaN."""
    if a != a or b != b:
        return a + b
    return a if a >= b else b


@numba.njit(cache=True, inline="always")
def _fmax(a, b):  # type: ignore[no-untyped-def]  # pragma: no cover
    """``np.fmax``: the other where one is NaN."""
    if a != a:
        return b
    if b != b:
        return a
    return a if a >= b else b


@numba.njit(cache=True, inline="always")
def _fmin(a, b):  # type: ignore[no-untyped-def]  # pragma: no cover
    """``np.fmin``: the other where one is NaN."""
    if a != a:
        return b
    if b != b:
        return a
    return a if a <= b else b


@numba.njit(cache=True, inline="always")
def _slab(o, d0, d1, d2, lo, hi):  # type: ignore[no-untyped-def]  # pragma: no cover
    """(entry, exit) of the line ``o + t d`` through the box [lo, hi] (``box_shells._slab_interval``)."""
    t1 = (lo[0] - o[0]) / d0
    t2 = (hi[0] - o[0]) / d0
    n0, f0 = _nan_min(t1, t2), _nan_max(t1, t2)
    t1 = (lo[1] - o[1]) / d1
    t2 = (hi[1] - o[1]) / d1
    n1, f1 = _nan_min(t1, t2), _nan_max(t1, t2)
    t1 = (lo[2] - o[2]) / d2
    t2 = (hi[2] - o[2]) / d2
    n2, f2 = _nan_min(t1, t2), _nan_max(t1, t2)
    return _fmax(_fmax(n0, n1), n2), _fmin(_fmin(f0, f1), f2)


@numba.njit(cache=True, inline="always")
def _hits(o, d0, d1, d2, lo, hi):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Whether the ray ``o + t d``, t > 0, meets the box [lo, hi] (``box_shells._slab_hits``)."""
    t_in, t_out = _slab(o, d0, d1, d2, lo, hi)
    return t_out >= _nan_max(t_in, 0.0) and t_out > 0.0


@numba.njit(cache=True, inline="always")
def _seen_point(rays, distance, y, x, a0, a1, a2, R):  # type: ignore[no-untyped-def]  # pragma: no cover
    """(finite, p0, p1, p2): the surface pixel (``y``, ``x``) sees in the frame of a box (centre
    offset from the camera ``a0, a1, a2``, rotation ``R``); not finite where it sees nothing."""
    seen = distance[y, x]
    if not math.isfinite(seen):
        return False, 0.0, 0.0, 0.0
    b0 = a0 + rays[y, x, 0] * seen
    b1 = a1 + rays[y, x, 1] * seen
    b2 = a2 + rays[y, x, 2] * seen
    return (True, b0 * R[0, 0] + b1 * R[1, 0] + b2 * R[2, 0], b0 * R[0, 1] + b1 * R[1, 1] + b2 * R[2, 1],
            b0 * R[0, 2] + b1 * R[1, 2] + b2 * R[2, 2])


@numba.njit(cache=True, inline="always")
def _on_object(rays, distance, y, x, a0, a1, a2, R, s0, s1, s2, vertical, floor):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Whether the surface pixel (``y``, ``x``) sees lies in the box (centre offset from the camera
    ``a0, a1, a2``, rotation ``R``, half-size ``s0, s1, s2``) above ``floor`` on axis ``vertical``."""
    finite, p0, p1, p2 = _seen_point(rays, distance, y, x, a0, a1, a2, R)
    pv = p0 if vertical == 0 else (p1 if vertical == 1 else p2)
    return finite and abs(p0) <= s0 and abs(p1) <= s1 and abs(p2) <= s2 and pv >= floor


@numba.njit(cache=True, inline="always")
def _entry_face(o, d0, d1, d2, entry, lo, hi):  # type: ignore[no-untyped-def]  # pragma: no cover
    """(axis, sign) of the face of the box [lo, hi] the point ``o + entry d`` lies on: the first
    axis of the largest |offset from its middle| / half-size (``box_shells._entry_face``)."""
    e0 = o[0] + d0 * entry - (lo[0] + hi[0]) / 2.0
    e1 = o[1] + d1 * entry - (lo[1] + hi[1]) / 2.0
    e2 = o[2] + d2 * entry - (lo[2] + hi[2]) / 2.0
    axis, sign, best = 0, np.sign(e0), abs(e0) / ((hi[0] - lo[0]) / 2.0)
    if abs(e1) / ((hi[1] - lo[1]) / 2.0) > best:
        axis, sign, best = 1, np.sign(e1), abs(e1) / ((hi[1] - lo[1]) / 2.0)
    if abs(e2) / ((hi[2] - lo[2]) / 2.0) > best:
        axis, sign = 2, np.sign(e2)
    return axis, sign


@numba.njit(cache=True, inline="always")
def _tail_on_object(rays, distance, y, x, a0, a1, a2, R, s0, s1, s2, half, vertical, floor, beside):  # type: ignore[no-untyped-def]  # pragma: no cover
    """:func:`_on_object` for the tails: below ``floor`` too where the surface lies more than
    ``beside`` (m) outside the box's footprint (``half``) along an axis other than ``vertical``."""
    finite, p0, p1, p2 = _seen_point(rays, distance, y, x, a0, a1, a2, R)
    if not (finite and abs(p0) <= s0 and abs(p1) <= s1 and abs(p2) <= s2):
        return False
    pv = p0 if vertical == 0 else (p1 if vertical == 1 else p2)
    if pv >= floor:
        return True
    return ((vertical != 0 and abs(p0) > half[0] + beside) or (vertical != 1 and abs(p1) > half[1] + beside)
            or (vertical != 2 and abs(p2) > half[2] + beside))


@numba.njit(cache=True, error_model="numpy")
def box_shell_kernel(filled, grown, x0, y0, rays, distance, normal, ground, open_, puddle, track,  # type: ignore[no-untyped-def]  # pragma: no cover
                     allowed, tails, hulls, changed, R, t, o, half, vertical, floor, center, body_lo,
                     body_hi, cabin_lo, cabin_hi, slack, beside):
    """One box of :func:`~wcbench.reference_model.appearance.box_shells.box_shells`, in place.

    ``filled`` / ``grown`` [h, w] uint8: the hull of the object's returns and that hull grown by
    the edge, over the frame region from column ``x0``, row ``y0``. First the tails (pixels of the
    region outside ``grown`` whose surface lies on the object, marked in ``tails``; ``grown`` is
    added to ``hulls``), then the shell of every ``filled`` pixel (``distance`` [H, W] float64,
    ``normal`` [H, W, 3], the four fields [H, W], ``changed`` [H, W] bool). ``R``, ``t`` the box's
    rotation and centre, ``o`` the camera centre in the box's frame, ``half`` its half-size,
    ``floor`` the height on axis ``vertical`` below which the road shows, ``center`` the camera
    centre (world), ``body_lo``/``body_hi`` and ``cabin_lo``/``cabin_hi`` the body's and the
    glasshouse's boxes, ``slack`` the box's margin (m), ``beside`` how far (m) outside the box's
    footprint a surface on the object below ``floor`` is tails too (``inf``: never).
    """
    rh, rw = filled.shape
    a0, a1, a2 = center[0] - t[0], center[1] - t[1], center[2] - t[2]
    s0, s1, s2 = half[0] + slack, half[1] + slack, half[2] + slack
    for r in range(rh):
        y = y0 + r
        for c in range(rw):
            x = x0 + c
            if grown[r, c]:
                hulls[y, x] = True
                continue
            if allowed[y, x] and _tail_on_object(rays, distance, y, x, a0, a1, a2, R, s0, s1, s2, half, vertical,
                                                 floor, beside):
                tails[y, x] = True
    lo = -half
    for r in range(rh):
        y = y0 + r
        for c in range(rw):
            x = x0 + c
            if not filled[r, c] or not allowed[y, x]:
                continue
            r0, r1, r2 = rays[y, x, 0], rays[y, x, 1], rays[y, x, 2]
            d0 = r0 * R[0, 0] + r1 * R[1, 0] + r2 * R[2, 0]
            d1 = r0 * R[0, 1] + r1 * R[1, 1] + r2 * R[2, 1]
            d2 = r0 * R[0, 2] + r1 * R[1, 2] + r2 * R[2, 2]
            near, far = _slab(o, d0, d1, d2, lo, half)
            if not (far >= near and near > 0.0):
                continue
            seen = distance[y, x]
            through = _hits(o, d0, d1, d2, body_lo, body_hi) or _hits(o, d0, d1, d2, cabin_lo, cabin_hi)
            behind = near + slack < seen and through
            if behind:
                # the glasshouse's face where the ray meets it through a window (not its top) before
                # the body and the lidar's surface (the glass the lidar saw through), else the box's
                b_in, b_out = _slab(o, d0, d1, d2, body_lo, body_hi)
                c_in, c_out = _slab(o, d0, d1, d2, cabin_lo, cabin_hi)
                hit_b = b_out >= _nan_max(b_in, 0.0) and b_out > 0.0
                hit_c = c_out >= _nan_max(c_in, 0.0) and c_out > 0.0
                axis, sign = _entry_face(o, d0, d1, d2, c_in, cabin_lo, cabin_hi)
                entry = c_in
                if not (hit_c and c_in < seen and not (hit_b and b_in < c_in) and axis != vertical):
                    axis, sign = _entry_face(o, d0, d1, d2, near, lo, half)
                    entry = near
                for i in range(3):
                    normal[y, x, i] = sign * R[i, axis]
                distance[y, x] = entry
            elif math.isfinite(seen):
                p0, p1, p2 = o[0] + d0 * seen, o[1] + d1 * seen, o[2] + d2 * seen
                pv = p0 if vertical == 0 else (p1 if vertical == 1 else p2)
                if not (abs(p0) <= s0 and abs(p1) <= s1 and abs(p2) <= s2 and pv >= floor):
                    continue
            else:
                continue
            ground[y, x] = 0.0
            open_[y, x] = 1.0
            puddle[y, x] = 0.0
            track[y, x] = 0.0
            changed[y, x] = True


@numba.njit(cache=True, error_model="numpy")
def top_band_kernel(x0, y0, rw, rh, rays, distance, center, R, t, half, slack, vertical, floor,  # type: ignore[no-untyped-def]  # pragma: no cover
                    image, steps, reach, step_min, share, lookback, bands):
    """One box's bands over its top
    (:func:`~wcbench.reference_model.appearance.box_shells._top_band_pixels`, its numpy reference
    and arguments), marked in ``bands`` [H, W] bool."""
    a0, a1, a2 = center[0] - t[0], center[1] - t[1], center[2] - t[2]
    s0, s1, s2 = half[0] + slack, half[1] + slack, half[2] + slack
    heights = np.zeros(rw, np.int64)
    tops = np.full(rw, -1, np.int64)
    for c in range(rw):
        x = x0 + c
        prev = False
        for r in range(rh):
            y = y0 + r
            seen = distance[y, x]
            on = _on_object(rays, distance, y, x, a0, a1, a2, R, s0, s1, s2, vertical, floor)
            starts = on and not prev and r > 0
            prev = on
            if not starts:
                continue
            far = False
            for i in range(max(0, r - lookback), r):
                above_d = distance[y0 + i, x]
                far = far or (math.isfinite(above_d) and above_d > seen + 1.0)
            if not far:
                continue
            stop = min(rh, r + reach + 1)
            if stop - r < 3:
                break
            strongest = 0.0
            for i in range(r, stop):
                strongest = max(strongest, float(steps[y0 + i, x]))
            level = max(step_min, share * strongest)
            edge = -1
            for i in range(r, stop):
                if steps[y0 + i, x] >= level:
                    edge = i
                    break
            if edge < r + 2:
                break
            near_above, near_below = 0.0, 0.0
            n_below = min(rh, edge + 2) - edge
            for k in range(3):
                band = 0.0
                for i in range(r, edge):
                    band += image[y0 + i, x, k]
                band /= edge - r
                below = 0.0
                for i in range(edge, edge + n_below):
                    below += image[y0 + i, x, k]
                below /= n_below
                near_above += (band - image[y - 1, x, k]) ** 2
                near_below += (band - below) ** 2
            if near_above < near_below:
                heights[c], tops[c] = edge - r, r
            break
    window = np.empty(5, np.int64)
    for c in range(rw):
        if tops[c] < 0:
            continue
        for j in range(5):
            window[j] = heights[min(max(c + j - 2, 0), rw - 1)]
        window.sort()
        for i in range(tops[c], tops[c] + min(window[2], heights[c])):
            if _on_object(rays, distance, y0 + i, x0 + c, a0, a1, a2, R, s0, s1, s2, vertical, floor):
                bands[y0 + i, x0 + c] = True
