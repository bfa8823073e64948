"""Numba kernels of :mod:`.fog`: the per-Gaussian transmittance channels and the exact compose.

Each mirrors its numpy reference in :mod:`.fog` (same float32 operations in the same order, so
results agree to an ulp or two); the exact fog runs both on every fogged frame, where the numpy
forms' several passes over the arrays cost more than the extra rasterized channel itself.
Compiled on first use and cached on disk.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["compose_exact_kernel", "transmitted_channels_kernel"]

_CHUNK = 4096  # rows per parallel task: large enough to amortise scheduling


@numba.njit(cache=True, parallel=True, error_model="numpy")
def transmitted_channels_kernel(means, colors, center, neg_beta, offset, out):  # type: ignore[no-untyped-def]  # pragma: no cover
    """out[i] = (colors[i] t_i, t_i), t_i = exp(-beta max(|means[i] - center| - offset, 0)).

    ``means`` [N, 3], ``colors`` [N, C] and ``center`` [3] float32; ``neg_beta`` = -beta and
    ``offset`` float32 scalars; ``out`` [N, C + 1] float32.
    """
    n = means.shape[0]
    n_ch = colors.shape[1]
    for chunk in numba.prange((n + _CHUNK - 1) // _CHUNK):
        for i in range(chunk * _CHUNK, min(n, (chunk + 1) * _CHUNK)):
            dx = means[i, 0] - center[0]
            dy = means[i, 1] - center[1]
            dz = means[i, 2] - center[2]
            d = np.float32(math.sqrt(dx * dx + dy * dy + dz * dz)) - offset
            # No fog: t = 1 even where the float32 distance overflows (0 * Inf), as the reference.
            t = np.float32(1.0) if neg_beta == 0 else np.float32(math.exp(max(d, np.float32(0.0)) * neg_beta))
            for k in range(n_ch):
                out[i, k] = colors[i, k] * t
            out[i, n_ch] = t


@numba.njit(cache=True, parallel=True, error_model="numpy")
def compose_exact_kernel(sum_color_t, sum_t, alpha, fog_color, sky, out):  # type: ignore[no-untyped-def]  # pragma: no cover
    """out = max(A - sum_t, 0) c_fog + sum_color_t + (1 - A) sky, per pixel (float32).

    ``sum_color_t`` [H, W, 3], ``sum_t`` and ``alpha`` [H, W], ``fog_color`` and ``sky`` [3],
    ``out`` [H, W, 3].
    """
    h, w = alpha.shape
    for y in numba.prange(h):
        for x in range(w):
            a = alpha[y, x]
            fog_weight = max(a - sum_t[y, x], np.float32(0.0))
            rest = np.float32(1.0) - a
            for k in range(3):
                out[y, x, k] = (fog_weight * fog_color[k] + sum_color_t[y, x, k]) + rest * sky[k]
