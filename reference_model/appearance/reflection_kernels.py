"""Numba kernel of :mod:`.maps`: where each pixel's ray, reflected by the ground plane, meets the scene.

:func:`reflection_lookup_kernel` mirrors the numpy reference
:func:`wcbench.reference_model.appearance.maps._reflection_lookup` pixel by pixel (the same float64
arithmetic; the reference's dot products go through BLAS and its norm through a reduction, which may
round differently, so the tests compare the looked-up positions to 1e-4 px and the pixels' states
exactly, on random streets). The reference's dozen numpy passes over the pixels below the horizon,
each gathering and allocating a column per quantity, made the screen-space reflection of a rainy
`pandaset_002` frame 19.7 ms; with the kernel's one pass it is 12.1 ms (docs/findings.md, thirty-fourth
session). Compiled on first use and cached on disk.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from wcbench.reference_model.appearance.maps import HIT_FILLED, HIT_SEEN, HIT_SKY, NO_HIT

__all__ = ["reflection_lookup_kernel"]


@numba.njit(cache=True, parallel=True)
def reflection_lookup_kernel(rays, distance, mirror, center, up, ground_height, w2c, K, seen_fraction,
                             slack_m, far_m, map_x, map_y, state):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Fill ``map_x``, ``map_y`` [H, W] float32 (the pixel whose colour is the reflection; the
    pixel's own where its ray does not meet the plane) and ``state`` [H, W] uint8 (:data:`~.maps.NO_HIT`,
    :data:`~.maps.HIT_SEEN`, :data:`~.maps.HIT_SKY`, :data:`~.maps.HIT_FILLED`).

    ``rays`` [H, W, 3] float32 unit world rays; ``distance`` [H, W] the camera's distance map and
    ``mirror`` [H, W] the unfolded reflected path lengths (m, ``inf`` where none); ``center`` [3],
    ``up`` [3] float64; ``w2c`` [3, 4] and ``K`` [3, 3] float64 the camera; a point at infinity is
    put ``far_m`` along the mirrored ray."""
    h, w = distance.shape
    height = (center[0] * up[0] + center[1] * up[1] + center[2] * up[2]) - ground_height
    for i in numba.prange(h):
        for j in range(w):
            map_x[i, j] = j
            map_y[i, j] = i
            state[i, j] = NO_HIT
            r0, r1, r2 = np.float64(rays[i, j, 0]), np.float64(rays[i, j, 1]), np.float64(rays[i, j, 2])
            down = r0 * up[0] + r1 * up[1] + r2 * up[2]
            if not (down < -1e-3 and height > 0):
                continue
            t_plane = height / -down
            g0, g1, g2 = center[0] + r0 * t_plane, center[1] + r1 * t_plane, center[2] + r2 * t_plane
            m0, m1, m2 = r0 - 2.0 * down * up[0], r1 - 2.0 * down * up[1], r2 - 2.0 * down * up[2]
            rest = np.float64(mirror[i, j]) - t_plane
            finite = math.isfinite(rest) and rest > 0
            length = rest if finite else far_m
            p0, p1, p2 = g0 + m0 * length, g1 + m1 * length, g2 + m2 * length
            xc = p0 * w2c[0, 0] + p1 * w2c[0, 1] + p2 * w2c[0, 2] + w2c[0, 3]
            yc = p0 * w2c[1, 0] + p1 * w2c[1, 1] + p2 * w2c[1, 2] + w2c[1, 3]
            z = p0 * w2c[2, 0] + p1 * w2c[2, 1] + p2 * w2c[2, 2] + w2c[2, 3]
            x = xc / z * K[0, 0] + K[0, 2] - 0.5
            y = yc / z * K[1, 1] + K[1, 2] - 0.5
            inside = z > 0 and x >= 0 and x <= w - 1 and y >= 0 and y <= h - 1
            seen = False
            if inside:
                if not finite:
                    seen = True
                else:
                    d0, d1, d2 = p0 - center[0], p1 - center[1], p2 - center[2]
                    far = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                    xi = min(max(int(np.rint(x)), 0), w - 1)
                    yi = min(max(int(np.rint(y)), 0), h - 1)
                    seen = np.float64(distance[yi, xi]) >= far * (1.0 - seen_fraction) - slack_m
            map_x[i, j] = min(max(x, 0.0), w - 1.0)
            map_y[i, j] = min(max(y, 0.0), h - 1.0)
            if seen:
                state[i, j] = HIT_SEEN
            elif not finite:
                state[i, j] = HIT_SKY
            else:
                state[i, j] = HIT_FILLED
