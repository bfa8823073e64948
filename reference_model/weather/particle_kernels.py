"""Numba kernels of :mod:`.particles`: a particle field's positions, culling and Gaussians.

Two passes mirror :meth:`.particles.ParticleField.gaussians` with ``fast=False`` (the numpy
reference), the same operations in the same order:

* :func:`field_kernel`: positions, wrap and range/view culling of every particle (parallel);
* :func:`shape_kernel`: the Gaussians of the kept particles (streak or flake shapes, opacity
  with fades, the capped-count scaling and the rasterizer's dilation compensation), written
  straight into caller-owned buffers, e.g. the tail of the renderer's scene + particle arrays.

Sines and cosines use :func:`fast_sin` / :func:`fast_cos` (Cody-Waite reduction and a Taylor
polynomial, branch-free so LLVM vectorises it): 3.3e-16 from libm at most over 2M random
arguments in each of |x| < 1e2, 1e4, 1e7, and 15x faster than libm calls in a numba loop on this
machine (tests assert < 1e-15 for |x| <= 4000). Compiled on first use and cached on disk.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["fast_cos", "fast_sin", "field_kernel", "shape_kernel"]

_M1 = np.uint64(0x9E3779B97F4A7C15)
_M2 = np.uint64(0xBF58476D1CE4E5B9)
_M3 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)

# pi in three parts of 27 significant bits: k * _PI_A and k * _PI_B are exact for |k| < 2^26, so
# x - k pi keeps full precision for |x| up to ~1e7 (Cody-Waite).
_INV_PI = 1.0 / math.pi
_PI_A = 3.141592651605606
_PI_B = 1.9841871479187034e-09
_PI_C = 1.1442377452219664e-17
# Taylor coefficients of sin r = r (S0 + S1 r^2 + ... + S10 r^20) on |r| <= pi/2: the first
# omitted term is below pi/2^23 / 23! = 1.2e-18.
(_S0, _S1, _S2, _S3, _S4, _S5, _S6, _S7, _S8, _S9, _S10) = ((-1.0) ** j / math.factorial(2 * j + 1) for j in range(11))
_ARM = math.pi / 3.0  # a flake's three Gaussians at 60 degrees


@numba.njit(cache=True, inline="always")
def _splitmix(x):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    x = x + _M1
    x = (x ^ (x >> _S30)) * _M2
    x = (x ^ (x >> _S27)) * _M3
    return x ^ (x >> _S31)


@numba.njit(cache=True, inline="always")
def _hash_uniform(seed, index, counter, stream):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Mirrors :func:`.hashing.hash_uniform`."""
    x = seed * _M1
    x = _splitmix(x ^ np.uint64(index))
    x = _splitmix(x ^ np.uint64(np.int64(counter)))
    x = _splitmix(x ^ np.uint64(stream))
    return float(x >> _S11) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _sin_reduced(x, k):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """sin(x - k pi) times (-1)^k for an integral or half-integral ``k`` with |x - k pi| <= pi/2."""
    r = ((x - k * _PI_A) - k * _PI_B) - k * _PI_C
    r2 = r * r
    p = _S10
    p = p * r2 + _S9
    p = p * r2 + _S8
    p = p * r2 + _S7
    p = p * r2 + _S6
    p = p * r2 + _S5
    p = p * r2 + _S4
    p = p * r2 + _S3
    p = p * r2 + _S2
    p = p * r2 + _S1
    p = p * r2 + _S0
    return p * r


@numba.njit(cache=True, inline="always", error_model="numpy")
def fast_sin(x):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """sin(x) for float64 ``x`` (|x| < 1e7; see the module docstring for its accuracy)."""
    k = np.floor(x * _INV_PI + 0.5)
    sign = 1.0 - 2.0 * (k - 2.0 * np.floor(0.5 * k))  # (-1)^k
    return sign * _sin_reduced(x, k)


