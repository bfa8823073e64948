"""The guided filter of He, Sun & Tang (2013, "Guided image filtering", TPAMI) with a colour guide,
exact at any regularisation.

OpenCV's ``cv2.ximgproc`` colour guided filter departs from the filter's definition when the guide
is in [0, 1] and ``eps`` is small (1e-3 and below): across an edge between two colours it smooths
as a box filter would (a 30 / 90 m step became 48-72 m beside the edge; up to 1.0 off on a [0, 1]
mask of a PandaSet frame; tools/ximgproc_fallback.py measured it first; why, in OpenCV's source,
was not traced). The filter is invariant to scaling the guide by s and ``eps`` by s**2, and on the
guide in [0, 255] OpenCV's is the definition (within 1.1e-4 of a float64 write-out of it on that
frame's mask at eps 1e-3 and 1e-4; tested to 1e-3, tests/reference_model/test_guided_filter.py),
so :func:`guided_filter` runs it there.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["guided_filter"]

#: The guide's scale for OpenCV (its 8-bit range), and so eps's (squared).
_SCALE = 255.0


def guided_filter(guide: np.ndarray, src: np.ndarray, *, radius: int, eps: float) -> np.ndarray:
    """``src`` filtered with ``guide`` (He et al. 2013): in each (2 ``radius`` + 1)^2 window the
    least-squares linear map of the guide's colour to ``src`` regularised by ``eps``, averaged over
    the windows that hold each pixel (box means, reflected borders).

    Parameters
    ----------
    guide : ndarray [H, W, 3] or [H, W] float
        The guide, in [0, 1] (display RGB).
    src : ndarray [H, W] or [H, W, C] float
        What is filtered; each channel alone, with the same guide.
    radius : int
        Window radius (px), >= 1.
    eps : float
        Regularisation, > 0 (in the guide's [0, 1] units: edges weaker than about sqrt(eps) are
        smoothed over).

    Returns
    -------
    ndarray float32, the shape of ``src``

    Raises
    ------
    ValueError
        If the shapes disagree, ``radius`` < 1 or ``eps`` <= 0.
    """
    g = np.asarray(guide, np.float32)
    s = np.asarray(src, np.float32)
    if g.shape[:2] != s.shape[:2] or g.ndim not in (2, 3) or s.ndim not in (2, 3) or radius < 1 or not eps > 0:
        raise ValueError(f"guide [H, W(, 3)] and src [H, W(, C)] of one size, radius >= 1 and eps > 0 were "
                         f"expected, got {g.shape}, {s.shape}, {radius} and {eps}")
    scaled = np.ascontiguousarray(g * np.float32(_SCALE))
    eps_scaled = float(eps) * _SCALE ** 2
    if hasattr(cv2.ximgproc, "createGuidedFilter"):  # the guide's covariances inverted once for every channel
        out = cv2.ximgproc.createGuidedFilter(scaled, int(radius), eps_scaled).filter(np.ascontiguousarray(s))
        return np.asarray(out, np.float32).reshape(s.shape)
    # the workstation's stand-in for ximgproc (tools/ximgproc_fallback.py) filters one channel a call
    channels = [s] if s.ndim == 2 else [s[..., c] for c in range(s.shape[2])]
    out = [cv2.ximgproc.guidedFilter(scaled, np.ascontiguousarray(c), int(radius), eps_scaled) for c in channels]
    return np.asarray(out[0] if s.ndim == 2 else np.stack(out, -1), np.float32)
