"""Fast CPU rasterizer: numba kernels for projection, tile binning, compositing and their backward.

Pipeline (forward):

1. ``_project_kernel`` (parallel over Gaussians, float64 arithmetic, 8 Gaussians per vector loop
   ``_project_lanes``): cull (non-finite, near/far, degenerate, transparent, off-screen), EWA
   projection (the 2D determinant from the minors of J V R diag(s), ``_cov2d``: needles keep it),
   conic, per-axis pixel box; what compositing reads of a Gaussian goes into one 64-byte record,
   in index order.
2. Binning: the visible set compacted in parallel (``_visible_keys``), one global depth sort (a
   chunked parallel LSD radix sort of the float bits, ``_radix_sort``), then a stable counting
   sort into 16x16 tiles (per-chunk histograms counted from the boxes in depth order,
   ``_tile_counts``, prefix sums ``_tile_offsets``, scatter ``_tile_fill``): every tile list comes
   out front to back without a per-tile sort, and every pass is parallel (docs/design.md §8). The
   lists hold Gaussian indices: compositing reads the records where the projection wrote them.
3. ``_render_forward`` (parallel over tiles, even ones then odd ones): Gaussian-major loop over the tile
   list, records prefetched ahead; each box row is evaluated as one 8- or 16-lane vector
   (``_fexp`` is a branch-free float32 exp so that LLVM vectorizes the row). Per-pair math in
   float32, transmittance and sums in float64; a pixel stops before T < 1e-4, a row is skipped
   when all its box pixels have stopped, a tile when all its pixels have.

Backward: ``_render_backward`` replays the same front-to-back order per tile with the same float
ops, so every skip and stop decision is the forward's, bit for bit. Since the forward saved its
float64 sums, the light behind pair i is ``total - running sum up to i``: no back-to-front pass and
no division chains. Per (tile, Gaussian) entry the gradients go to their own row of a buffer, at
the entry's tile-list position (a tile's writes stream), summed per Gaussian afterwards through
the list of each Gaussian's rows that binning wrote (``_reduce_entries``): no atomics, and
results do not depend on the thread count.
``_project_backward`` then chains to the 3D parameters. Gradients beyond float32 saturate at
+-3.4e38 (``_sat``) instead of overflowing to Inf (docs/design.md §9).

Vectorization notes (measured: a lane loop that LLVM leaves scalar is ~6x slower): indices are
unsigned so that numba drops its negative-index wraparound; all per-tile state of a lane loop
lives in one float64 buffer at constant offsets, because LLVM refuses the runtime alias checks for
loops of fewer than 16 iterations; division uses ``error_model="numpy"`` (no exception branch).

The twin :mod:`.torch_twin` computes the same function with plain torch ops.
"""

from __future__ import annotations

import math
import threading
import time
import weakref
from typing import Any

import numba
import numpy as np
import torch
from llvmlite import ir
from numba import njit, prange
from numba.core import cgutils, types
from numba.extending import intrinsic, overload
from numba.np.unsafe.ndarray import to_fixed_tuple

from wcbench.reference_model.raster.common import (
    ALPHA_MAX,
    ALPHA_MIN,
    CULL_DEGENERATE,
    CULL_NEAR_FAR,
    CULL_NONFINITE,
    CULL_OFFSCREEN,
    CULL_TRANSPARENT,
    EPS2D,
    MAX_DEPTH,
    MAX_EXTENT,
    QUAT_EPS2,
    SIGMA_EXTENT,
    T_STOP,
    TILE_SIZE,
    counts_meta,
    empty_meta,
)

__all__ = ["RenderJob"]

F32 = np.float32
TS = TILE_SIZE
#: log2 of the tile size: the tile of pixel x is x >> _TS_SHIFT, which is floor(x / TS) for every
#: integer x, without the sign fix-ups of a floor division (`bench raster`'s binning phase: 7.8 -> 6.0-6.7
#: ms at one thread with the other changes of docs/design.md §8's third pass).
_TS_SHIFT = TS.bit_length() - 1
assert 1 << _TS_SHIFT == TS
# float32 constants: a bare Python float would promote every float32 expression to float64.
_HALF = F32(0.5)
_ONE = F32(1.0)
_TWO = F32(2.0)
_ZERO = F32(0.0)
_ALPHA_MIN = F32(ALPHA_MIN)
_ALPHA_MAX = F32(ALPHA_MAX)
# Cephes expf: exp(x) = 2^n p(r), r = x - n ln 2 split in two parts for exactness.
_LOG2E = F32(1.44269504088896341)
_ROUND = F32(12582912.0)  # 1.5 * 2^23: (t + R) - R rounds t to the nearest integer in float32
_LN2_HI = F32(0.693359375)
_LN2_LO = F32(-2.12194440e-4)
_P0, _P1, _P2 = F32(1.9875691500e-4), F32(1.3981999507e-3), F32(8.3334519073e-3)
_P3, _P4, _P5 = F32(4.1665795894e-2), F32(1.6666665459e-1), F32(5.0000001201e-1)
_EXP_LO, _EXP_HI = F32(-87.0), F32(88.0)
#: Largest finite float32: gradients beyond it saturate there instead of becoming Inf (and NaN
#: further down the chain); the twin does the same (docs/design.md §9).
_GMAX = float(np.finfo(np.float32).max)
_GMAX32 = F32(_GMAX)
#: 255 o above which sqrt(2 ln(255 o)) >= SIGMA_EXTENT for sure (exp(SIGMA_EXTENT^2 / 2), plus a
#: relative margin far above the log's rounding): the box extent is SIGMA_EXTENT there.
_KK_SAT = math.exp(0.5 * SIGMA_EXTENT * SIGMA_EXTENT) * (1.0 + 1e-9)


@njit(cache=True, inline="always")
def _sat(x: float) -> float:
    """``x`` clamped to the finite float32 range (a gradient too large for float32 saturates)."""
    return min(max(x, -_GMAX), _GMAX)


def _bits_to_f32_typer(typingctx: Any, bits: Any) -> Any:
    """Reinterpret an int32 as float32 (an LLVM bitcast, so loops using it still vectorize)."""
    sig = types.float32(types.int32)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.bitcast(args[0], ir.FloatType())

    return sig, codegen


_bits_to_f32: Any = intrinsic(_bits_to_f32_typer)


def _prefetch_typer_for(write: int) -> Any:
    """The typing function of a prefetch intrinsic (llvm.prefetch: high locality, data cache; for a
    read when ``write`` is 0, for a write when 1, which fetches the line in an owned state)."""

    def typer(typingctx: Any, arr: Any, row: Any) -> Any:
        sig = types.void(arr, row)

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            aryty = signature.args[0]
            ary = context.make_array(aryty)(context, builder, args[0])
            row = context.cast(builder, args[1], signature.args[1], types.intp)
            inds = [row] + [context.get_constant(types.intp, 0)] * (aryty.ndim - 1)
            ptr = cgutils.get_item_pointer2(context, builder, data=ary.data,
                                            shape=cgutils.unpack_tuple(builder, ary.shape),
                                            strides=cgutils.unpack_tuple(builder, ary.strides),
                                            layout=aryty.layout, inds=inds, wraparound=False, boundscheck=False)
            i8p = ir.IntType(8).as_pointer()
            i32 = ir.IntType(32)
            fn = cgutils.get_or_insert_function(builder.module,
                                                ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                                "llvm.prefetch.p0")
            builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, write), ir.Constant(i32, 3),
                              ir.Constant(i32, 1)])
            return context.get_dummy_value()

        return sig, codegen

    return typer


#: ``_prefetch(arr, row)``: hint the cache to fetch ``arr[row]`` for reading (never faults, even
#: past the end); ``_prefetch_write``: the same for a write.
_prefetch: Any = intrinsic(_prefetch_typer_for(0))
_prefetch_write: Any = intrinsic(_prefetch_typer_for(1))


#: int32 values to a 64-byte cache line.
_I32_PER_LINE = 16

#: How many tile-list entries ahead the render loops prefetch a Gaussian's record: a tile list
#: jumps through the records, so each record is otherwise a cache miss.
_PREFETCH = 8


