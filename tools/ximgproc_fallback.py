"""``cv2.ximgproc.guidedFilter`` for machines whose OpenCV lacks the contrib modules.

The lent workstation's image ships ``opencv-python-headless`` without ``ximgproc``, and the contrib
wheel (69 MB) does not fit the 64 MiB the device tool carries. tools/workstation_check.sh installs
this module as ``sitecustomize`` there when ``cv2.ximgproc`` is missing: the exact guided filter of
He et al. (2010), gray and colour guides (normalised box means over a (2r+1)^2 window, reflected
borders). It equals OpenCV's for a gray guide and for a colour guide at eps >= 1e-2 to float32
rounding (1e-4); at the smaller eps of the sky matte and the editor's masks (1e-3, 1e-4) OpenCV's colour
filter departs from the exact one (by up to 1.0 on a PandaSet frame) and this one does not, so the
workstation's runs compare with each other, not bit for bit with a contrib install
(tests/test_workstation_tools.py). It changes nothing where ximgproc exists.
"""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np


def _mean(a: np.ndarray, r: int) -> np.ndarray:
    return cv2.boxFilter(a, cv2.CV_32F, (2 * r + 1, 2 * r + 1), normalize=True, borderType=cv2.BORDER_REFLECT)


def guided_filter(guide: np.ndarray, src: np.ndarray, radius: int, eps: float, dDepth: int = -1) -> np.ndarray:
    """``src`` [H, W] float32 filtered under ``guide`` [H, W] or [H, W, 3] (``cv2.ximgproc.guidedFilter``)."""
    I = np.asarray(guide, np.float32)  # noqa: E741 (He et al.'s name)
    p = np.asarray(src, np.float32)
    r = int(radius)
    mean_p = _mean(p, r)
    if I.ndim == 2 or I.shape[2] == 1:
        I = I.reshape(p.shape)  # noqa: E741
        mean_I = _mean(I, r)
        var = _mean(I * I, r) - mean_I * mean_I
        a = (_mean(I * p, r) - mean_I * mean_p) / (var + eps)
        b = mean_p - a * mean_I
        return _mean(a, r) * I + _mean(b, r)
    ch = [I[..., k] for k in range(3)]
    mean_I = [_mean(c, r) for c in ch]
    cov_Ip = np.stack([_mean(c * p, r) - m * mean_p for c, m in zip(ch, mean_I)], -1)  # [H, W, 3]
    sigma = np.empty((*p.shape, 3, 3), np.float32)
    for i in range(3):
        for j in range(i, 3):
            sigma[..., i, j] = sigma[..., j, i] = _mean(ch[i] * ch[j], r) - mean_I[i] * mean_I[j]
    sigma += eps * np.eye(3, dtype=np.float32)
    a = np.linalg.solve(sigma, cov_Ip[..., None])[..., 0]  # [H, W, 3]
    b = mean_p - sum(a[..., k] * mean_I[k] for k in range(3))
    return sum(_mean(np.ascontiguousarray(a[..., k]), r) * ch[k] for k in range(3)) + _mean(b, r)


def install() -> bool:
    """Give ``cv2`` an ``ximgproc.guidedFilter`` when it has none; True if it was added."""
    if hasattr(cv2, "ximgproc"):
        return False
    cv2.ximgproc = SimpleNamespace(guidedFilter=guided_filter)  # type: ignore[attr-defined]
    return True


install()