@numba.njit(cache=True, inline="always", error_model="numpy")
def fast_cos(x):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """cos(x) = sin(x + pi/2), reduced around the half-integers k - 1/2 so pi/2 adds no rounding."""
    k = np.floor(x * _INV_PI + 1.0)  # cos x = (-1)^k sin(x - (k - 1/2) pi)
    sign = 1.0 - 2.0 * (k - 2.0 * np.floor(0.5 * k))
    return sign * _sin_reduced(x, k - 0.5)


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _flutter(amp, omega, phase, t, out):  # type: ignore[no-untyped-def]  # pragma: no cover
    """out[j] = amp[j] sin(omega[j] t + phase[j]) over flat arrays (a vectorised loop)."""
    n = amp.shape[0]
    step = 4096
    for chunk in numba.prange((n + step - 1) // step):
        for j in range(chunk * step, min(n, (chunk + 1) * step)):
            out[j] = amp[j] * fast_sin(omega[j] * t + phase[j])


@numba.njit(cache=True, parallel=True, error_model="numpy")
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
    n_modes = omega.shape[2]
    turb = np.empty((n, 3, n_modes)) if has_turb else np.empty((0, 3, n_modes))
    if has_turb:
        _flutter(amp.reshape(-1), omega.reshape(-1), phase.reshape(-1), t, turb.reshape(-1))
    x_lo, x_hi = -kp[2] / kp[0], (size_px[0] - kp[2]) / kp[0]
    y_lo, y_hi = -kp[3] / kp[1], (size_px[1] - kp[3]) / kp[1]
    for i in numba.prange(n):
        u0 = initial[i, 0] + (vel[i, 0] * t - shift[0])
        u1 = initial[i, 1] + (vel[i, 1] * t - shift[1])
        u2 = initial[i, 2] + (vel[i, 2] * t - shift[2])
        if has_turb:
            # Summed in the numpy reference's order: (sum_k amp sin) - offset.
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for k in range(n_modes):
                a0 += turb[i, 0, k]
                a1 += turb[i, 1, k]
                a2 += turb[i, 2, k]
            u0 += a0 - offset[i, 0]
            u1 += a1 - offset[i, 1]
            u2 += a2 - offset[i, 2]
        wraps = np.floor(u2 / size[2])
        if wraps != 0.0:
            w = np.int64(wraps)
            u0 += size[0] * _hash_uniform(seed, i, w, 0)
            u1 += size[1] * _hash_uniform(seed, i, w, 1)
        u0 = u0 - np.floor(u0 / size[0]) * size[0] + lo[0]
        u1 = u1 - np.floor(u1 / size[1]) * size[1] + lo[1]
        u2 = u2 - np.floor(u2 / size[2]) * size[2] + lo[2]
        p0 = u0 * basis[0, 0] + u1 * basis[1, 0] + u2 * basis[2, 0] + c[0]
        p1 = u0 * basis[0, 1] + u1 * basis[1, 1] + u2 * basis[2, 1] + c[1]
        p2 = u0 * basis[0, 2] + u1 * basis[1, 2] + u2 * basis[2, 2] + c[2]
        out_pos[i, 0] = p0
        out_pos[i, 1] = p1
        out_pos[i, 2] = p2
        d2 = (p0 - c[0]) * (p0 - c[0]) + (p1 - c[1]) * (p1 - c[1]) + (p2 - c[2]) * (p2 - c[2])
        ok = d2 < r2_max and d2 > r2_min
        if ok and do_view:
            x = W[0, 0] * p0 + W[0, 1] * p1 + W[0, 2] * p2 + W[0, 3]
            y = W[1, 0] * p0 + W[1, 1] * p1 + W[1, 2] * p2 + W[1, 3]
            z = W[2, 0] * p0 + W[2, 1] * p1 + W[2, 2] * p2 + W[2, 3]
            if z <= near:
                ok = False
            else:
                xn, yn = x / z, y / z
                px, py = reach / z + 3.0 / kp[0], reach / z + 3.0 / kp[1]
                ok = xn > x_lo - px and xn < x_hi + px and yn > y_lo - py and yn < y_hi + py
        out_ok[i] = ok


@numba.njit(cache=True, inline="always", error_model="numpy")
def _dilation_factor(mx, my, mz, qw, qx, qy, qz, sx, sy, sz, W, fx, fy, eps2d):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Mirrors :func:`.particle_geometry.particle_dilation_compensation` for one Gaussian (float64)."""
    qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    w, x, y, z = qw / qn, qx / qn, qy / qn, qz / qn
    R00, R01, R02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    R10, R11, R12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    R20, R21, R22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    cx = W[0, 0] * mx + W[0, 1] * my + W[0, 2] * mz + W[0, 3]
    cy = W[1, 0] * mx + W[1, 1] * my + W[1, 2] * mz + W[1, 3]
    cz = max(W[2, 0] * mx + W[2, 1] * my + W[2, 2] * mz + W[2, 3], 1e-6)
    # J W: rows of the projection Jacobian times the rotation of the view.
    j00, j02 = fx / cz, -fx * cx / (cz * cz)
    j11, j12 = fy / cz, -fy * cy / (cz * cz)
    a0 = j00 * W[0, 0] + j02 * W[2, 0]
    a1 = j00 * W[0, 1] + j02 * W[2, 1]
    a2 = j00 * W[0, 2] + j02 * W[2, 2]
    b0 = j11 * W[1, 0] + j12 * W[2, 0]
    b1 = j11 * W[1, 1] + j12 * W[2, 1]
    b2 = j11 * W[1, 2] + j12 * W[2, 2]
    # T = (J W) (R S): columns of R scaled by the standard deviations.
    t00 = (a0 * R00 + a1 * R10 + a2 * R20) * sx
    t01 = (a0 * R01 + a1 * R11 + a2 * R21) * sy
    t02 = (a0 * R02 + a1 * R12 + a2 * R22) * sz
    t10 = (b0 * R00 + b1 * R10 + b2 * R20) * sx
    t11 = (b0 * R01 + b1 * R11 + b2 * R21) * sy
    t12 = (b0 * R02 + b1 * R12 + b2 * R22) * sz
    c00 = t00 * t00 + t01 * t01 + t02 * t02
    c11 = t10 * t10 + t11 * t11 + t12 * t12
    # Cauchy-Binet, as the reference: c00 c11 - c01^2 is rounding noise for a long thin streak.
    m01 = t00 * t11 - t01 * t10
    m02 = t00 * t12 - t02 * t10
    m12 = t01 * t12 - t02 * t11
    det = m01 * m01 + m02 * m02 + m12 * m12
    det_d = det + eps2d * (c00 + c11) + eps2d * eps2d
    factor = math.sqrt(det / max(det_d, 1e-30))
    if not math.isfinite(factor):
        return 1.0
    return min(max(factor, 0.0), 1.0)


# fmt: off
@numba.njit(cache=True, inline="always", error_model="numpy")
def _write_row(  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    row, i, p0, p1, p2, qw, qx, qy, qz, s0, s1, s2, opacity, v0, v1, v2,
    color, compensate, W, fx, fy, eps2d, means, quats, scales, opacities, colors, particle, velocity,
):
    """One output Gaussian, cast to float32 as the reference does (dilation on the float32 values)."""
    mx, my, mz = np.float32(p0), np.float32(p1), np.float32(p2)
    qw32, qx32, qy32, qz32 = np.float32(qw), np.float32(qx), np.float32(qy), np.float32(qz)
    s0_, s1_, s2_ = np.float32(s0), np.float32(s1), np.float32(s2)
    op = np.float32(opacity)
    if compensate:
        factor = _dilation_factor(
            float(mx), float(my), float(mz), float(qw32), float(qx32), float(qy32), float(qz32),
            float(s0_), float(s1_), float(s2_), W, fx, fy, eps2d,
        )
        op = np.float32(op * np.float32(factor))
    means[row, 0], means[row, 1], means[row, 2] = mx, my, mz
    quats[row, 0], quats[row, 1], quats[row, 2], quats[row, 3] = qw32, qx32, qy32, qz32
    scales[row, 0], scales[row, 1], scales[row, 2] = s0_, s1_, s2_
    opacities[row] = op
    colors[row, 0], colors[row, 1], colors[row, 2] = color[0], color[1], color[2]
    particle[row] = i
    velocity[row, 0], velocity[row, 1], velocity[row, 2] = np.float32(v0), np.float32(v1), np.float32(v2)
# fmt: on


@numba.njit(cache=True, parallel=True, error_model="numpy")
def shape_kernel(  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    keep,
    pos,
    c,
    t,
    vel_box,
    amp,
    omega,
    phase,
    has_turb,
    basis,
    cam_vel,
    exposure_s,
    is_rain,
    physical,
    stretch,
    diameter_mm,
    size_ratio,
    short_ratio,
    scale_m,
    opacity0,
    fade_m,
    radius_m,
    min_distance_m,
    represented,
    orientation,
    spin_rate,
    compensate,
    W,
    fx,
    fy,
    eps2d,
    color,
    means,
    quats,
    scales,
    opacities,
    colors,
    particle,
    velocity,
):
    """Write the Gaussians of the kept particles ``keep`` [K] (one per drop, three per flake).

    Row ``j`` (drops) or rows ``3 j .. 3 j + 2`` (flakes) of the output arrays means [M, 3],
    quats [M, 4], scales [M, 3], opacities [M], colors [M, 3] (float32), particle [M] (int64) and
    velocity [M, 3] (float32) belong to ``keep[j]``; ``pos`` [N, 3] are the positions from
    :func:`field_kernel`. (Arrays are passed one by one: numba's parallel loops drop writes to
    arrays passed inside a tuple.) Physical specs size a particle as sigma = D ``size_ratio`` / 4,
    the two short axes times ``short_ratio``; others use ``scale_m`` [3]. With ``compensate``
    opacities are scaled by the dilation factor of view ``W`` [3, 4].
    """
    n_modes = omega.shape[2]
    for j in numba.prange(keep.shape[0]):
        i = keep[j]
        p0, p1, p2 = pos[i, 0], pos[i, 1], pos[i, 2]
        dist = math.sqrt((p0 - c[0]) * (p0 - c[0]) + (p1 - c[1]) * (p1 - c[1]) + (p2 - c[2]) * (p2 - c[2]))
        fade = 1.0
        if fade_m > 0:
            fade *= min(max((radius_m - dist) / fade_m, 0.0), 1.0)
        if min_distance_m > 0:
            fade *= min(max((dist - min_distance_m) / min_distance_m, 0.0), 1.0)
        vb0, vb1, vb2 = vel_box[i, 0], vel_box[i, 1], vel_box[i, 2]
        if has_turb:
            f0 = 0.0
            f1 = 0.0
            f2 = 0.0
            for k in range(n_modes):
                f0 += amp[i, 0, k] * omega[i, 0, k] * fast_cos(omega[i, 0, k] * t + phase[i, 0, k])
                f1 += amp[i, 1, k] * omega[i, 1, k] * fast_cos(omega[i, 1, k] * t + phase[i, 1, k])
                f2 += amp[i, 2, k] * omega[i, 2, k] * fast_cos(omega[i, 2, k] * t + phase[i, 2, k])
            vb0, vb1, vb2 = vb0 + f0, vb1 + f1, vb2 + f2
        v0 = vb0 * basis[0, 0] + vb1 * basis[1, 0] + vb2 * basis[2, 0]
        v1 = vb0 * basis[0, 1] + vb1 * basis[1, 1] + vb2 * basis[2, 1]
        v2 = vb0 * basis[0, 2] + vb1 * basis[1, 2] + vb2 * basis[2, 2]
        if physical:
            base0 = diameter_mm[i] * size_ratio * 1e-3 / 4.0  # sigma = D / 4
            base1 = base0 * short_ratio
            base2 = base0 * short_ratio
        else:
            base0, base1, base2 = scale_m[0], scale_m[1], scale_m[2]
        opacity = opacity0
        if is_rain and stretch:
            # A uniform segment of length |v| t_exp has variance (|v| t_exp)^2 / 12.
            r0, r1, r2 = v0 - cam_vel[0], v1 - cam_vel[1], v2 - cam_vel[2]
            travel = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2) * exposure_s
            long = math.sqrt(base2 * base2 + travel * travel / 12.0)
            opacity = opacity * base2 / long
            base2 = long
        if represented > 1.0:
            # Optical depth of k independent drops: 1 - (1 - a)^k.
            opacity = -math.expm1(represented * math.log1p(-min(opacity, 0.99)))
        opacity = min(max(opacity * fade, 0.0), 1.0)
        rw = rx = ry = 0.0
        if is_rain:
            # quat_from_axis_to: local z onto the line of the relative velocity, the shorter turn.
            r0, r1, r2 = v0 - cam_vel[0], v1 - cam_vel[1], v2 - cam_vel[2]
            nv = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
            d0, d1, d2 = 0.0, 0.0, 1.0
            if nv > 1e-12:
                d0, d1, d2 = r0 / max(nv, 1e-300), r1 / max(nv, 1e-300), r2 / max(nv, 1e-300)
            if d2 < 0:
                d0, d1, d2 = -d0, -d1, -d2
            qn = math.sqrt((1.0 + d2) * (1.0 + d2) + d1 * d1 + d0 * d0 + 0.0)
            rw, rx, ry = (1.0 + d2) / qn, -d1 / qn, d0 / qn
        angle = spin_rate[i] * t
        ow, ox, oy, oz = orientation[i, 0], orientation[i, 1], orientation[i, 2], orientation[i, 3]
        rows = 1 if is_rain else 3
        for m in range(rows):
            if is_rain:
                qw, qx, qy, qz = rw, rx, ry, 0.0
            else:
                half = 0.5 * (angle + m * _ARM)
                bw, bz = fast_cos(half), fast_sin(half)
                # orientation * (cos h, 0, 0, sin h): the arm's spin about the flake's normal.
                qw, qx, qy, qz = ow * bw - oz * bz, ox * bw + oy * bz, oy * bw - ox * bz, ow * bz + oz * bw
            # fmt: off
            _write_row(
                rows * j + m, i, p0, p1, p2, qw, qx, qy, qz, base0, base1, base2, opacity, v0, v1, v2,
                color, compensate, W, fx, fy, eps2d, means, quats, scales, opacities, colors, particle, velocity,
            )
            # fmt: on