def _fma_typer(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    """a * b + c of three float32 with one rounding (llvm.fma: a ``vfmadd`` in vectorized loops).

    numba does not contract a multiply and an add by itself, and leaving that to LLVM could round
    the forward and the backward differently; an explicit call rounds the same way everywhere.
    On a CPU without FMA instructions LLVM calls libm's ``fmaf`` instead: the same results, slower.
    """
    if not (a == b == c == types.float32):
        return None
    sig = types.float32(a, b, c)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.fma(args[0], args[1], args[2])

    return sig, codegen


_fma: Any = intrinsic(_fma_typer)


@njit(cache=True)
def _fexp(x: float) -> float:
    """float32 exp, ~1 ulp on [-87, 88] (inputs are clamped there); branch-free for vectorization.

    The same code runs in the forward, the backward and the pair replay, so all three make
    bit-identical skip decisions. The reduction and the polynomial are fused multiply-adds, which
    shortens the row's chain of dependent operations from 20 to 11 (the forward blend's timing:
    docs/design.md §8, fifth pass); the error stays within 1.5 ulp of the float64 exp (a test).
    """
    x = min(max(x, _EXP_LO), _EXP_HI)
    r = _fma(x, _LOG2E, _ROUND) - _ROUND
    xr = _fma(-r, _LN2_HI, x)
    xr = _fma(-r, _LN2_LO, xr)
    z = xr * xr
    p = _fma(_fma(_fma(_fma(_fma(_P0, xr, _P1), xr, _P2), xr, _P3), xr, _P4), xr, _P5)
    p = _fma(p, z, xr) + _ONE
    n = np.int32(r) + np.int32(127)
    return p * _bits_to_f32(n << np.int32(23))


# ---------------------------------------------------------------------------------------------------
# Projection
# ---------------------------------------------------------------------------------------------------
#
# Both projection passes run in lane loops: a parallel work item copies 8 Gaussians' inputs into a
# float64 buffer (scalar loads, and the few scalar-only pieces: the finiteness test of a variable
# number of colors, the log of a faint Gaussian's opacity), one non-inlined function evaluates all
# 8 with branch-free float64 code over that buffer (LLVM vectorizes it: one buffer at constant
# offsets needs no alias checks, and every branch is a select), and the results are copied out.
# The arithmetic is the per-Gaussian code's, op for op, so the outputs are the same bit for bit;
# `bench raster`'s projection phases went from 8.2 (forward) and 14.1 ms (backward) at one thread to
# 3.8-4.2 and 4.7-5.1 ms (docs/design.md §8).


@njit(cache=True, inline="always")
def _rotmat(qw: float, qx: float, qy: float, qz: float) -> tuple:
    """Normalised quaternion, 1/|q| and rotation matrix (row-major 9-tuple), all float64.

    A quaternion with |q|^2 <= QUAT_EPS2 is the identity, with 1/|q| = 0 (zero gradient).
    Branch-free (selects), so that it vectorizes in the lane loops.
    """
    sq = qw * qw + qx * qx + qy * qy + qz * qz
    ok = sq > QUAT_EPS2
    inv = 1.0 / np.sqrt(sq) if ok else 0.0
    w = qw * inv if ok else 1.0
    x = qx * inv if ok else 0.0
    y = qy * inv if ok else 0.0
    z = qz * inv if ok else 0.0
    R = (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
         2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
         2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
    return (w, x, y, z), inv, R


@njit(cache=True, inline="always")
def _mm(a: tuple, b: tuple) -> tuple:
    """Product of two row-major 3x3 matrices stored as 9-tuples."""
    return (a[0] * b[0] + a[1] * b[3] + a[2] * b[6], a[0] * b[1] + a[1] * b[4] + a[2] * b[7],
            a[0] * b[2] + a[1] * b[5] + a[2] * b[8],
            a[3] * b[0] + a[4] * b[3] + a[5] * b[6], a[3] * b[1] + a[4] * b[4] + a[5] * b[7],
            a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
            a[6] * b[0] + a[7] * b[3] + a[8] * b[6], a[6] * b[1] + a[7] * b[4] + a[8] * b[7],
            a[6] * b[2] + a[7] * b[5] + a[8] * b[8])


@njit(cache=True, inline="always")
def _tr(a: tuple) -> tuple:
    """Transpose of a row-major 3x3 9-tuple."""
    return (a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8])


@njit(cache=True, inline="always")
def _cov2d(R: tuple, sx: float, sy: float, sz: float, V: tuple, j00: float, j02: float, j11: float,
           j12: float) -> tuple:
    """Dilated 2D covariance (a, b, c) and its determinant, from T = J V R diag(s) (float64).

    cov2 = T T^T + EPS2D I. The determinant is not formed as a c - b^2, which for a needle
    (scales like (1e-30, 1e30, 1)) is the difference of two ~1e120 numbers and keeps only rounding
    noise of either sign; Cauchy-Binet gives det(T T^T) = sum of the squared 2x2 minors of T, and
    minor (i, j) of T is that of A = J V R (unit-sized) times s_i s_j, so the determinant keeps its
    relative precision and is positive: a needle is drawn as the line it projects to
    (docs/design.md §9). The twin (:func:`.torch_twin._project`) uses the same construction.
    """
    VR = _mm(V, R)
    a0, a1, a2 = j00 * VR[0] + j02 * VR[6], j00 * VR[1] + j02 * VR[7], j00 * VR[2] + j02 * VR[8]
    b0, b1, b2 = j11 * VR[3] + j12 * VR[6], j11 * VR[4] + j12 * VR[7], j11 * VR[5] + j12 * VR[8]
    t00, t01, t02 = a0 * sx, a1 * sy, a2 * sz
    t10, t11, t12 = b0 * sx, b1 * sy, b2 * sz
    a = t00 * t00 + t01 * t01 + t02 * t02
    b = t00 * t10 + t01 * t11 + t02 * t12
    c = t10 * t10 + t11 * t11 + t12 * t12
    m01 = (a0 * b1 - a1 * b0) * (sx * sy)
    m02 = (a0 * b2 - a2 * b0) * (sx * sz)
    m12 = (a1 * b2 - a2 * b1) * (sy * sz)
    det = (m01 * m01 + m02 * m02 + m12 * m12) + EPS2D * (a + c) + EPS2D * EPS2D
    return a + EPS2D, b, c + EPS2D, det


@njit(cache=True, inline="always")
def _jacobian_clamp(intr: np.ndarray, wf: float, hf: float) -> tuple:
    """Bounds (-x, +x, -y, +y) of x/z and y/z in the projection Jacobian: the frustum widened by
    0.3 of its half-width, as in gsplat, so far off-screen Gaussians do not blow up the Jacobian."""
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    tan_x = 0.5 * wf / fx
    tan_y = 0.5 * hf / fy
    return (
        cx / fx + 0.3 * tan_x,
        (wf - cx) / fx + 0.3 * tan_x,
        cy / fy + 0.3 * tan_y,
        (hf - cy) / fy + 0.3 * tan_y,
    )


@njit(cache=True)
def _camera_tuples(V: np.ndarray, tvec: np.ndarray, intr: np.ndarray, wf: float, hf: float) -> tuple:
    """The camera as the lane functions take it: rotation (row-major 9-tuple), translation,
    (fx, fy, cx, cy) and the Jacobian's clamp bounds (:func:`_jacobian_clamp`), all float64."""
    Vt = (V[0, 0], V[0, 1], V[0, 2], V[1, 0], V[1, 1], V[1, 2], V[2, 0], V[2, 1], V[2, 2])
    return Vt, (tvec[0], tvec[1], tvec[2]), (intr[0], intr[1], intr[2], intr[3]), _jacobian_clamp(intr, wf, hf)


@njit(cache=True, inline="always")
def _to_camera(px: float, py: float, pz: float, V: tuple, tv: tuple) -> tuple:
    """Camera coordinates (x, y, z) of a world point (float64; ``V`` row-major 9-tuple, ``tv`` 3-tuple)."""
    return (V[0] * px + V[1] * py + V[2] * pz + tv[0],
            V[3] * px + V[4] * py + V[5] * pz + tv[1],
            V[6] * px + V[7] * py + V[8] * pz + tv[2])


@njit(cache=True, inline="always")
def _ewa_jacobian(rx: float, ry: float, z: float, fx: float, fy: float, lim_xn: float, lim_xp: float,
                  lim_yn: float, lim_yp: float) -> tuple:
    """The projection's Jacobian (j00, j02, j11, j12) at (x/z, y/z) = (rx, ry) clamped to the
    widened frustum (:func:`_jacobian_clamp`), and the clamped (ux, uy)."""
    ux = min(max(rx, -lim_xn), lim_xp)
    uy = min(max(ry, -lim_yn), lim_yp)
    return fx / z, -fx * ux / z, fy / z, -fy * uy / z, ux, uy


#: Columns of the per-Gaussian render record (16 float32, one 64-byte cache line): what compositing
#: reads of a Gaussian. The projection writes it in index order, and compositing reads it there.
#: The 2D mean is stored as an integer anchor plus a float32 offset 0.5 - (m - anchor), so that
#: dx = (px - anchor) + offset loses nothing to the size of pixel coordinates (a float32 mean near
#: x = 1000 px is off by up to 3e-5 px, which moves the alpha of a 1-px Gaussian by ~1e-5). The
#: box (x0, x1, y0, y1, exact integers) and the first three colors ride along.
_AX, _AY, _HX, _HY, _CA, _CB, _CC, _OP, _Z, _BX, _COL = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 13
_NPRM = 16


#: Lanes of the projection's vector loops, and Gaussians per parallel work item (of the projection
#: passes and of the backward's reduction).
_PL = 8
_PROJ_CHUNK = 1024
#: Slots (each ``_PL`` wide) of the projection's lane buffer. Inputs: mean, quaternion, scales,
#: 255 * opacity, 2 ln(255 o) (faint Gaussians only), finite flag; outputs: 2D mean, conic, depth,
#: box, ceil of the half-extents, cull reason.
_LPX, _LQW, _LSX, _LO255, _LLOG, _LFIN = 0, 3, 7, 10, 11, 12
_LMX, _LQA, _LZ, _LBOX, _LEXT, _LWHY = 13, 15, 18, 19, 23, 25
_NLF = 26
#: Backward lane buffer: mean, quaternion, scales, dL/d (2D mean, conic, depth); then dL/d (mean,
#: quaternion, scales).
_LGM2, _LGCON, _LGZ = 10, 12, 15
_LOM, _LOQ, _LOS = 16, 19, 23
_NLB = 26


#: 255 * ALPHA_MIN in float64: ``255 o >= _O255_MIN`` is ``o >= ALPHA_MIN`` for a float32 ``o``
#: (multiplying by 255 in float64 is exact for float32 inputs and monotone).
_O255_MIN = 255.0 * float(np.float32(ALPHA_MIN))


@njit(cache=True, inline="always", error_model="numpy")
def _load_gaussian(buf: np.ndarray, ln: int, means: np.ndarray, quats: np.ndarray, scales: np.ndarray,
                   i: int) -> None:
    """Copy Gaussian ``i``'s mean, quaternion and scales into lane ``ln`` of ``buf`` (float64)."""
    for k in range(3):
        buf[(_LPX + k) * _PL + ln] = means[i, k]
        buf[(_LSX + k) * _PL + ln] = scales[i, k]
    for k in range(4):
        buf[(_LQW + k) * _PL + ln] = quats[i, k]


@njit(cache=True, error_model="numpy")
def _project_lanes(buf: np.ndarray, Vt: tuple, tv: tuple, intr: tuple, lims: tuple, near: float, far: float,
                   wf: float, hf: float) -> None:
    """Cull and project the ``_PL`` Gaussians of ``buf`` (float64, branch-free: one vector loop).

    Not inlined: the loop vectorizes in a function of its own, not in a parallel loop's body.
    """
    fx, fy, cx, cy = intr
    lim_xn, lim_xp, lim_yn, lim_yp = lims
    for ln in range(_PL):
        x, y, z = _to_camera(buf[_LPX * _PL + ln], buf[(_LPX + 1) * _PL + ln], buf[(_LPX + 2) * _PL + ln], Vt, tv)
        mx = fx * x / z + cx
        my = fy * y / z + cy
        j00, j02, j11, j12, _, _ = _ewa_jacobian(x / z, y / z, z, fx, fy, lim_xn, lim_xp, lim_yn, lim_yp)
        _, _, R = _rotmat(buf[_LQW * _PL + ln], buf[(_LQW + 1) * _PL + ln], buf[(_LQW + 2) * _PL + ln],
                          buf[(_LQW + 3) * _PL + ln])
        a, b, cc, det = _cov2d(R, buf[_LSX * _PL + ln], buf[(_LSX + 1) * _PL + ln], buf[(_LSX + 2) * _PL + ln],
                               Vt, j00, j02, j11, j12)
        proper = (np.isfinite(a) and np.isfinite(b) and np.isfinite(cc) and np.isfinite(det) and det > _ZERO
                  and np.isfinite(mx) and np.isfinite(my))
        o255 = buf[_LO255 * _PL + ln]
        # Box half-extent in sigmas: beyond sqrt(2 ln(255 o)) sigmas o exp(-q / 2) < 1/255 and every
        # pair would be skipped, so the box is the smaller of that and SIGMA_EXTENT. Above _KK_SAT
        # the log is >= SIGMA_EXTENT^2 / 2 with margin, so the min is SIGMA_EXTENT: the same value
        # without the scalar log call (most Gaussians are that opaque).
        kk = SIGMA_EXTENT if o255 >= _KK_SAT else min(np.sqrt(buf[_LLOG * _PL + ln]), SIGMA_EXTENT)
        ex = min(kk * np.sqrt(a), MAX_EXTENT)
        ey = min(kk * np.sqrt(cc), MAX_EXTENT)
        # The pixel box, clamped to the image: exact integers held in float64.
        x0 = max(min(max(np.ceil(mx - ex - 0.5), -1.0), wf), 0.0)
        x1 = min(min(max(np.floor(mx + ex - 0.5), -1.0), wf), wf - 1.0)
        y0 = max(min(max(np.ceil(my - ey - 0.5), -1.0), hf), 0.0)
        y1 = min(min(max(np.floor(my + ey - 0.5), -1.0), hf), hf - 1.0)
        why = (CULL_NONFINITE if buf[_LFIN * _PL + ln] == 0.0
               else CULL_NEAR_FAR if not (z > near and z < far and z <= MAX_DEPTH)
               else CULL_DEGENERATE if not proper else CULL_TRANSPARENT if not (o255 >= _O255_MIN)
               else CULL_OFFSCREEN if not (x0 <= x1 and y0 <= y1) else 0)
        buf[_LMX * _PL + ln] = mx
        buf[(_LMX + 1) * _PL + ln] = my
        buf[_LQA * _PL + ln] = cc / det
        buf[(_LQA + 1) * _PL + ln] = -b / det
        buf[(_LQA + 2) * _PL + ln] = a / det
        buf[_LZ * _PL + ln] = z
        buf[_LBOX * _PL + ln] = x0
        buf[(_LBOX + 1) * _PL + ln] = x1
        buf[(_LBOX + 2) * _PL + ln] = y0
        buf[(_LBOX + 3) * _PL + ln] = y1
        buf[_LEXT * _PL + ln] = np.ceil(ex)
        buf[(_LEXT + 1) * _PL + ln] = np.ceil(ey)
        buf[_LWHY * _PL + ln] = why


@njit(parallel=True, cache=True, error_model="numpy")
def _project_kernel(
    means: np.ndarray,  # [N, 3] f32
    quats: np.ndarray,  # [N, 4] f32
    scales: np.ndarray,  # [N, 3] f32
    opac: np.ndarray,  # [N] f32
    colors: np.ndarray,  # [N, C] f32
    V: np.ndarray,  # [3, 3] f64 world-to-camera rotation
    tvec: np.ndarray,  # [3] f64
    intr: np.ndarray,  # [4] f64 fx, fy, cx, cy
    width: int,
    height: int,
    near: float,
    far: float,
    means2d_f32: np.ndarray,  # out [N, 2] f32 (the public output: no serial cast afterwards)
    depth: np.ndarray,  # out [N] f32
    radii: np.ndarray,  # out [N, 2] i32 ceil of the box half-extent (px)
    reason: np.ndarray,  # out [N] i8
    rec: np.ndarray,  # out [N, 16] f32 render records (_AX ... _COL), written for visible Gaussians only
) -> None:
    """Cull and project every Gaussian (float64 arithmetic: per Gaussian it is cheap, and the 2D
    means, conics and boxes then carry no float32 rounding of large pixel coordinates).

    Culls, first reason first: non-finite input, depth outside (near, far), degenerate 2D
    covariance, opacity under ALPHA_MIN, box off the image. Culled Gaussians get zero outputs
    and no record.

    The records are written here, in index order, and stay there: binning reads only their boxes
    through the depth order, and compositing reads them in place (a tile's Gaussians lie closer
    together in index order than in depth order when the points are stored in spatial order, as
    lidar voxels are; docs/design.md §8).
    """
    wf = float(width)
    hf = float(height)
    Vt, tv, intr4, lims = _camera_tuples(V, tvec, intr, wf, hf)
    n_ch = colors.shape[1]
    n = means.shape[0]
    for item in prange((n + _PROJ_CHUNK - 1) // _PROJ_CHUNK):
        buf = np.empty(_NLF * _PL)
        for g0 in range(item * _PROJ_CHUNK, min(n, (item + 1) * _PROJ_CHUNK), _PL):
            nl = min(_PL, n - g0)
            for ln in range(_PL):
                i = g0 + min(ln, nl - 1)  # a short last group repeats its last Gaussian
                _load_gaussian(buf, ln, means, quats, scales, i)
                o255 = 255.0 * np.float64(opac[i])
                buf[_LO255 * _PL + ln] = o255
                buf[_LLOG * _PL + ln] = 2.0 * np.log(o255) if o255 < _KK_SAT else 0.0
                finite = np.isfinite(opac[i])
                for k in range(3):
                    finite = finite and np.isfinite(means[i, k]) and np.isfinite(scales[i, k])
                for k in range(4):
                    finite = finite and np.isfinite(quats[i, k])
                for k in range(n_ch):
                    finite = finite and np.isfinite(colors[i, k])
                buf[_LFIN * _PL + ln] = 1.0 if finite else 0.0
            _project_lanes(buf, Vt, tv, intr4, lims, near, far, wf, hf)
            for ln in range(nl):
                i = g0 + ln
                why = np.int8(buf[_LWHY * _PL + ln])
                reason[i] = why
                if why != 0:
                    means2d_f32[i, 0] = _ZERO
                    means2d_f32[i, 1] = _ZERO
                    depth[i] = _ZERO
                    radii[i, 0] = 0
                    radii[i, 1] = 0
                    continue
                for k in range(2):
                    m = buf[(_LMX + k) * _PL + ln]
                    means2d_f32[i, k] = F32(m)
                    radii[i, k] = np.int32(buf[(_LEXT + k) * _PL + ln])
                    anchor = np.floor(m)
                    rec[i, _AX + k] = anchor
                    rec[i, _HX + k] = 0.5 - (m - anchor)
                for k in range(3):
                    rec[i, _CA + k] = buf[(_LQA + k) * _PL + ln]
                    rec[i, _COL + k] = colors[i, min(k, n_ch - 1)]
                rec[i, _OP] = opac[i]
                z = F32(buf[_LZ * _PL + ln])
                depth[i] = z
                rec[i, _Z] = z
                for k in range(4):
                    rec[i, _BX + k] = np.int32(buf[(_LBOX + k) * _PL + ln])


@njit(cache=True, inline="always")
def _minor_grad(ai: float, aj: float, bi: float, bj: float, si: float, sj: float, gD: float) -> tuple:
    """Gradient through the 2x2 minor m = u si sj, u = ai bj - aj bi, of T = A diag(s) (rows a, b of
    A, columns i < j), given dL/d det = gD (dL/dm = 2 m gD): (dL/dsi, dL/dsj, du) where du = dL/du
    si sj feeds dL/dai = du bj, dL/dbj = du ai, dL/daj = -du bi, dL/dbi = -du aj."""
    u, ss = ai * bj - aj * bi, si * sj
    e = _TWO * (u * ss) * gD
    return e * u * sj, e * u * si, e * ss


@njit(cache=True, error_model="numpy")
def _project_backward_lanes(buf: np.ndarray, Vt: tuple, tv: tuple, intr: tuple, lims: tuple) -> None:
    """Chain dL/d (2D mean, conic, depth) of the ``_PL`` Gaussians of ``buf`` to their mean,
    quaternion and scales (float64, branch-free: one vector loop; see :func:`_project_lanes`)."""
    fx, fy = intr[0], intr[1]
    lim_xn, lim_xp, lim_yn, lim_yp = lims
    for ln in range(_PL):
        x, y, z = _to_camera(buf[_LPX * _PL + ln], buf[(_LPX + 1) * _PL + ln], buf[(_LPX + 2) * _PL + ln], Vt, tv)
        rx = x / z
        ry = y / z
        j00, j02, j11, j12, ux, uy = _ewa_jacobian(rx, ry, z, fx, fy, lim_xn, lim_xp, lim_yn, lim_yp)
        qn, qinv, R = _rotmat(buf[_LQW * _PL + ln], buf[(_LQW + 1) * _PL + ln], buf[(_LQW + 2) * _PL + ln],
                              buf[(_LQW + 3) * _PL + ln])
        s0, s1, s2 = buf[_LSX * _PL + ln], buf[(_LSX + 1) * _PL + ln], buf[(_LSX + 2) * _PL + ln]
        a, b, cc, det = _cov2d(R, s0, s1, s2, Vt, j00, j02, j11, j12)  # the forward's conic, bit for bit
        Qa, Qb, Qc = cc / det, -b / det, a / det
        # conic = (cc, -b, a) / det with a, b, cc and det built from T = A diag(s), A = J V R, as
        # in _cov2d: differentiate that form (what autograd does in the twin). The textbook chain
        # -Q dL Q through J V M M^T V^T J^T cancels catastrophically for a needle Gaussian.
        g0, g1, g2 = buf[_LGCON * _PL + ln], buf[(_LGCON + 1) * _PL + ln], buf[(_LGCON + 2) * _PL + ln]
        gD = -(g0 * Qa + g1 * Qb + g2 * Qc) / det  # dL/d det
        gP = g2 / det + EPS2D * gD  # dL/d sum_k T0k^2 (directly and through det's dilation term)
        gQ = -g1 / det  # dL/d sum_k T0k T1k
        gS = g0 / det + EPS2D * gD  # dL/d sum_k T1k^2
        VR = _mm(Vt, R)
        A00, A01, A02 = j00 * VR[0] + j02 * VR[6], j00 * VR[1] + j02 * VR[7], j00 * VR[2] + j02 * VR[8]
        A10, A11, A12 = j11 * VR[3] + j12 * VR[6], j11 * VR[4] + j12 * VR[7], j11 * VR[5] + j12 * VR[8]
        # Through a, b, cc: dL/dT0k = 2 T0k gP + T1k gQ, dL/dT1k = 2 T1k gS + T0k gQ; T = A diag(s).
        t00, t01, t02, t10, t11, t12 = A00 * s0, A01 * s1, A02 * s2, A10 * s0, A11 * s1, A12 * s2
        d00, d01, d02 = _TWO * t00 * gP + t10 * gQ, _TWO * t01 * gP + t11 * gQ, _TWO * t02 * gP + t12 * gQ
        d10, d11, d12 = _TWO * t10 * gS + t00 * gQ, _TWO * t11 * gS + t01 * gQ, _TWO * t12 * gS + t02 * gQ
        gA00, gA01, gA02 = d00 * s0, d01 * s1, d02 * s2
        gA10, gA11, gA12 = d10 * s0, d11 * s1, d12 * s2
        gs0, gs1, gs2 = d00 * A00 + d10 * A10, d01 * A01 + d11 * A11, d02 * A02 + d12 * A12
        # Through det's minors m_ij = u_ij s_i s_j, u_ij = A0i A1j - A0j A1i (dL/dm_ij = 2 m_ij gD).
        dsi, dsj, du = _minor_grad(A00, A01, A10, A11, s0, s1, gD)  # minor (0, 1)
        gs0, gs1 = gs0 + dsi, gs1 + dsj
        gA00, gA11, gA01, gA10 = gA00 + du * A11, gA11 + du * A00, gA01 - du * A10, gA10 - du * A01
        dsi, dsj, du = _minor_grad(A00, A02, A10, A12, s0, s2, gD)  # minor (0, 2)
        gs0, gs2 = gs0 + dsi, gs2 + dsj
        gA00, gA12, gA02, gA10 = gA00 + du * A12, gA12 + du * A00, gA02 - du * A10, gA10 - du * A02
        dsi, dsj, du = _minor_grad(A01, A02, A11, A12, s1, s2, gD)  # minor (1, 2)
        gs1, gs2 = gs1 + dsi, gs2 + dsj
        gA01, gA12, gA02, gA11 = gA01 + du * A12, gA12 + du * A01, gA02 - du * A11, gA11 - du * A02
        buf[_LOS * _PL + ln] = _sat(gs0)
        buf[(_LOS + 1) * _PL + ln] = _sat(gs1)
        buf[(_LOS + 2) * _PL + ln] = _sat(gs2)
        # A = J (V R) with J = [[j00, 0, j02], [0, j11, j12]].
        gj00 = gA00 * VR[0] + gA01 * VR[1] + gA02 * VR[2]
        gj02 = gA00 * VR[6] + gA01 * VR[7] + gA02 * VR[8]
        gj11 = gA10 * VR[3] + gA11 * VR[4] + gA12 * VR[5]
        gj12 = gA10 * VR[6] + gA11 * VR[7] + gA12 * VR[8]
        gVR = (j00 * gA00, j00 * gA01, j00 * gA02,
               j11 * gA10, j11 * gA11, j11 * gA12,
               j02 * gA00 + j12 * gA10, j02 * gA01 + j12 * gA11, j02 * gA02 + j12 * gA12)
        gR = _mm(_tr(Vt), gVR)
        w, qx, qy, qz = qn
        gw = _TWO * (-qz * gR[1] + qy * gR[2] + qz * gR[3] - qx * gR[5] - qy * gR[6] + qx * gR[7])
        gx = _TWO * (qy * gR[1] + qz * gR[2] + qy * gR[3] - _TWO * qx * gR[4] - w * gR[5] + qz * gR[6]
                     + w * gR[7] - _TWO * qx * gR[8])
        gy = _TWO * (-_TWO * qy * gR[0] + qx * gR[1] + w * gR[2] + qx * gR[3] + qz * gR[5] - w * gR[6]
                     + qz * gR[7] - _TWO * qy * gR[8])
        gz = _TWO * (-_TWO * qz * gR[0] - w * gR[1] + qx * gR[2] + w * gR[3] - _TWO * qz * gR[4]
                     + qy * gR[5] + qx * gR[6] + qy * gR[7])
        # q_hat = q / |q|: dq = (dq_hat - q_hat (q_hat . dq_hat)) / |q|; zero for the identity fallback.
        dot = w * gw + qx * gx + qy * gy + qz * gz
        buf[_LOQ * _PL + ln] = _sat((gw - w * dot) * qinv)
        buf[(_LOQ + 1) * _PL + ln] = _sat((gx - qx * dot) * qinv)
        buf[(_LOQ + 2) * _PL + ln] = _sat((gy - qy * dot) * qinv)
        buf[(_LOQ + 3) * _PL + ln] = _sat((gz - qz * dot) * qinv)
        # J entries -> camera point; the clamp passes gradient only inside its range (as torch.clamp).
        gmx, gmy = buf[_LGM2 * _PL + ln], buf[(_LGM2 + 1) * _PL + ln]
        g_ux = -fx / z * gj02
        g_uy = -fy / z * gj12
        zz = z * z
        g_cz = (buf[_LGZ * _PL + ln] - fx / zz * gj00 + fx * ux / zz * gj02 - fy / zz * gj11 + fy * uy / zz * gj12
                - fx * x / zz * gmx - fy * y / zz * gmy)
        g_cx = fx / z * gmx
        g_cy = fy / z * gmy
        in_x = -lim_xn <= rx and rx <= lim_xp
        g_cx = g_cx + g_ux / z if in_x else g_cx
        g_cz = g_cz - g_ux * x / zz if in_x else g_cz
        in_y = -lim_yn <= ry and ry <= lim_yp
        g_cy = g_cy + g_uy / z if in_y else g_cy
        g_cz = g_cz - g_uy * y / zz if in_y else g_cz
        for k in range(3):
            buf[(_LOM + k) * _PL + ln] = _sat(Vt[k] * g_cx + Vt[3 + k] * g_cy + Vt[6 + k] * g_cz)


@njit(parallel=True, cache=True, error_model="numpy")
def _project_backward(
    means: np.ndarray,  # [N, 3] f32
    quats: np.ndarray,  # [N, 4]
    scales: np.ndarray,  # [N, 3]
    V: np.ndarray,  # [3, 3]
    tvec: np.ndarray,  # [3]
    intr: np.ndarray,  # [4]
    width: int,
    height: int,
    reason: np.ndarray,  # [N] i8
    g_m2: np.ndarray,  # [N, 2] dL/d means2d
    g_con: np.ndarray,  # [N, 3] dL/d conic (a, b, c)
    g_z: np.ndarray,  # [N] dL/d depth
    g_means: np.ndarray,  # out [N, 3]
    g_quats: np.ndarray,  # out [N, 4]
    g_scales: np.ndarray,  # out [N, 3]
) -> None:
    """Gradients of the 3D parameters from those of the projection's outputs (zero for culled
    Gaussians); lane loops as in :func:`_project_kernel`."""
    Vt, tv, intr4, lims = _camera_tuples(V, tvec, intr, float(width), float(height))
    n = means.shape[0]
    for item in prange((n + _PROJ_CHUNK - 1) // _PROJ_CHUNK):
        buf = np.empty(_NLB * _PL)
        for g0 in range(item * _PROJ_CHUNK, min(n, (item + 1) * _PROJ_CHUNK), _PL):
            nl = min(_PL, n - g0)
            for ln in range(_PL):
                i = g0 + min(ln, nl - 1)  # a short last group repeats its last Gaussian
                _load_gaussian(buf, ln, means, quats, scales, i)
                for k in range(2):
                    buf[(_LGM2 + k) * _PL + ln] = g_m2[i, k]
                for k in range(3):
                    buf[(_LGCON + k) * _PL + ln] = g_con[i, k]
                buf[_LGZ * _PL + ln] = g_z[i]
            _project_backward_lanes(buf, Vt, tv, intr4, lims)
            for ln in range(nl):
                i = g0 + ln
                culled = reason[i] != 0
                for k in range(3):
                    g_means[i, k] = _ZERO if culled else buf[(_LOM + k) * _PL + ln]
                    g_scales[i, k] = _ZERO if culled else buf[(_LOS + k) * _PL + ln]
                for k in range(4):
                    g_quats[i, k] = _ZERO if culled else buf[(_LOQ + k) * _PL + ln]


# ---------------------------------------------------------------------------------------------------
# Binning
# ---------------------------------------------------------------------------------------------------

_RADIX_BITS = 11
_RADIX = 1 << _RADIX_BITS


#: Below this many keys a sort or compaction runs as one chunk (a parallel region costs ~10 us).
_MIN_CHUNK = 16384


def _n_chunks(n: int) -> int:
    """Chunks of a chunked parallel pass over ``n`` items: one per thread, one for small ``n``.

    Results never depend on it (every chunked pass here writes the same output for any count).
    """
    return max(1, min(numba.get_num_threads(), n // _MIN_CHUNK))


@njit(parallel=True, cache=True, error_model="numpy")
def _radix_sort(keys: np.ndarray, idx: np.ndarray, n_chunks: int) -> np.ndarray:
    """Stable ascending sort of uint32 ``keys`` [M] carrying int64 ``idx`` [M]; returns idx sorted.

    LSD radix in three 11-bit passes. Each pass counts digits per chunk of the input in parallel,
    takes exclusive prefix sums over (digit, chunk) (2048 x chunks, serial and tiny), then each
    chunk scatters its keys in input order at its own cursors: the output is the stable order
    whatever the chunk count. ``keys`` is overwritten.
    """
    n = keys.shape[0]
    keys_out = np.empty(n, np.uint32)
    idx_out = np.empty(n, np.int64)
    step = (n + n_chunks - 1) // n_chunks
    hist = np.zeros((n_chunks, _RADIX), np.int64)
    for p in range(3):
        shift = np.uint32(p * _RADIX_BITS)
        for ch in prange(n_chunks):
            for b in range(_RADIX):
                hist[ch, b] = 0
            for i in range(ch * step, min(n, (ch + 1) * step)):
                hist[ch, (keys[i] >> shift) & np.uint32(_RADIX - 1)] += 1
        run = 0
        for b in range(_RADIX):
            for ch in range(n_chunks):
                c = hist[ch, b]
                hist[ch, b] = run
                run += c
        for ch in prange(n_chunks):
            for i in range(ch * step, min(n, (ch + 1) * step)):
                d = (keys[i] >> shift) & np.uint32(_RADIX - 1)
                pos = hist[ch, d]
                hist[ch, d] = pos + 1
                keys_out[pos] = keys[i]
                idx_out[pos] = idx[i]
        keys, keys_out = keys_out, keys
        idx, idx_out = idx_out, idx
    return idx


def depth_order(bits: np.ndarray) -> np.ndarray:
    """Stable ascending order [M] (int64 positions) of uint32 keys [M] (:func:`_radix_sort`).

    Positive float32 depths sort like their bits, and a stable sort keeps ties in index order, so
    ``vis[depth_order(depths[vis].view(uint32))]`` is the (depth, index) order a sort of packed 64-bit
    keys gives, in about a third of the time (2-core CPU, 150k Gaussians).
    """
    n = bits.shape[0]
    return _radix_sort(np.array(bits, np.uint32), np.arange(n, dtype=np.int64), _n_chunks(n))


@njit(parallel=True, cache=True, error_model="numpy")
def _visible_keys(reason: np.ndarray, depth: np.ndarray, n_chunks: int) -> tuple:
    """Indices [M] int64 of the visible Gaussians (``reason == 0``) in index order, their depth
    bits [M] uint32, and the count of each cull reason [n_reasons] (chunked: per-chunk counts, a
    prefix sum, then each chunk writes at its offset)."""
    n = reason.shape[0]
    n_reasons = CULL_OFFSCREEN + 1
    step = (n + n_chunks - 1) // n_chunks
    # Each chunk counts into its own 128-byte row (rows in one cache line made the two threads'
    # increments bounce that line between cores: 2 threads ran slower than 1), and the visible
    # count, nearly every Gaussian, in a register rather than through memory.
    hist = np.zeros((n_chunks, max(16, n_reasons)), np.int64)
    for ch in prange(n_chunks):
        n_vis = 0
        for i in range(ch * step, min(n, (ch + 1) * step)):
            r = reason[i]
            if r == 0:
                n_vis += 1
            else:
                hist[ch, r] += 1
        hist[ch, 0] = n_vis
    offs = np.zeros(n_chunks + 1, np.int64)
    for ch in range(n_chunks):
        offs[ch + 1] = offs[ch] + hist[ch, 0]
    m = offs[n_chunks]
    vis = np.empty(m, np.int64)
    bits = np.empty(m, np.uint32)
    dbits = depth.view(np.uint32)
    for ch in prange(n_chunks):
        k = offs[ch]
        for i in range(ch * step, min(n, (ch + 1) * step)):
            if reason[i] == 0:
                vis[k] = i
                bits[k] = dbits[i]
                k += 1
    return vis, bits, hist[:, :n_reasons].sum(axis=0)


@njit(parallel=True, cache=True, error_model="numpy")
def _tile_counts(
    order: np.ndarray,  # [M] i64 Gaussian index per sorted position
    rec: np.ndarray,  # [N, 16] f32 records of the projection, index order
    tiles_x: int,
    pbox: np.ndarray,  # out [M, 4] i32 boxes in depth order
    counts: np.ndarray,  # out [n_chunks, n_tiles] i64 per-chunk tile histograms (zeros on entry)
    per_g: np.ndarray,  # out [M] i64 tiles of each sorted Gaussian
) -> None:
    """Copy the boxes into depth order and count the tiles of each Gaussian and of each chunk of
    the order (the counting sort's first pass).

    The chunks are contiguous runs of the order (``counts.shape[0]`` of them); the caller's
    arrays, not ones made here, since an array made here would be filled by a parallel loop of its
    own, scheduled with the caller's chunk size.
    """
    m = order.shape[0]
    n_chunks = counts.shape[0]
    step = (m + n_chunks - 1) // n_chunks
    for chunk in prange(n_chunks):
        for s in range(chunk * step, min(m, (chunk + 1) * step)):
            if s + 4 * _PREFETCH < m:  # order jumps through the records: fetch ahead
                _prefetch(rec, order[s + 4 * _PREFETCH])
            g = order[s]
            for q in range(4):
                pbox[s, q] = np.int32(rec[g, _BX + q])
            tx0, tx1 = pbox[s, 0] >> _TS_SHIFT, pbox[s, 1] >> _TS_SHIFT
            ty0, ty1 = pbox[s, 2] >> _TS_SHIFT, pbox[s, 3] >> _TS_SHIFT
            per_g[s] = (tx1 - tx0 + 1) * (ty1 - ty0 + 1)
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    counts[chunk, ty * tiles_x + tx] += 1


@njit(parallel=True, cache=True, error_model="numpy")
def _tile_offsets(counts: np.ndarray) -> tuple:
    """From per-chunk tile histograms [n_chunks, n_tiles]: each tile's first entry [n_tiles + 1], each
    chunk's first slot in each tile [n_chunks, n_tiles] and each chunk's first entry in Gaussian-major
    order [n_chunks] (the prefix sums of the counting sort; parallel over tiles, one short serial scan)."""
    n_chunks, n_tiles = counts.shape
    tile_start = np.zeros(n_tiles + 1, np.int64)
    cursor0 = np.empty((n_chunks, n_tiles), np.int64)
    for t in prange(n_tiles):
        run = 0
        for ch in range(n_chunks):
            cursor0[ch, t] = run
            run += counts[ch, t]
        tile_start[t + 1] = run
    for t in range(n_tiles):
        tile_start[t + 1] += tile_start[t]
    for t in prange(n_tiles):
        for ch in range(n_chunks):
            cursor0[ch, t] += tile_start[t]
    per_chunk = np.empty(n_chunks, np.int64)
    for ch in prange(n_chunks):
        per_chunk[ch] = counts[ch].sum()
    chunk_base = np.zeros(n_chunks, np.int64)
    for ch in range(1, n_chunks):
        chunk_base[ch] = chunk_base[ch - 1] + per_chunk[ch - 1]
    return tile_start, cursor0, chunk_base


@njit(parallel=True, cache=True, error_model="numpy")
def _tile_fill(
    order: np.ndarray, pbox: np.ndarray, tiles_x: int, cursor0: np.ndarray, chunk_base: np.ndarray, goff: np.ndarray,
    tile_ids: np.ndarray, entry_pos: np.ndarray,
) -> None:
    """Counting-sort scatter: each chunk writes the indices of its Gaussians (``order``'s, whose
    boxes ``pbox`` [M, 4] follows, in depth order) at its own cursors.

    ``chunk_base[ch]`` is the number of entries of the chunks before ``ch``: each chunk runs its part
    of the exclusive prefix sum ``goff`` (first entry of each Gaussian, Gaussian-major) itself, and
    writes ``entry_pos`` [E] (the tile-list position of each Gaussian-major entry) in order: the
    backward's gradient rows, written per tile, are summed per Gaussian through it.
    """
    m = pbox.shape[0]
    n_chunks = cursor0.shape[0]
    step = (m + n_chunks - 1) // n_chunks
    half = (n_chunks + 1) // 2
    for item in prange(n_chunks):
        # Items alternate between the first and second half of the chunks: chunks handed out at the
        # same time are then not neighbours, whose ranges of a tile list meet in one cache line.
        ch = item // 2 + (half if item % 2 else 0)
        cur = cursor0[ch].copy()
        e = chunk_base[ch]
        for s in range(ch * step, min(m, (ch + 1) * step)):
            tx0, tx1 = pbox[s, 0] >> _TS_SHIFT, pbox[s, 1] >> _TS_SHIFT
            ty0, ty1 = pbox[s, 2] >> _TS_SHIFT, pbox[s, 3] >> _TS_SHIFT
            goff[s] = e
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    t = ty * tiles_x + tx
                    k = cur[t]
                    if (k & (_I32_PER_LINE - 1)) == 0:
                        # A list's next cache line, fetched for writing as this one starts: the
                        # scatter feeds one stream per tile, more than hardware prefetchers follow.
                        _prefetch_write(tile_ids, k + _I32_PER_LINE)
                    tile_ids[k] = order[s]
                    entry_pos[e] = k
                    cur[t] = k + 1
                    e += 1


# ---------------------------------------------------------------------------------------------------
# Compositing
# ---------------------------------------------------------------------------------------------------
#
# Per tile, pixel (r, j) lives at p = r * TS + j of flat per-tile arrays. The lane loops below are
# inlined with literal lane counts (8 or 16) and channel mode, so LLVM sees constant trip counts and
# emits straight vector code. All float64 per-pixel state sits in one array at constant channel
# offsets (k * TS * TS), so LLVM can prove the accesses independent without runtime alias checks.


@njit(cache=True, inline="always", error_model="numpy")
def _popcount16(x: int) -> int:
    """Number of set bits of a 16-bit mask (SWAR)."""
    x = x - ((x >> 1) & 0x5555)
    x = (x & 0x3333) + ((x >> 2) & 0x3333)
    x = (x + (x >> 4)) & 0x0F0F
    return (x + (x >> 8)) & 0x1F


@njit(cache=True, inline="always", error_model="numpy")
def _window(gx0: int, gx1: int) -> tuple:
    """First lane and lane count of the lanes evaluated for columns [gx0, gx1] of a tile row.

    Boxes up to 8 pixels wide get an 8-lane window (one 256-bit vector of float32) placed at the
    box, clamped inside the tile; wider ones the full 16 lanes.
    """
    half = TS // 2
    if gx1 - gx0 < half:
        return min(gx0, TS - half), half
    return 0, TS


@njit(cache=True, inline="always", error_model="numpy")
def _pixel_sigma(ix: int, hx: np.float32, dy: np.float32, ca: np.float32, cb: np.float32, cc: np.float32) -> tuple:
    """(dx, sigma) of a pixel ``ix`` columns from the Gaussian's anchor pixel: its float32 offset and
    the conic's exponent 0.5 (a dx^2 + c dy^2) + b dx dy."""
    dx = F32(ix) + hx
    return dx, _HALF * (ca * dx * dx + cc * dy * dy) + cb * dx * dy


@njit(cache=True, inline="always", error_model="numpy")
def _entry_box(rec: np.ndarray, s: int, ox: int, oy: int) -> tuple:
    """Gaussian ``s``'s pixel box inside the tile at (ox, oy): first and last row, the mask of its
    columns, and the lanes evaluated (:func:`_window`)."""
    gx0 = max(np.int64(rec[s, _BX]) - ox, 0)
    gx1 = min(np.int64(rec[s, _BX + 1]) - ox, TS - 1)
    gy0 = max(np.int64(rec[s, _BX + 2]) - oy, 0)
    gy1 = min(np.int64(rec[s, _BX + 3]) - oy, TS - 1)
    colmask = np.int32(((1 << (gx1 + 1)) - 1) ^ ((1 << gx0) - 1))
    j0, nl = _window(gx0, gx1)
    return gy0, gy1, colmask, j0, nl


#: Most channels whose color sums are fused into the lane loops (one kernel variant per count);
#: more channels take the separate per-channel loops.
_MAX_FUSED = 16


@njit(cache=True, inline="always", error_model="numpy")
def _entry_colors(rec: np.ndarray, colors: np.ndarray, s: int, nf: int) -> tuple:
    """Gaussian ``s``'s ``nf`` colors as a tuple of float32 (``nf`` a literal; (0.0,) when 0).

    A tuple lives in registers: the lane loops read it without loads that LLVM would have to prove
    apart from the tile buffer's stores. Up to three come from the 64-byte record (already in cache).
    """
    if nf == 0:
        return (_ZERO,)
    if nf <= 3:
        return to_fixed_tuple(rec[s, _COL:_COL + nf], nf)  # type: ignore[call-arg]
    return to_fixed_tuple(colors[s], nf)  # type: ignore[call-arg]


_COLOR_TERMS: dict[int, tuple[Any, Any]] = {}


def _color_terms(nf: int) -> tuple[Any, Any]:
    """The ``add`` and ``dot`` of :func:`_add_colors` and :func:`_dot_colors` written out for ``nf``
    channels, one statement per channel with constant offsets (made once per count).

    A loop over the channels with ``cols[ch]`` would index the tuple at run time, which LLVM neither
    unrolls nor vectorizes (2x slower than separate loops for 15 channels in a standalone timing;
    `bench raster`'s ``b_pandaset_186k_15ch`` times the written-out form). Not cached
    on their own: they are inlined into the cached kernels.
    """
    if nf in _COLOR_TERMS:
        return _COLOR_TERMS[nf]
    if nf == 0:
        @njit(inline="always", error_model="numpy")
        def add(buf: np.ndarray, u: np.uint64, w: float, cols: tuple) -> None:
            pass

        @njit(inline="always", error_model="numpy")
        def dot(S: np.ndarray, u: np.uint64, cols: tuple, acc: float) -> float:
            return acc
    else:
        prev_add, prev_dot = _color_terms(nf - 1)
        ch = nf - 1
        fwd_off = np.uint64((_FC + ch) * TS * TS)
        bwd_off = np.uint64(_UGC + ch * TS * TS)

        @njit(inline="always", error_model="numpy")
        def add(buf: np.ndarray, u: np.uint64, w: float, cols: tuple) -> None:
            prev_add(buf, u, w, cols)
            buf[fwd_off + u] += w * np.float64(cols[ch])

        @njit(inline="always", error_model="numpy")
        def dot(S: np.ndarray, u: np.uint64, cols: tuple, acc: float) -> float:
            return prev_dot(S, u, cols, acc) + np.float64(cols[ch]) * S[bwd_off + u]
    _COLOR_TERMS[nf] = (add, dot)
    return add, dot


def _add_colors(buf: np.ndarray, u: np.uint64, w: float, cols: tuple) -> None:
    """buf[(_FC + ch) TS^2 + u] += w cols[ch] for every channel of ``cols`` (forward).

    This Python body is the plain reference; jitted code gets the written-out overload below.
    """
    for ch, c in enumerate(cols):
        buf[np.uint64((_FC + ch) * TS * TS) + np.uint64(u)] += w * np.float64(c)


def _dot_colors(S: np.ndarray, u: np.uint64, cols: tuple, acc: float) -> float:
    """acc + the sum over channels, in order, of cols[ch] dL/dC_ch at u (backward).

    This Python body is the plain reference; jitted code gets the written-out overload below.
    """
    for ch, c in enumerate(cols):
        acc = acc + np.float64(c) * S[np.uint64(_UGC + ch * TS * TS) + np.uint64(u)]
    return acc


# Overloads chosen by the tuple's length at typing time: the kernels name these module functions,
# not per-count closures, so their cache key (bytecode and closure values) stays the same from one
# process to the next and numba's disk cache hits.
@overload(_add_colors, inline="always")
def _add_colors_typed(buf: Any, u: Any, w: Any, cols: Any) -> Any:
    add = _color_terms(len(cols))[0]

    def impl(buf: Any, u: Any, w: Any, cols: Any) -> None:  # same annotations as the typing function
        add(buf, u, w, cols)

    return impl


@overload(_dot_colors, inline="always")
def _dot_colors_typed(S: Any, u: Any, cols: Any, acc: Any) -> Any:
    dot = _color_terms(len(cols))[1]

    def impl(S: Any, u: Any, cols: Any, acc: Any) -> Any:  # same annotations as the typing function
        return dot(S, u, cols, acc)

    return impl


#: Channels of the per-tile float64 buffer of the forward, each TS * TS long (pixel p = r * TS + j):
#: transmittance, sum w, sum w z, a scratch row of weights, then the C color sums. Every access
#: of the lane loops is then base + constant + lane, so LLVM sees that they never overlap and
#: vectorizes without runtime alias checks (which it refuses to emit for these loops).
_FT, _FW, _FD, _FB, _FC = 0, 1, 2, 3, 4


@njit(cache=True, inline="always", error_model="numpy")
def _fwd_entry(
    nl: int, j0: int, gy0: int, gy1: int, ox: int, oy: int, colmask: np.int32, rec: np.ndarray, s: int,
    rowbits: np.ndarray, buf: np.ndarray, colors: np.ndarray, nf: int, with_depth: bool,
) -> tuple:
    """Composite Gaussian ``s`` into rows gy0..gy1, lanes j0..j0+nl of a tile at (ox, oy).

    ``buf`` is the tile's float64 state (channels ``_FT`` ...). With ``nf`` = C (1 to
    ``_MAX_FUSED`` channels) the color sums are fused into the lane loop; with ``nf`` = 0 they run
    as separate loops over the weight scratch row. ``rowbits[r]`` has bit j set for pixels that
    have stopped. Returns (pixels that stopped, pairs evaluated). Per-pair math is float32,
    transmittance and sums float64.

    ``nl`` and ``nf`` are literals at each call site, so after inlining the lane loop has a
    constant trip count, and :func:`_add_colors` writes each channel at a
    constant offset; indices are unsigned, so numba drops its negative-index wraparound and
    addresses are affine in the lane counter.
    """
    n_ch = colors.shape[1]
    npx = TS * TS
    ax, hx, hy = np.int64(rec[s, _AX]), rec[s, _HX], rec[s, _HY]
    ay = np.int64(rec[s, _AY])
    ca, cb, cc, o = rec[s, _CA], rec[s, _CB], rec[s, _CC], rec[s, _OP]
    z64 = np.float64(rec[s, _Z])
    cols = _entry_colors(rec, colors, s, nf)
    n_done = 0
    pairs = 0
    for r in range(gy0, gy1 + 1):
        db = rowbits[r]
        live = colmask & ~db
        if live == 0:
            continue  # every pixel of the box in this row has stopped
        p0 = r * TS + j0
        u0 = np.uint64(p0)
        dy = F32(oy + r - ay) + hy
        stopbits = np.int32(0)
        for jj in range(nl):
            u = u0 + np.uint64(jj)
            j = j0 + jj
            _, sigma = _pixel_sigma(ox + j - ax, hx, dy, ca, cb, cc)
            alpha = min(_ALPHA_MAX, o * _fexp(-sigma))
            use = (((live >> j) & 1) != 0) & (sigma >= _ZERO) & (alpha >= _ALPHA_MIN)
            tj = buf[u]
            a64 = np.float64(alpha)
            test = tj * (1.0 - a64)
            stop = use & (test < T_STOP)
            use = use & (test >= T_STOP)
            w = a64 * tj if use else 0.0
            buf[u] = test if use else tj
            buf[np.uint64(_FW * npx) + u] += w
            if with_depth:
                buf[np.uint64(_FD * npx) + u] += w * z64
            if nf:
                _add_colors(buf, u, w, cols)
            else:
                buf[np.uint64(_FB * npx) + u] = w
            stopbits |= np.int32(stop) << np.int32(j)
        if not nf:
            for ch in range(n_ch):
                col = np.float64(colors[s, ch])
                uc = np.uint64((_FC + ch) * npx + p0)
                ub = np.uint64(_FB * npx + p0)
                for jj in range(nl):
                    buf[uc + np.uint64(jj)] += buf[ub + np.uint64(jj)] * col
        rowbits[r] = db | stopbits
        n_done += _popcount16(stopbits)
        pairs += _popcount16(live)
    return n_done, pairs


def _make_render_forward(nf: int, render_depth: bool) -> Any:
    """Compile-on-demand variant of the kernel for fixed flags.

    ``nf``: C (at most ``_MAX_FUSED``), the color sums fused into the lane loop, or 0 (separate
    loops); ``render_depth``: accumulate sum w z.

    The flags are closure constants: numba freezes them, LLVM drops the dead variants, and
    each variant is compiled (and cached) only when first used.
    """

    @njit(parallel=True, cache=True, error_model="numpy")
    def kernel(
        tile_start: np.ndarray,  # [n_tiles + 1] i64
        tile_ids: np.ndarray,  # [E] i32 Gaussian index per entry (depth order within a tile)
        tile_order: np.ndarray,  # [n_tiles] i64, the order tiles are handed out in
        rec: np.ndarray,  # [N, 16] f32 records (index order)
        colors: np.ndarray,  # [N, C] f32 (read for C > 3; the records hold up to three)
        width: int,
        height: int,
        tiles_x: int,
        acc_img: np.ndarray,  # out [H, W, C + 2] f64: sum w c, sum w (alpha), sum w z
        color: np.ndarray,  # out [H, W, C] f32
        alpha: np.ndarray,  # out [H, W] f32
        dnum: np.ndarray,  # out [H, W] f32 (untouched if not render_depth)
        tile_end: np.ndarray,  # out [n_tiles] i64: the entry where every pixel of the tile had stopped
        tile_pairs: np.ndarray,  # out [n_tiles] i64: pairs evaluated
    ) -> None:
        n_ch = colors.shape[1]
        npx = TS * TS
        for it in prange(tile_order.shape[0]):
            t = tile_order[it]
            ox = (t % tiles_x) * TS
            oy = (t // tiles_x) * TS
            buf = np.zeros((_FC + n_ch) * npx)
            buf[:npx] = 1.0  # transmittance
            rowbits = np.zeros(TS, np.int32)  # bit j set: pixel (r, j) is done
            n_done = 0
            # Pixels beyond the image border start "done" so that early termination still fires.
            for r in range(TS):
                for j in range(TS):
                    if oy + r >= height or ox + j >= width:
                        rowbits[r] |= np.int32(1 << j)
                        n_done += 1
            pairs = 0
            start = tile_start[t]
            end = tile_start[t + 1]
            k_end = end
            for k in range(start, end):
                if n_done == npx:
                    k_end = k
                    break
                if k + _PREFETCH < end:
                    _prefetch(rec, tile_ids[k + _PREFETCH])
                    if nf == 0 or nf > 3:
                        _prefetch(colors, tile_ids[k + _PREFETCH])
                s = tile_ids[k]
                gy0, gy1, colmask, j0, nl = _entry_box(rec, s, ox, oy)
                if nl == TS:
                    nd, pc = _fwd_entry(TS, 0, gy0, gy1, ox, oy, colmask, rec, s, rowbits, buf, colors, nf,
                                        render_depth)
                else:
                    nd, pc = _fwd_entry(TS // 2, j0, gy0, gy1, ox, oy, colmask, rec, s, rowbits, buf, colors, nf,
                                        render_depth)
                n_done += nd
                pairs += pc
            tile_end[t] = k_end
            tile_pairs[t] = pairs
            for r in range(min(TS, height - oy)):
                for j in range(min(TS, width - ox)):
                    y, x, p = oy + r, ox + j, r * TS + j
                    for ch in range(n_ch):
                        v = buf[(_FC + ch) * npx + p]
                        acc_img[y, x, ch] = v
                        color[y, x, ch] = F32(v)
                    acc_img[y, x, n_ch] = buf[_FW * npx + p]
                    alpha[y, x] = F32(buf[_FW * npx + p])
                    acc_img[y, x, n_ch + 1] = buf[_FD * npx + p]
                    if render_depth:
                        dnum[y, x] = F32(buf[_FD * npx + p])


    return kernel


# ---------------------------------------------------------------------------------------------------
# Inference-only compositing (rendering a trained model: no gradients)
# ---------------------------------------------------------------------------------------------------
#
# The training forward keeps float64 transmittance and sums and writes them per pixel (``acc_img``)
# for its backward. A render needs neither: ``_make_render_image`` composites the same tile lists
# in the same front-to-back order with the same per-pair float32 math, but keeps the per-tile state
# in float32 (twice the lanes per vector, half the bytes) and writes only the image. Its pixels
# stop at the same T_STOP, decided on the float32 transmittance, so a pixel whose float64
# transmittance sits within rounding of 1e-4 may take one pair more or fewer: that pair weighs less
# than 1e-4 (docs/design.md §8). A caller that reads only the front surface may stop sooner (the
# ``stop`` of ``RenderJob.image``: the physical editor's surface maps, docs/design.md §7), after
# the pair that takes the transmittance below it, so what it leaves out weighs less than the stop.

#: Planes (TS * TS float32 each, pixel p = r * TS + j) of the per-tile buffer of the image kernel:
#: transmittance, sum w (alpha: ``1 - T`` would lose its relative precision at low alpha, where
#: the expected depth divides by it), sum w z, then the C color sums (constant offsets, as ``_FT``
#: ... of the forward).
_IT, _IW, _ID, _IC = 0, 1, 2, 3
_T_STOP32 = F32(T_STOP)

_IMAGE_TERMS: dict[int, Any] = {}


def _image_color_terms(nf: int) -> Any:
    """``add`` of :func:`_add_colors32` written out for ``nf`` channels, one float32 statement per
    channel at a constant offset (made once per count, as :func:`_color_terms`)."""
    if nf in _IMAGE_TERMS:
        return _IMAGE_TERMS[nf]
    if nf == 0:
        @njit(inline="always", error_model="numpy")
        def add(buf: np.ndarray, u: np.uint64, w: np.float32, cols: tuple) -> None:
            pass
    else:
        prev_add = _image_color_terms(nf - 1)
        ch = nf - 1
        off = np.uint64((_IC + ch) * TS * TS)

        @njit(inline="always", error_model="numpy")
        def add(buf: np.ndarray, u: np.uint64, w: np.float32, cols: tuple) -> None:
            prev_add(buf, u, w, cols)
            buf[off + u] += w * cols[ch]
    _IMAGE_TERMS[nf] = add
    return add


def _add_colors32(buf: np.ndarray, u: np.uint64, w: np.float32, cols: tuple) -> None:
    """buf[(_IC + ch) TS^2 + u] += w cols[ch] in float32 for every channel of ``cols`` (image kernel).

    This Python body is the plain reference; jitted code gets the written-out overload below.
    """
    for ch, c in enumerate(cols):
        buf[np.uint64((_IC + ch) * TS * TS) + np.uint64(u)] += w * c


@overload(_add_colors32, inline="always")
def _add_colors32_typed(buf: Any, u: Any, w: Any, cols: Any) -> Any:
    add = _image_color_terms(len(cols))

    def impl(buf: Any, u: Any, w: Any, cols: Any) -> None:  # same annotations as the typing function
        add(buf, u, w, cols)

    return impl


@njit(cache=True, inline="always", error_model="numpy")
def _image_entry(
    nl: int, j0: int, gy0: int, gy1: int, ox: int, oy: int, colmask: np.int32, rec: np.ndarray, s: int,
    rowbits: np.ndarray, buf: np.ndarray, colors: np.ndarray, nf: int, with_depth: bool, t_stop: np.float32,
) -> tuple:
    """:func:`_fwd_entry` for the image kernel: Gaussian ``s`` composited into rows gy0..gy1, lanes
    j0..j0+nl of a tile, with float32 state in ``buf`` (planes ``_IT`` ...) and the ``nf`` color
    sums fused (``nf`` >= 1); a pixel stops before its transmittance falls below ``T_STOP`` (the
    pair that would take it there dropped, as the training's forward) or once it has fallen below
    ``t_stop`` (that pair kept). Returns (pixels that stopped, pairs evaluated)."""
    ax, hx, hy = np.int64(rec[s, _AX]), rec[s, _HX], rec[s, _HY]
    ay = np.int64(rec[s, _AY])
    ca, cb, cc, o = rec[s, _CA], rec[s, _CB], rec[s, _CC], rec[s, _OP]
    z = rec[s, _Z]
    cols = _entry_colors(rec, colors, s, nf)
    n_done = 0
    pairs = 0
    for r in range(gy0, gy1 + 1):
        db = rowbits[r]
        live = colmask & ~db
        if live == 0:
            continue  # every pixel of the box in this row has stopped
        u0 = np.uint64(r * TS + j0)
        dy = F32(oy + r - ay) + hy
        stopbits = np.int32(0)
        for jj in range(nl):
            u = u0 + np.uint64(jj)
            j = j0 + jj
            _, sigma = _pixel_sigma(ox + j - ax, hx, dy, ca, cb, cc)
            alpha = min(_ALPHA_MAX, o * _fexp(-sigma))
            use = (((live >> j) & 1) != 0) & (sigma >= _ZERO) & (alpha >= _ALPHA_MIN)
            tj = buf[u]
            test = tj * (_ONE - alpha)
            stop = use & (test < _T_STOP32)
            use = use & (test >= _T_STOP32)
            # a caller's sooner stop keeps the pair that takes T below it (what it drops weighs
            # less than the stop); at T_STOP (the default) it never fires
            stop = stop | (use & (test < t_stop))
            w = alpha * tj if use else _ZERO
            buf[u] = test if use else tj
            buf[np.uint64(_IW * TS * TS) + u] += w
            if with_depth:
                buf[np.uint64(_ID * TS * TS) + u] += w * z
            _add_colors32(buf, u, w, cols)
            stopbits |= np.int32(stop) << np.int32(j)
        rowbits[r] = db | stopbits
        n_done += _popcount16(stopbits)
        pairs += _popcount16(live)
    return n_done, pairs


def _make_render_image(nf: int, render_depth: bool) -> Any:
    """Compile-on-demand image kernel (no backward state) for ``nf`` = C fused channels (1 to
    ``_MAX_FUSED``) and ``render_depth``; the flags are closure constants, as in
    :func:`_make_render_forward`."""

    @njit(parallel=True, cache=True, error_model="numpy")
    def kernel(
        tile_start: np.ndarray,  # [n_tiles + 1] i64
        tile_ids: np.ndarray,  # [E] i32 Gaussian index per entry (depth order within a tile)
        tile_order: np.ndarray,  # [n_tiles] i64, the order tiles are handed out in
        rec: np.ndarray,  # [N, 16] f32 records (index order)
        colors: np.ndarray,  # [N, C] f32 (read for C > 3; the records hold up to three)
        width: int,
        height: int,
        tiles_x: int,
        color: np.ndarray,  # out [H, W, C] f32: sum w c
        alpha: np.ndarray,  # out [H, W] f32: sum w
        dnum: np.ndarray,  # out [H, W] f32: sum w z (untouched if not render_depth)
        tile_pairs: np.ndarray,  # out [n_tiles] i64: pairs evaluated
        t_stop: np.float32,  # a pixel stops once its transmittance falls below this (that pair kept)
    ) -> None:
        n_ch = colors.shape[1]
        npx = TS * TS
        for it in prange(tile_order.shape[0]):
            t = tile_order[it]
            ox = (t % tiles_x) * TS
            oy = (t // tiles_x) * TS
            buf = np.zeros((_IC + n_ch) * npx, np.float32)
            buf[:npx] = _ONE  # transmittance
            rowbits = np.zeros(TS, np.int32)  # bit j set: pixel (r, j) is done
            n_done = 0
            # Pixels beyond the image border start "done" so that early termination still fires.
            for r in range(TS):
                for j in range(TS):
                    if oy + r >= height or ox + j >= width:
                        rowbits[r] |= np.int32(1 << j)
                        n_done += 1
            pairs = 0
            end = tile_start[t + 1]
            for k in range(tile_start[t], end):
                if n_done == npx:
                    break  # every pixel of the tile has stopped
                if k + _PREFETCH < end:
                    _prefetch(rec, tile_ids[k + _PREFETCH])
                    if nf > 3:
                        _prefetch(colors, tile_ids[k + _PREFETCH])
                s = tile_ids[k]
                gy0, gy1, colmask, j0, nl = _entry_box(rec, s, ox, oy)
                if nl == TS:
                    nd, pc = _image_entry(TS, 0, gy0, gy1, ox, oy, colmask, rec, s, rowbits, buf, colors, nf,
                                          render_depth, t_stop)
                else:
                    nd, pc = _image_entry(TS // 2, j0, gy0, gy1, ox, oy, colmask, rec, s, rowbits, buf, colors,
                                          nf, render_depth, t_stop)
                n_done += nd
                pairs += pc
            tile_pairs[t] = pairs
            for r in range(min(TS, height - oy)):
                for j in range(min(TS, width - ox)):
                    y, x, p = oy + r, ox + j, r * TS + j
                    for ch in range(n_ch):
                        color[y, x, ch] = buf[(_IC + ch) * npx + p]
                    alpha[y, x] = buf[_IW * npx + p]
                    if render_depth:
                        dnum[y, x] = buf[_ID * npx + p]

    return kernel


_NQ = 9  # per-entry gradient slots before the colors: mx, my, |mx|, |my|, conic a, b, c, opacity, z
#: Planes (TS * TS float64 each, pixel p = r * TS + j) of the per-tile buffer of the backward:
#: transmittance, running sum of w f, forward total F, dL/dA, dL/dD, a scratch plane (f without
#: fused colors), the weight w of the pair (0 where unused); then one plane per gradient slot (9),
#: then dL/dC per color. Every access of the lane loop is then base + constant + lane, so LLVM
#: vectorizes it without runtime alias checks.
_BT, _BU, _BF, _BA, _BD, _BS1, _BW, _BG = 0, 1, 2, 3, 4, 5, 6, 7
#: The first dL/dC plane.
_UGC = (_BG + _NQ) * TS * TS


@njit(cache=True, inline="always", error_model="numpy")
def _bwd_entry(
    nl: int, j0: int, gy0: int, gy1: int, ox: int, oy: int, colmask: np.int32, rec: np.ndarray, s: int,
    rowbits: np.ndarray, S: np.ndarray, colors: np.ndarray, nf: int, with_depth: bool,
) -> int:
    """Replay Gaussian ``s`` over its rows of a tile and write its per-pixel gradient terms to ``S``.

    The forward's decisions are re-made bit for bit (same ops on the same inputs), so the skip and
    stop pattern is the forward's. With f_i = dL/dA + c_i . dL/dC + z_i dL/dD, the light behind
    pair i is F - (running sum of w f up to i): two float64 sums of the same terms. Each pixel meets
    the Gaussian once, so its gradient terms and its weight are written, not accumulated, into
    their planes (zeros where the pair is unused); the color gradients are the weight's dot
    products with dL/dC (:func:`_entry_sums`). ``nf`` as in :func:`_fwd_entry`. Returns the bit mask
    of the rows visited.
    """
    n_ch = colors.shape[1]
    npx = TS * TS
    ax, hx, hy = np.int64(rec[s, _AX]), rec[s, _HX], rec[s, _HY]
    ay = np.int64(rec[s, _AY])
    ca, cb, cc, o = rec[s, _CA], rec[s, _CB], rec[s, _CC], rec[s, _OP]
    ca64, cb64, cc64 = np.float64(ca), np.float64(cb), np.float64(cc)
    z64 = np.float64(rec[s, _Z])
    cols = _entry_colors(rec, colors, s, nf)
    rows = 0
    for r in range(gy0, gy1 + 1):
        db = rowbits[r]
        live = colmask & ~db
        if live == 0:
            continue
        rows |= 1 << r
        p0 = r * TS + j0
        u0 = np.uint64(p0)
        if not nf:
            # f without the colors' share, then the colors in separate loops.
            for jj in range(nl):
                u = u0 + np.uint64(jj)
                S[np.uint64(_BS1 * npx) + u] = S[np.uint64(_BA * npx) + u] + z64 * S[np.uint64(_BD * npx) + u]
            for ch in range(n_ch):
                col = np.float64(colors[s, ch])
                for jj in range(nl):
                    u = u0 + np.uint64(jj)
                    S[np.uint64(_BS1 * npx) + u] += col * S[np.uint64(_UGC + ch * npx) + u]
        dy = F32(oy + r - ay) + hy
        dy64 = np.float64(dy)
        stopbits = np.int32(0)
        for jj in range(nl):
            u = u0 + np.uint64(jj)
            j = j0 + jj
            dx, sigma = _pixel_sigma(ox + j - ax, hx, dy, ca, cb, cc)
            e = _fexp(-sigma)
            raw = o * e
            alpha = min(_ALPHA_MAX, raw)
            use = (((live >> j) & 1) != 0) & (sigma >= _ZERO) & (alpha >= _ALPHA_MIN)
            tj = S[u]
            a64 = np.float64(alpha)
            test = tj * (1.0 - a64)
            stop = use & (test < T_STOP)
            use = use & (test >= T_STOP)
            w = a64 * tj  # the forward's weight, bit for bit
            if nf:
                f = _dot_colors(S, u, cols, S[np.uint64(_BA * npx) + u])
                if with_depth:
                    f += z64 * S[np.uint64(_BD * npx) + u]
            else:
                f = S[np.uint64(_BS1 * npx) + u]
            fu = S[np.uint64(_BU * npx) + u] + w * f
            # dL/dalpha = T f - (sum of w f behind this pair) / (1 - alpha)
            g_a = tj * f - (S[np.uint64(_BF * npx) + u] - fu) / (1.0 - a64)
            g_a = g_a if use & (raw <= _ALPHA_MAX) else 0.0
            gs = -g_a * a64  # dL/dsigma
            dx64 = np.float64(dx)
            gdx = gs * (ca64 * dx64 + cb64 * dy64)
            gdy = gs * (cc64 * dy64 + cb64 * dx64)
            w_use = w if use else 0.0
            S[np.uint64(_BG * npx) + u] = -gdx
            S[np.uint64((_BG + 1) * npx) + u] = -gdy
            S[np.uint64((_BG + 2) * npx) + u] = abs(gdx)
            S[np.uint64((_BG + 3) * npx) + u] = abs(gdy)
            S[np.uint64((_BG + 4) * npx) + u] = gs * 0.5 * dx64 * dx64
            S[np.uint64((_BG + 5) * npx) + u] = gs * dx64 * dy64
            S[np.uint64((_BG + 6) * npx) + u] = gs * 0.5 * dy64 * dy64
            S[np.uint64((_BG + 7) * npx) + u] = g_a * np.float64(e)
            S[np.uint64((_BG + 8) * npx) + u] = w_use * S[np.uint64(_BD * npx) + u]
            S[np.uint64(_BW * npx) + u] = w_use
            S[np.uint64(_BU * npx) + u] = fu if use else S[np.uint64(_BU * npx) + u]
            S[u] = test if use else tj
            stopbits |= np.int32(stop) << np.int32(j)
        rowbits[r] = db | stopbits
    return rows


def _vec8_ptr(context: Any, builder: Any, aryty: Any, ary_val: Any, off_val: Any, off_ty: Any) -> Any:
    """LLVM pointer to the 8 float64 at flat offset ``off`` of a C-contiguous 1-D array, as <8 x double>*."""
    ary = context.make_array(aryty)(context, builder, ary_val)
    off = context.cast(builder, off_val, off_ty, types.intp)
    return builder.bitcast(builder.gep(ary.data, [off]), ir.VectorType(ir.DoubleType(), 8).as_pointer())


def _acc8_typer(typingctx: Any, arr: Any, acc: Any, u: Any) -> Any:
    """``S[acc:acc + 8] += S[u:u + 8]`` as one 8-lane float64 vector add.

    Written out in LLVM IR because the same sums as eight scalar accumulators compiled to 107
    scalar adds (LLVM cannot tell two ranges of one array apart at run-time offsets; docs/design.md
    §8 has what it changes in a training step). Lane by lane it is the scalar ``S[acc + l] += S[u + l]``.
    """
    sig = types.void(arr, acc, u)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        aryty, accty, uty = signature.args
        pa = _vec8_ptr(context, builder, aryty, args[0], args[1], accty)
        pu = _vec8_ptr(context, builder, aryty, args[0], args[2], uty)
        builder.store(builder.fadd(builder.load(pa, align=8), builder.load(pu, align=8)), pa, align=8)
        return context.get_dummy_value()

    return sig, codegen


_acc8: Any = intrinsic(_acc8_typer)


def _acc8_dot_typer(typingctx: Any, arr: Any, acc: Any, u: Any, v: Any) -> Any:
    """``S[acc:acc + 8] += S[u:u + 8] * S[v:v + 8]`` (a multiply, then an add: no fused rounding),
    one 8-lane float64 vector each (see :func:`_acc8_typer`)."""
    sig = types.void(arr, acc, u, v)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        aryty, accty, uty, vty = signature.args
        pa = _vec8_ptr(context, builder, aryty, args[0], args[1], accty)
        pu = _vec8_ptr(context, builder, aryty, args[0], args[2], uty)
        pv = _vec8_ptr(context, builder, aryty, args[0], args[3], vty)
        prod = builder.fmul(builder.load(pu, align=8), builder.load(pv, align=8))
        builder.store(builder.fadd(builder.load(pa, align=8), prod), pa, align=8)
        return context.get_dummy_value()

    return sig, codegen


_acc8_dot: Any = intrinsic(_acc8_dot_typer)


@njit(cache=True, error_model="numpy")
def _entry_sums(S: np.ndarray, rows: int, gy0: int, gy1: int, j0: int, nl: int, n_ch: int, out: np.ndarray,
                k: int) -> None:
    """out[k] = one entry's gradients: the sums of the ``_NQ`` gradient planes over the visited rows
    and lanes, then per color the dot product of the weight plane with dL/dC there.

    Eight column accumulators per quantity (the 8 float64 after the dL/dC planes of ``S``, one
    vector: :func:`_acc8`) summed down the rows, lanes j0..j0+7 and then, for a 16-lane row,
    j0+8..j0+15, then across in a fixed tree: a fixed order, so the result does not depend on threads.
    """
    npx = TS * TS
    acc = np.uint64(_UGC + n_ch * npx)
    for i in range((_NQ + n_ch) * 8):
        S[acc + np.uint64(i)] = 0.0
    for r in range(gy0, gy1 + 1):
        if (rows >> r) & 1:
            u = np.uint64(r * TS + j0)
            for q in range(_NQ):
                a = acc + np.uint64(q * 8)
                p = np.uint64((_BG + q) * npx) + u
                _acc8(S, a, p)
                if nl == TS:
                    _acc8(S, a, p + np.uint64(8))
            for ch in range(n_ch):
                a = acc + np.uint64((_NQ + ch) * 8)
                w = np.uint64(_BW * npx) + u
                g = np.uint64(_UGC + ch * npx) + u
                _acc8_dot(S, a, w, g)
                if nl == TS:
                    _acc8_dot(S, a, w + np.uint64(8), g + np.uint64(8))
    for q in range(_NQ + n_ch):
        b = acc + np.uint64(q * 8)
        c = (S[b], S[b + np.uint64(1)], S[b + np.uint64(2)], S[b + np.uint64(3)], S[b + np.uint64(4)],
             S[b + np.uint64(5)], S[b + np.uint64(6)], S[b + np.uint64(7)])
        out[k, q] = _sat(((c[0] + c[1]) + (c[2] + c[3])) + ((c[4] + c[5]) + (c[6] + c[7])))


def _make_render_backward(nf: int, render_depth: bool) -> Any:
    """Compile-on-demand variant of the kernel for fixed flags (as :func:`_make_render_forward`).

    The flags are closure constants: numba freezes them, LLVM drops the dead variants, and
    each variant is compiled (and cached) only when first used.
    """

    @njit(parallel=True, cache=True, error_model="numpy")
    def kernel(
        tile_start: np.ndarray,  # [n_tiles + 1]
        tile_ids: np.ndarray,  # [E]
        tile_order: np.ndarray,  # [n_tiles]
        tile_end: np.ndarray,  # [n_tiles] from the forward
        rec: np.ndarray,  # [N, 16] f32 records (index order)
        colors: np.ndarray,  # [N, C] f32
        width: int,
        height: int,
        tiles_x: int,
        acc_img: np.ndarray,  # [H, W, C + 2] f64 forward sums
        g_color: np.ndarray,  # [H, W, C] f32 dL/d(color before background)
        g_alpha: np.ndarray,  # [H, W] f32
        g_dnum: np.ndarray,  # [H, W] f32 dL/d(sum w z)
        entry_grads: np.ndarray,  # out [E, 9 + C] f32 per tile-list entry: mx, my, |mx|, |my|, conic a, b, c,
        #                          opacity, z, colors
    ) -> None:
        n_ch = colors.shape[1]
        npx = TS * TS
        nq = entry_grads.shape[1]
        for it in prange(tile_order.shape[0]):
            t = tile_order[it]
            ox = (t % tiles_x) * TS
            oy = (t // tiles_x) * TS
            start = tile_start[t]
            end = tile_start[t + 1]
            k_end = tile_end[t]
            for k in range(k_end, end):
                for q in range(nq):
                    entry_grads[k, q] = _ZERO  # entries the forward never reached
            if k_end == start:
                continue
            S = np.zeros(_UGC + n_ch * npx + (_NQ + n_ch) * 8)  # planes, then _entry_sums' accumulators
            S[:npx] = 1.0  # transmittance
            rowbits = np.zeros(TS, np.int32)
            for r in range(TS):
                for j in range(TS):
                    y, x, p = oy + r, ox + j, r * TS + j
                    if y >= height or x >= width:
                        rowbits[r] |= np.int32(1 << j)
                        continue
                    ga = np.float64(g_alpha[y, x])
                    S[_BA * npx + p] = ga
                    tot = acc_img[y, x, n_ch] * ga
                    for ch in range(n_ch):
                        gc = np.float64(g_color[y, x, ch])
                        S[_UGC + ch * npx + p] = gc
                        tot += acc_img[y, x, ch] * gc
                    if render_depth:
                        gd = np.float64(g_dnum[y, x])
                        S[_BD * npx + p] = gd
                        tot += acc_img[y, x, n_ch + 1] * gd
                    S[_BF * npx + p] = tot
            for k in range(start, k_end):
                if k + _PREFETCH < k_end:
                    _prefetch(rec, tile_ids[k + _PREFETCH])
                    if nf == 0 or nf > 3:
                        _prefetch(colors, tile_ids[k + _PREFETCH])
                s = tile_ids[k]
                gy0, gy1, colmask, j0, nl = _entry_box(rec, s, ox, oy)
                if nl == TS:
                    rows = _bwd_entry(TS, 0, gy0, gy1, ox, oy, colmask, rec, s, rowbits, S, colors, nf, render_depth)
                else:
                    rows = _bwd_entry(TS // 2, j0, gy0, gy1, ox, oy, colmask, rec, s, rowbits, S, colors, nf,
                                      render_depth)
                _entry_sums(S, rows, gy0, gy1, j0, nl, n_ch, entry_grads, k)

    return kernel


#: How many Gaussians ahead the reduction prefetches rows (random rows of a 17 MB buffer at 480x270;
#: a row of 9 + C float32 spans one to three cache lines). With 8 ahead, the first line of a row
#: only and static shares, `bench raster`'s reduction phase took 5.9 ms at two threads; with 16
#: ahead, every line and items handed out one at a time, 3.8-4.3 ms. The lines its sums go to
#: (six arrays at the Gaussian's index: random writes) are fetched for writing as well.
_REDUCE_PREFETCH = 16


@njit(parallel=True, cache=True, error_model="numpy")
def _reduce_entries(
    order: np.ndarray, goff: np.ndarray, per_g: np.ndarray, entry_pos: np.ndarray, entry_grads: np.ndarray,
    reason: np.ndarray,  # [N] i8: rows of culled Gaussians are set to zero
    g_m2: np.ndarray,  # out [N, 2] f32 dL/d means2d
    g_abs: np.ndarray,  # out [N, 2] f32 absolute 2D gradient (AbsGS)
    g_con: np.ndarray,  # out [N, 3] f32 dL/d conic
    g_op: np.ndarray,  # out [N] f32 dL/d opacity
    g_z: np.ndarray,  # out [N] f32 dL/d depth
    g_col: np.ndarray,  # out [N, C] f32 dL/d colors
) -> None:
    """Sum each Gaussian's per-(tile, Gaussian) gradient rows (in tile order: deterministic) straight
    into the per-quantity gradient arrays (no [N, 9 + C] staging array and no serial column copies).

    The backward wrote each entry's row at its tile-list position (a tile's rows are consecutive,
    so its writes stream); Gaussian ``s``'s rows are ``entry_pos[goff[s]:goff[s] + per_g[s]]``, in
    tile order, read here at random, which costs less than writing at random (no read for
    ownership, and independent loads overlap). Each visible Gaussian is one sorted position, summed
    by one thread: no atomics, and the sums do not depend on the thread count.
    """
    nq = entry_grads.shape[1]
    flat = entry_grads.reshape(entry_grads.size)
    n = reason.shape[0]
    for item in prange((n + _PROJ_CHUNK - 1) // _PROJ_CHUNK):  # items, not Gaussians: see the caller
        for i in range(item * _PROJ_CHUNK, min(n, (item + 1) * _PROJ_CHUNK)):
            if reason[i] != 0:
                for q in range(2):
                    g_m2[i, q] = _ZERO
                    g_abs[i, q] = _ZERO
                for q in range(3):
                    g_con[i, q] = _ZERO
                g_op[i] = _ZERO
                g_z[i] = _ZERO
                for q in range(g_col.shape[1]):
                    g_col[i, q] = _ZERO
    m = goff.shape[0]
    for item in prange((m + _PROJ_CHUNK - 1) // _PROJ_CHUNK):
        acc = np.empty(nq, np.float32)
        for s in range(item * _PROJ_CHUNK, min(m, (item + 1) * _PROJ_CHUNK)):
            if s + _REDUCE_PREFETCH < m:  # the rows of a Gaussian further on: random reads, fetched ahead
                ahead = s + _REDUCE_PREFETCH
                for e in range(goff[ahead], goff[ahead] + per_g[ahead]):
                    first = entry_pos[e] * nq
                    for b in range(first, first + nq, 16):  # every cache line of the row
                        _prefetch(flat, b)
                    _prefetch(flat, first + nq - 1)
                ga = order[ahead]  # and the lines its sums go to, for writing
                _prefetch_write(g_m2, ga)
                _prefetch_write(g_abs, ga)
                _prefetch_write(g_con, ga)
                _prefetch_write(g_op, ga)
                _prefetch_write(g_z, ga)
                _prefetch_write(g_col, ga)
            for q in range(nq):
                acc[q] = _ZERO
            for e in range(goff[s], goff[s] + per_g[s]):
                row = entry_pos[e]
                for q in range(nq):
                    acc[q] = min(max(acc[q] + entry_grads[row, q], -_GMAX32), _GMAX32)  # saturate
            g = order[s]
            g_m2[g, 0], g_m2[g, 1], g_abs[g, 0], g_abs[g, 1] = acc[0], acc[1], acc[2], acc[3]
            g_con[g, 0], g_con[g, 1], g_con[g, 2] = acc[4], acc[5], acc[6]
            g_op[g], g_z[g] = acc[7], acc[8]
            for q in range(_NQ, nq):
                g_col[g, q - _NQ] = acc[q]


@njit(parallel=True, cache=True, error_model="numpy")
def _replay_pairs(
    tile_start: np.ndarray, tile_ids: np.ndarray, rec: np.ndarray, width: int, height: int,
    tiles_x: int, write: bool, pix_off: np.ndarray, counts: np.ndarray, out_g: np.ndarray,
) -> None:
    """Re-make the forward's decisions (scalar code, same ops) and list the pairs it composited.

    ``write=False``: count pairs per pixel into ``counts``; ``write=True``: write the Gaussian
    index of each pair at ``pix_off[pixel] + i``, front to back.
    """
    n_tiles = tile_start.shape[0] - 1
    for t in prange(n_tiles):
        ox = (t % tiles_x) * TS
        oy = (t // tiles_x) * TS
        T = np.ones(TS * TS)
        done = np.zeros(TS * TS, np.bool_)
        cur = np.zeros(TS * TS, np.int64)
        for k in range(tile_start[t], tile_start[t + 1]):
            s = tile_ids[k]
            for r in range(max(np.int64(rec[s, _BX + 2]) - oy, 0), min(np.int64(rec[s, _BX + 3]) - oy, TS - 1) + 1):
                dy = F32(oy + r - np.int64(rec[s, _AY])) + rec[s, _HY]
                for j in range(max(np.int64(rec[s, _BX]) - ox, 0), min(np.int64(rec[s, _BX + 1]) - ox, TS - 1) + 1):
                    p = r * TS + j
                    if done[p]:
                        continue
                    dx = F32(ox + j - np.int64(rec[s, _AX])) + rec[s, _HX]
                    sigma = _HALF * (rec[s, _CA] * dx * dx + rec[s, _CC] * dy * dy) + rec[s, _CB] * dx * dy
                    alpha = min(_ALPHA_MAX, rec[s, _OP] * _fexp(-sigma))
                    if sigma < _ZERO or alpha < _ALPHA_MIN:
                        continue
                    test = T[p] * (1.0 - np.float64(alpha))
                    if test < T_STOP:
                        done[p] = True
                        continue
                    T[p] = test
                    if write:
                        out_g[pix_off[(oy + r) * width + ox + j] + cur[p]] = s
                    cur[p] += 1
        if not write:
            for r in range(min(TS, height - oy)):
                for j in range(min(TS, width - ox)):
                    counts[(oy + r) * width + ox + j] = cur[r * TS + j]


_KERNELS: dict[tuple[str, int, bool], Any] = {}
#: Tiles per work item of the compositing loops (dynamic scheduling absorbs uneven tiles and busy cores).
_TILE_CHUNK = 4
#: Chunks per thread of the counting sort into tiles (see ``RenderJob._bin``).
_SORT_CHUNKS_PER_THREAD = 8
#: Fewer tiles than this per thread and the work items shrink to one tile (see :func:`_tile_chunk`).
_TILES_PER_THREAD = 64


def _tile_chunk(n_tiles: int) -> int:
    """Tiles per work item of the compositing loops for this many tiles and the current threads.

    Four neighbouring tiles per item keep their shared records in cache, but the last items then
    decide when the loop ends: with 510 tiles (480x270) a greedy schedule of the measured per-tile
    costs ends 31 % after the ideal at 16 threads with items of 4 tiles, 0.9 % with single tiles
    (0.02 % either way at 2 threads; docs/design.md §8). Single tiles once a thread gets fewer
    than ``_TILES_PER_THREAD`` tiles.
    """
    return _TILE_CHUNK if n_tiles >= _TILES_PER_THREAD * numba.get_num_threads() else 1


def _kernel(which: str, n_channels: int, render_depth: bool) -> Any:
    """The compositing kernel ``which`` ("forward", "backward" or "image") for these flags (made once).

    Up to ``_MAX_FUSED`` channels, one variant per channel count with the color terms fused into
    the lane loops (C = 3 RGB, 4 with the exact-fog transmittance, 15 for four weathers and three
    hazes); more channels share one variant with separate per-channel loops ("forward" and
    "backward"; :meth:`RenderJob.image` takes the forward there).
    """
    nf = n_channels if 0 < n_channels <= _MAX_FUSED else 0
    key = (which, nf, bool(render_depth))
    if key not in _KERNELS:
        makers = {"forward": _make_render_forward, "backward": _make_render_backward, "image": _make_render_image}
        _KERNELS[key] = makers[which](nf, bool(render_depth))
    return _KERNELS[key]


# ---------------------------------------------------------------------------------------------------
# Driver
# ---------------------------------------------------------------------------------------------------


def _aligned_empty(shape: tuple[int, ...], dtype: type, align: int = 64) -> np.ndarray:
    """An uninitialised C array whose first element sits on an ``align``-byte boundary."""
    n = int(np.prod(shape))
    itemsize = np.dtype(dtype).itemsize
    raw: np.ndarray = np.empty(n + align // itemsize, dtype)
    skip = (-raw.ctypes.data % align) // itemsize
    return raw[skip:skip + n].reshape(shape)


class _ScratchPool:
    """Large internal arrays of a render, reused by later renders instead of freshly mapped.

    glibc serves allocations above its mmap threshold (32 MiB at most) with fresh pages, which the
    kernel faults in and zeroes on first touch: ~8 ms for the 83 MB float64 sums of a 1920x1080
    frame, every call. Arrays of at least ``min_bytes`` come from here; a job gives them back when
    it is done (its backward, or its garbage collection), and at most ``max_bytes`` wait here.
    Never used for arrays handed to the caller (images, gradients, per-Gaussian outputs).
    """

    def __init__(self, min_bytes: int, max_bytes: int) -> None:
        self.min_bytes, self.max_bytes = min_bytes, max_bytes
        self._free: list[np.ndarray] = []
        self._lock = threading.Lock()

    def take(self, shape: tuple[int, ...], dtype: Any, owner: list[np.ndarray]) -> np.ndarray:
        """An uninitialised C array of ``shape``, 64-byte aligned; its storage is appended to ``owner``."""
        itemsize = np.dtype(dtype).itemsize
        nbytes = int(np.prod(shape)) * itemsize
        if nbytes < self.min_bytes:
            return _aligned_empty(shape, dtype)
        raw = None
        with self._lock:
            fits = [i for i, b in enumerate(self._free) if nbytes + 64 <= b.nbytes <= 2 * nbytes + 64]
            if fits:
                raw = self._free.pop(min(fits, key=lambda i: self._free[i].nbytes))
        if raw is None:
            raw = np.empty(nbytes + 64, np.uint8)
        owner.append(raw)
        skip = -raw.ctypes.data % 64
        return raw[skip:skip + nbytes].view(dtype).reshape(shape)

    def give(self, owner: list[np.ndarray]) -> None:
        """Return the storage listed in ``owner`` (emptied); the oldest beyond ``max_bytes`` is dropped."""
        with self._lock:
            self._free.extend(owner)
            owner.clear()
            while sum(b.nbytes for b in self._free) > self.max_bytes:
                self._free.pop(0)


#: Arrays of 8 MiB and more (a 1080p frame's sums and entry gradients) are pooled, up to 512 MiB.
_SCRATCH = _ScratchPool(8 << 20, 512 << 20)


def _as_f32(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().numpy(), dtype=np.float32)


class RenderJob:
    """One render with the numba backend: projection at construction, then forward / backward.

    Parameters
    ----------
    means, quats, scales, opacities, colors : Tensor
        float32 parameters, shapes as in :func:`wcbench.reference_model.rasterize` (already checked).
    viewmat : Tensor [4, 4]
    K : Tensor [3, 3]
    width, height : int
    near, far : float
    render_depth : bool

    Attributes
    ----------
    means2d_f32 [N, 2] float32, radii [N, 2] int32, depths [N] float32 : ndarray
        Per-Gaussian outputs of the projection (zeros for culled Gaussians); the job never writes
        them again, so :func:`rasterize` hands them to torch without a copy.
    meta : dict
        Counters (see :class:`RenderOutput`); ``n_tile_entries`` and ``n_pairs`` are filled by
        :meth:`forward`; ``phase_ms`` (dict of str to float) the wall time of each phase so far:
        ``project`` and the visible pass's part of ``sort`` (at construction), the rest of
        ``sort`` and ``bin`` (at :meth:`forward`), ``fwd_blend``, then ``bwd_blend``,
        ``bwd_reduce`` and ``bwd_project`` (at :meth:`backward`). ``wcbench bench raster`` reads
        them; what a call spends outside them is the torch glue (docs/design.md §8).
    """

    def __init__(
        self, means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
        colors: torch.Tensor, viewmat: torch.Tensor, K: torch.Tensor, width: int, height: int, *,
        near: float, far: float, render_depth: bool,
    ) -> None:
        self.means, self.quats, self.scales = _as_f32(means), _as_f32(quats), _as_f32(scales)
        self.opac, self.colors = _as_f32(opacities), _as_f32(colors)
        vm = viewmat.detach().to(torch.float64).numpy()
        k = K.detach().to(torch.float64).numpy()
        self.V = np.ascontiguousarray(vm[:3, :3])
        self.tvec = np.ascontiguousarray(vm[:3, 3])
        self.intr = np.array([k[0, 0], k[1, 1], k[0, 2], k[1, 2]])
        self.width, self.height = width, height
        self.n_channels = self.colors.shape[1]
        self.render_depth = render_depth
        n = self.means.shape[0]
        # Pooled internal arrays (acc_img, records, tile lists), returned when the job is collected.
        self._scratch: list[np.ndarray] = []
        weakref.finalize(self, _SCRATCH.give, self._scratch)
        self.means2d_f32 = np.empty((n, 2), np.float32)
        self.depths = np.empty(n, np.float32)
        self.radii = np.empty((n, 2), np.int32)
        self.reason = np.empty(n, np.int8)
        self._rec = _SCRATCH.take((n, _NPRM), np.float32, self._scratch)
        t0 = time.perf_counter()
        if n:
            _project_kernel(self.means, self.quats, self.scales, self.opac, self.colors, self.V, self.tvec,
                            self.intr, width, height, float(near), float(far), self.means2d_f32, self.depths,
                            self.radii, self.reason, self._rec)
        t1 = time.perf_counter()
        # The visible set and the cull counters in one chunked parallel pass (docs/design.md §8); its
        # time counts to the sort.
        self._vis, self._vis_bits, counts = _visible_keys(self.reason, self.depths, _n_chunks(n))
        self.meta: dict[str, Any] = empty_meta("numba", n)
        self.meta.update(counts_meta(counts.tolist()))
        self.phase_ms: dict[str, float] = {"project": 1e3 * (t1 - t0), "sort": 1e3 * (time.perf_counter() - t1)}
        self.meta["phase_ms"] = self.phase_ms

    def _bin(self) -> None:
        self.tiles_x = -(-self.width // TS)
        self.tiles_y = -(-self.height // TS)
        n_tiles = self.tiles_x * self.tiles_y
        t0 = time.perf_counter()
        # One global front-to-back sort (ties by index): positive float32 bits sort like the floats.
        m = len(self._vis)
        self.order = _radix_sort(self._vis_bits, self._vis, _n_chunks(m))  # overwrites both inputs
        del self._vis, self._vis_bits
        t1 = time.perf_counter()
        self.phase_ms["sort"] += 1e3 * (t1 - t0)
        pbox = np.empty((m, 4), np.int32)  # the boxes in depth order, for the scatter only
        # Chunks of the counting sort: contiguous runs of the depth order, several per thread and
        # handed out one at a time, because near Gaussians cover more tiles than far ones and the
        # first runs cost the most (equal static shares measured 1.6-1.8x from 1 to 2 threads).
        n_chunks = max(1, min(_SORT_CHUNKS_PER_THREAD * numba.get_num_threads(), m // 2048 + 1))
        counts = np.zeros((n_chunks, n_tiles), np.int64)
        self.per_g = np.empty(m, np.int64)
        if m:
            with numba.parallel_chunksize(1):
                _tile_counts(self.order, self._rec, self.tiles_x, pbox, counts, self.per_g)
        self.tile_start, cursor0, chunk_base = _tile_offsets(counts)
        self.goff = np.empty(m, np.int64)
        n_entries = int(self.tile_start[-1])
        self.entry_pos = _SCRATCH.take((n_entries,), np.int64, self._scratch)
        self.tile_ids = _SCRATCH.take((n_entries,), np.int32, self._scratch)
        with numba.parallel_chunksize(1):
            _tile_fill(self.order, pbox, self.tiles_x, cursor0, chunk_base, self.goff, self.tile_ids,
                       self.entry_pos)
        # Even tiles, then odd ones, handed out in chunks of a few: neighbouring tiles share Gaussians
        # (records stay in cache; heaviest-first order measured 1.6x slower), and sky and street rows
        # are spread over both threads.
        tiles = np.arange(n_tiles, dtype=np.int64)
        self.tile_order = np.concatenate([tiles[0::2], tiles[1::2]])
        self.meta["n_tile_entries"] = n_entries
        self.phase_ms["bin"] = 1e3 * (time.perf_counter() - t1)

    def forward(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Composite: color before background [H, W, C], alpha [H, W], sum(w z) [H, W] (float32)."""
        self._bin()
        t0 = time.perf_counter()
        h, w, c = self.height, self.width, self.n_channels
        self.acc_img = _SCRATCH.take((h, w, c + 2), np.float64, self._scratch)
        color = np.empty((h, w, c), np.float32)
        alpha = np.empty((h, w), np.float32)
        dnum = np.zeros((h, w) if self.render_depth else (1, 1), np.float32)
        n_tiles = len(self.tile_order)
        self.tile_end = np.empty(n_tiles, np.int64)
        tile_pairs = np.zeros(n_tiles, np.int64)
        with numba.parallel_chunksize(_tile_chunk(n_tiles)):
            _kernel("forward", self.n_channels, self.render_depth)(
                self.tile_start, self.tile_ids, self.tile_order, self._rec, self.colors, w, h, self.tiles_x,
                self.acc_img, color, alpha, dnum, self.tile_end, tile_pairs)
        self.meta["n_pairs"] = int(tile_pairs.sum())
        self.phase_ms["fwd_blend"] = 1e3 * (time.perf_counter() - t0)
        return color, alpha, dnum

    def image(self, *, stop: float = T_STOP) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Composite for a render without gradients: the outputs of :meth:`forward` (color before
        background [H, W, C], alpha [H, W], sum(w z) [H, W], float32) from the image kernel, which
        keeps float32 state and nothing for a backward (``_make_render_image``). A job that ran
        this has no :meth:`backward`. More than ``_MAX_FUSED`` channels take :meth:`forward`.
        Every pixel stops at ``T_STOP`` as the forward's do; a ``stop`` above it (a transmittance
        below 1) stops a pixel sooner, once its transmittance has fallen below ``stop``, the pair
        that took it there composited."""
        if not 0 < self.n_channels <= _MAX_FUSED:
            if stop != T_STOP:
                raise ValueError(f"a stop transmittance other than {T_STOP} needs at most {_MAX_FUSED} channels, "
                                 f"got {self.n_channels}")
            return self.forward()
        self._bin()
        t0 = time.perf_counter()
        h, w, c = self.height, self.width, self.n_channels
        color = np.empty((h, w, c), np.float32)
        alpha = np.empty((h, w), np.float32)
        dnum = np.zeros((h, w) if self.render_depth else (1, 1), np.float32)
        n_tiles = len(self.tile_order)
        tile_pairs = np.zeros(n_tiles, np.int64)
        with numba.parallel_chunksize(_tile_chunk(n_tiles)):
            _kernel("image", c, self.render_depth)(
                self.tile_start, self.tile_ids, self.tile_order, self._rec, self.colors, w, h, self.tiles_x,
                color, alpha, dnum, tile_pairs, F32(stop))
        self.meta["n_pairs"] = int(tile_pairs.sum())
        self.phase_ms["fwd_blend"] = 1e3 * (time.perf_counter() - t0)
        return color, alpha, dnum

    def backward(
        self, g_color: np.ndarray, g_alpha: np.ndarray, g_dnum: np.ndarray
    ) -> tuple[np.ndarray, ...]:
        """Gradients for (means, quats, scales, opacities, colors, means2d, means2d_abs)."""
        t0 = time.perf_counter()
        n, c = self.means.shape[0], self.n_channels
        local: list[np.ndarray] = []
        entry_grads = _SCRATCH.take((len(self.tile_ids), _NQ + c), np.float32, local)
        if not self.render_depth:
            g_dnum = np.zeros((1, 1), np.float32)
        with numba.parallel_chunksize(_tile_chunk(len(self.tile_order))):
            _kernel("backward", self.n_channels, self.render_depth)(
                self.tile_start, self.tile_ids, self.tile_order, self.tile_end, self._rec, self.colors, self.width,
                self.height, self.tiles_x, self.acc_img, g_color, g_alpha, g_dnum, entry_grads)
        t1 = time.perf_counter()
        g_m2, g_abs = np.empty((n, 2), np.float32), np.empty((n, 2), np.float32)
        g_con, g_col = np.empty((n, 3), np.float32), np.empty((n, c), np.float32)
        g_op, g_z = np.empty(n, np.float32), np.empty(n, np.float32)
        if n:
            # Items handed out one at a time: near Gaussians (the first of the depth order) cover
            # more tiles, so equal static shares leave one thread with most of the rows.
            with numba.parallel_chunksize(1):
                _reduce_entries(self.order, self.goff, self.per_g, self.entry_pos, entry_grads, self.reason, g_m2,
                                g_abs, g_con, g_op, g_z, g_col)
        _SCRATCH.give(local)
        t2 = time.perf_counter()
        g_means = np.empty((n, 3), np.float32)
        g_quats = np.empty((n, 4), np.float32)
        g_scales = np.empty((n, 3), np.float32)
        if n:
            _project_backward(self.means, self.quats, self.scales, self.V, self.tvec, self.intr, self.width,
                              self.height, self.reason, g_m2, g_con, g_z, g_means, g_quats, g_scales)
        out = (g_means, g_quats, g_scales, g_op, g_col, g_m2, g_abs)
        t3 = time.perf_counter()
        self.phase_ms.update(bwd_blend=1e3 * (t1 - t0), bwd_reduce=1e3 * (t2 - t1), bwd_project=1e3 * (t3 - t2))
        return out

    def composited_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """The (Gaussian, pixel) pairs the forward composited, grouped by pixel, front to back.

        Returns
        -------
        gid, pix : ndarray [P] int64
            Gaussian index and pixel index ``y * width + x``; the input of the twin's ``pairs=``.
        """
        hw = self.height * self.width
        counts = np.zeros(hw, np.int64)
        off = np.zeros(hw, np.int64)
        dummy = np.zeros(0, np.int64)
        args = (self.tile_start, self.tile_ids, self._rec, self.width, self.height, self.tiles_x)
        _replay_pairs(*args, False, off, counts, dummy)
        np.cumsum(counts[:-1], out=off[1:])
        gid = np.empty(int(counts.sum()), np.int64)
        _replay_pairs(*args, True, off, counts, gid)
        pix = np.repeat(np.arange(hw, dtype=np.int64), counts)
        return gid, pix
