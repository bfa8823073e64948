"""Fused training SSIM (numba): the forward and its hand-written backward, in two passes each.

The same function as :func:`~wcbench.reference_model.training.losses.training_ssim_torch` (its
twin: 11x11 Gaussian window of sigma 1.5 as two 1D passes, zero padding, mean over pixels per
channel), without its dozen full-size temporaries: the five blurred maps (x, y, x^2, y^2, x y) are
combined into SSIM row by row as the vertical pass makes them, and the forward keeps only the three
derivative maps the backward needs, dS/dmu_x, dS/dE[x^2] and dS/dE[x y] per pixel. The backward
blurs those with the same window (the adjoint of a zero-padded correlation with a symmetric window
is itself) and forms dL/dx = G*d_mu + 2 x G*d_xx + y G*d_xy, as fused SSIM implementations for
3DGS training do. float32 maps, as the twin's convolutions; the per-channel sums in float64.

Work items are (channel, block of rows), so a 3-channel image keeps every thread busy.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["ssim_backward", "ssim_forward"]

_R = 5  # window radius: 11 taps
_BLOCK = 16  # rows per work item


@njit(cache=True, inline="always", error_model="numpy")
def _hblur(pad: np.ndarray, w: int, taps: np.ndarray, out: np.ndarray, o0: int) -> None:
    """out[o0 + j] = sum_k taps[k] pad[j + k], j < w: a row blurred from its copy ``pad`` with R zeros
    on each side. Unsigned indices, so numba adds no negative-index wraparound and LLVM vectorizes
    over j."""
    base = np.uint64(o0)
    for j in range(w):
        out[base + np.uint64(j)] = 0.0
    for k in range(2 * _R + 1):
        t = taps[k]
        for j in range(w):
            out[base + np.uint64(j)] += t * pad[np.uint64(j + k)]


@njit(cache=True, inline="always", error_model="numpy")
def _vblur(flat: np.ndarray, plane: int, r: int, h: int, w: int, taps: np.ndarray, v: np.ndarray, v0: int) -> None:
    """v[v0 + j] = sum_k taps[k] flat[plane + (r + k - R) w + j] over the rows inside the image (an
    [H, W] plane of a flat array starting at ``plane``)."""
    vb = np.uint64(v0)
    for j in range(w):
        v[vb + np.uint64(j)] = 0.0
    for k in range(2 * _R + 1):
        rr = r + k - _R
        if rr < 0 or rr >= h:
            continue
        t = taps[k]
        src = np.uint64(plane + rr * w)
        for j in range(w):
            v[vb + np.uint64(j)] += t * flat[src + np.uint64(j)]


@njit(parallel=True, cache=True, error_model="numpy")
def ssim_forward(x: np.ndarray, y: np.ndarray, taps: np.ndarray, c1: float, c2: float) -> tuple:
    """SSIM per channel of images ``x``, ``y`` [C, H, W] float32 (window ``taps`` [11]).

    Returns
    -------
    sums : ndarray [C] float64
        Sum over pixels of the SSIM map (divide by H W for the mean).
    d_mu, d_xx, d_xy : ndarray [C, H, W] float32
        dS/dmu_x, dS/dE[x^2] and dS/dE[x y] per pixel (``y`` held fixed).
    """
    c_count, h, w = x.shape
    hw = h * w
    xf, yf = x.reshape(-1), y.reshape(-1)
    blocks = (h + _BLOCK - 1) // _BLOCK
    # horizontal pass: planes (map m, channel c) of x, y, x^2, y^2, x y, blurred along rows
    hb = np.empty(5 * c_count * hw, np.float32)
    for item in prange(c_count * blocks):
        c, b = item // blocks, item % blocks
        pad = np.zeros((5, w + 2 * _R), np.float32)
        for r in range(b * _BLOCK, min(h, (b + 1) * _BLOCK)):
            row = np.uint64(c * hw + r * w)
            for j in range(w):
                a, bb = xf[row + np.uint64(j)], yf[row + np.uint64(j)]
                pad[0, j + _R] = a
                pad[1, j + _R] = bb
                pad[2, j + _R] = a * a
                pad[3, j + _R] = bb * bb
                pad[4, j + _R] = a * bb
            for m in range(5):
                _hblur(pad[m], w, taps, hb, (m * c_count + c) * hw + r * w)
    d_mu = np.empty(c_count * hw, np.float32)
    d_xx = np.empty(c_count * hw, np.float32)
    d_xy = np.empty(c_count * hw, np.float32)
    partial = np.zeros(c_count * blocks)
    f1, f2, two, one = np.float32(c1), np.float32(c2), np.float32(2.0), np.float32(1.0)
    for item in prange(c_count * blocks):
        c, b = item // blocks, item % blocks
        v = np.empty(5 * w, np.float32)
        acc = 0.0
        for r in range(b * _BLOCK, min(h, (b + 1) * _BLOCK)):
            for m in range(5):
                _vblur(hb, (m * c_count + c) * hw, r, h, w, taps, v, m * w)
            row = np.uint64(c * hw + r * w)
            for j in range(w):
                mx, my, exx = v[np.uint64(j)], v[np.uint64(w + j)], v[np.uint64(2 * w + j)]
                eyy, exy = v[np.uint64(3 * w + j)], v[np.uint64(4 * w + j)]
                vx, vy, cxy = exx - mx * mx, eyy - my * my, exy - mx * my
                a1, a2 = two * mx * my + f1, two * cxy + f2
                b1, b2 = mx * mx + my * my + f1, vx + vy + f2
                den = b1 * b2
                s = (a1 * a2) / den
                acc += np.float64(s)
                u = row + np.uint64(j)
                d_mu[u] = two * my * (a2 - a1) / den - two * mx * s * (one / b1 - one / b2)
                d_xx[u] = -s / b2
                d_xy[u] = two * a1 / den
        partial[item] = acc
    sums = np.zeros(c_count)
    for item in range(c_count * blocks):  # a fixed order: the same sums for any thread count
        sums[item // blocks] += partial[item]
    return sums, d_mu.reshape(c_count, h, w), d_xx.reshape(c_count, h, w), d_xy.reshape(c_count, h, w)


@njit(parallel=True, cache=True, error_model="numpy")
def ssim_backward(x: np.ndarray, y: np.ndarray, taps: np.ndarray, d_mu: np.ndarray, d_xx: np.ndarray,
                  d_xy: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """dL/dx [C, H, W] float32 from the forward's derivative maps and ``scale`` [C] = dL/dSSIM_c / (H W)."""
    c_count, h, w = x.shape
    hw = h * w
    xf, yf = x.reshape(-1), y.reshape(-1)
    df = (d_mu.reshape(-1), d_xx.reshape(-1), d_xy.reshape(-1))
    blocks = (h + _BLOCK - 1) // _BLOCK
    hb = np.empty(3 * c_count * hw, np.float32)
    for item in prange(c_count * blocks):
        c, b = item // blocks, item % blocks
        s = np.float32(scale[c])
        pad = np.zeros((3, w + 2 * _R), np.float32)
        for r in range(b * _BLOCK, min(h, (b + 1) * _BLOCK)):
            row = np.uint64(c * hw + r * w)
            for j in range(w):
                u = row + np.uint64(j)
                pad[0, j + _R] = s * df[0][u]
                pad[1, j + _R] = s * df[1][u]
                pad[2, j + _R] = s * df[2][u]
            for m in range(3):
                _hblur(pad[m], w, taps, hb, (m * c_count + c) * hw + r * w)
    out = np.empty(c_count * hw, np.float32)
    two = np.float32(2.0)
    for item in prange(c_count * blocks):
        c, b = item // blocks, item % blocks
        v = np.empty(3 * w, np.float32)
        for r in range(b * _BLOCK, min(h, (b + 1) * _BLOCK)):
            for m in range(3):
                _vblur(hb, (m * c_count + c) * hw, r, h, w, taps, v, m * w)
            row = np.uint64(c * hw + r * w)
            for j in range(w):
                u = row + np.uint64(j)
                out[u] = v[np.uint64(j)] + two * xf[u] * v[np.uint64(w + j)] + yf[u] * v[np.uint64(2 * w + j)]
    return out.reshape(c_count, h, w)
