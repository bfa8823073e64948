"""Numba kernels of :mod:`.shading`: the sRGB transfer functions (IEC 61966-2-1) in one pass.

Each mirrors its numpy reference in :mod:`.shading` operation for operation in float32 (the clip,
the branch at the linear segment, the power), so the results agree to the last bit or two: the
kernel's power is the C library's powf and the reference's numpy's own float32 power, whose last bit
varies with numpy's version and the CPU it dispatches for (the tests allow 5e-7 of the value on
every float32 in [0, 1] of a stride and on the edge values, and no difference off the power). The
reference's ``np.where`` evaluates both branches over the whole frame, with a temporary per
operation; the editor converts a 480 x 270 frame five to eight times (the raw frame, the
reflections, the edited frame, the sky), which was a tenth of a rainy frame's time
(docs/findings.md). Compiled on first use and cached on disk.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["linear_to_srgb_kernel", "srgb_to_linear_kernel"]

_CHUNK = 16384  # values per parallel task: large enough to amortise scheduling

# the reference's float32 constants (NumPy 2 casts a Python float operand to the array's float32)
_ZERO = np.float32(0.0)
_ONE = np.float32(1.0)
_DECODE_KNEE = np.float32(0.04045)
_DECODE_SLOPE = np.float32(12.92)
_OFFSET = np.float32(0.055)
_SCALE = np.float32(1.055)
_GAMMA = np.float32(2.4)
_ENCODE_KNEE = np.float32(0.0031308)
_INV_GAMMA = np.float32(1.0 / 2.4)


@numba.njit(cache=True, inline="always")
def _clip01(v):  # type: ignore[no-untyped-def]  # pragma: no cover
    # np.clip's order: a NaN passes through both comparisons unchanged
    if v < _ZERO:
        return _ZERO
    if v > _ONE:
        return _ONE
    return v


@numba.njit(cache=True, parallel=True, error_model="numpy")
def srgb_to_linear_kernel(values, out):  # type: ignore[no-untyped-def]  # pragma: no cover
    """out[i] = the linear light of the sRGB value ``values[i]`` clipped to [0, 1] (both [N] float32)."""
    n = values.shape[0]
    for chunk in numba.prange((n + _CHUNK - 1) // _CHUNK):
        for i in range(chunk * _CHUNK, min(n, (chunk + 1) * _CHUNK)):
            c = _clip01(values[i])
            if c <= _DECODE_KNEE:
                out[i] = c / _DECODE_SLOPE
            else:
                out[i] = ((c + _OFFSET) / _SCALE) ** _GAMMA


@numba.njit(cache=True, parallel=True, error_model="numpy")
def linear_to_srgb_kernel(values, out):  # type: ignore[no-untyped-def]  # pragma: no cover
    """out[i] = the sRGB value of the linear light ``values[i]`` clipped to [0, 1] (both [N] float32)."""
    n = values.shape[0]
    for chunk in numba.prange((n + _CHUNK - 1) // _CHUNK):
        for i in range(chunk * _CHUNK, min(n, (chunk + 1) * _CHUNK)):
            c = _clip01(values[i])
            if c <= _ENCODE_KNEE:
                out[i] = c * _DECODE_SLOPE
            else:
                out[i] = _SCALE * c ** _INV_GAMMA - _OFFSET
