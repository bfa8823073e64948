"""Numba kernel of :mod:`.particles`: positions, wrap and culling of a particle field in one pass.

Mirrors :meth:`.particles.ParticleField.visible` with ``fast=False`` (the numpy reference): the
same operations in the same order, so wrap counts and kept indices agree exactly and positions to
rounding (only ``sin`` may differ by an ulp between numpy's SIMD and libm). Compiled on first use
and cached on disk.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["field_kernel"]

_M1 = np.uint64(0x9E3779B97F4A7C15)
_M2 = np.uint64(0xBF58476D1CE4E5B9)
_M3 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


@numba.njit(cache=True, inline="always")
def _splitmix(x):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    x = x + _M1
    x = (x ^ (x >> _S30)) * _M2
    x = (x ^ (x >> _S27)) * _M3
    return x ^ (x >> _S31)


@numba.njit(cache=True, inline="always")
def _hash_uniform(seed, index, counter, stream):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Mirrors :func:`.particles._hash_uniform`."""
    x = seed * _M1
    x = _splitmix(x ^ np.uint64(index))
    x = _splitmix(x ^ np.uint64(np.int64(counter)))
    x = _splitmix(x ^ np.uint64(stream))
    return float(x >> _S11) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, nogil=True)
def field_kernel(  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    initial,
    vel,
    amp,
    omega,
    phase,
    offset,
    has_turb,
    t,
    shift,
    size,
    lo,
    seed,
    basis,
    c,
    r2_max,
    r2_min,
    do_view,
    W,
    kp,
    size_px,
    near,
    reach,
    out_pos,
    out_ok,
):
    """Fill ``out_pos`` [N, 3] (world) and ``out_ok`` [N] (in range and, with ``do_view``, in view).

    Arguments are the arrays of :class:`.particles.ParticleField` (box coordinates) plus
    ``shift`` = camera in box coordinates + box low corner, the view ``W`` [3, 4], ``kp`` =
    (fx, fy, cx, cy), ``size_px`` = (width, height), ``near`` and ``reach`` (3-sigma bound, m).
    """
    n = initial.shape[0]
    u = np.empty(3)
    for i in range(n):
        for a in range(3):
            u[a] = initial[i, a] + (vel[i, a] * t - shift[a])
            if has_turb:
                acc = 0.0
                for k in range(omega.shape[2]):
                    acc += amp[i, a, k] * np.sin(omega[i, a, k] * t + phase[i, a, k])
                u[a] += acc - offset[i, a]
        wraps = np.floor(u[2] / size[2])
        if wraps != 0.0:
            w = np.int64(wraps)
            u[0] += size[0] * _hash_uniform(seed, i, w, 0)
            u[1] += size[1] * _hash_uniform(seed, i, w, 1)
        for a in range(3):
            u[a] = u[a] - np.floor(u[a] / size[a]) * size[a] + lo[a]
        d2 = 0.0
        for a in range(3):
            p = u[0] * basis[0, a] + u[1] * basis[1, a] + u[2] * basis[2, a] + c[a]
            out_pos[i, a] = p
            d2 += (p - c[a]) * (p - c[a])
        ok = d2 < r2_max and d2 > r2_min
        if ok and do_view:
            x = W[0, 0] * out_pos[i, 0] + W[0, 1] * out_pos[i, 1] + W[0, 2] * out_pos[i, 2] + W[0, 3]
            y = W[1, 0] * out_pos[i, 0] + W[1, 1] * out_pos[i, 1] + W[1, 2] * out_pos[i, 2] + W[1, 3]
            z = W[2, 0] * out_pos[i, 0] + W[2, 1] * out_pos[i, 1] + W[2, 2] * out_pos[i, 2] + W[2, 3]
            if z <= near:
                ok = False
            else:
                xn, yn = x / z, y / z
                px, py = reach / z + 3.0 / kp[0], reach / z + 3.0 / kp[1]
                ok = (
                    xn > -kp[2] / kp[0] - px
                    and xn < (size_px[0] - kp[2]) / kp[0] + px
                    and yn > -kp[3] / kp[1] - py
                    and yn < (size_px[1] - kp[3]) / kp[1] + py
                )
        out_ok[i] = ok
