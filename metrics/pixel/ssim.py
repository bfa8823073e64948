"""SSIM exactly as docs/design.md §5 defines it (and as scikit-image computes it).

Gaussian window 11x11 with sigma 1.5, K1 = 0.01, K2 = 0.03, data range 1, population
covariances, float64, SSIM map averaged over the valid region (5 px cropped at each border, as
``skimage.metrics.structural_similarity(..., gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=1, channel_axis=-1)``) and over channels. This is not the
3DGS training SSIM, which zero-pads instead of cropping.
"""

from __future__ import annotations

import cv2
import numpy as np

from wcbench.core.parallel import parallel_map
from wcbench.metrics.base import PerFrameReferenceMetric, as_float_image_pair, check_min_side

SIGMA = 1.5
TRUNCATE = 3.5  # scipy.ndimage.gaussian_filter's default: radius int(3.5 * 1.5 + 0.5) = 5
K1, K2 = 0.01, 0.03
_RADIUS = int(TRUNCATE * SIGMA + 0.5)
_VARIANT = "gaussian 11x11 sigma 1.5, valid region (5 px crop), float64, mean over channels (= skimage)"


def gaussian_kernel_1d(sigma: float = SIGMA, radius: int = _RADIUS) -> np.ndarray:
    """Normalised 1D Gaussian taps [2 radius + 1] in float64 (scipy's construction)."""
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


def ssim_map_mean(a: np.ndarray, b: np.ndarray, *, data_range: float = 1.0) -> float:
    """SSIM of two images [H, W, C] (float64 math), mean over valid pixels and channels."""
    check_min_side(a[None], 2 * _RADIUS + 1, name="ssim")  # the 11 x 11 window and OpenCV's reflection need it
    k = gaussian_kernel_1d()
    x, y = a.astype(np.float64), b.astype(np.float64)

    def blur(m: np.ndarray) -> np.ndarray:
        return cv2.sepFilter2D(m, cv2.CV_64F, k, k, borderType=cv2.BORDER_REFLECT)

    ux, uy = blur(x), blur(y)
    vx = blur(x * x) - ux * ux
    vy = blur(y * y) - uy * uy
    vxy = blur(x * y) - ux * uy
    c1, c2 = (K1 * data_range) ** 2, (K2 * data_range) ** 2
    s = ((2 * ux * uy + c1) * (2 * vxy + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2))
    r = _RADIUS
    valid = s[r:-r, r:-r]
    return float(valid.reshape(-1, valid.shape[-1] if valid.ndim == 3 else 1).mean(axis=0).mean())


def ssim(pred: np.ndarray, reference: np.ndarray) -> float:
    """Mean SSIM of a frame or sequence against its reference.

    Parameters
    ----------
    pred, reference : ndarray [H, W, 3] or [T, H, W, 3]
        Float RGB in [0, 1] (or uint8, divided by 255).

    Returns
    -------
    float
        In [-1, 1]; 1 for identical images.

    Raises
    ------
    ValueError
        On images that are not finite RGB in [0, 1] (or uint8), shapes that differ, no frames, or
        frames under 11 px on a side (the Gaussian window).
    """
    p, r = as_float_image_pair(pred, reference, names=("pred", "reference"))
    if not len(p):
        raise ValueError("ssim: no frames")
    return float(np.mean([ssim_map_mean(a, b) for a, b in zip(p, r)]))


class SSIM(PerFrameReferenceMetric):
    """Structural similarity per frame, averaged over the sequence."""

    name = "ssim"
    description = "SSIM (gaussian 11x11, sigma 1.5, = skimage) against the ground-truth sequence"
    outputs = ("ssim",)
    higher_is_better = True
    variant = _VARIANT
    min_side = 2 * _RADIUS + 1
    identical_value = 1.0  # every pixel's ratio is (2 mu^2 + C1)(2 s^2 + C2) over itself

    def frame_values(self, pred: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """Per-frame SSIM [B], frames in parallel (OpenCV's filters and NumPy release the GIL; each
        frame's value is the same as alone)."""
        return np.array(parallel_map(lambda k: ssim_map_mean(pred[k], reference[k]), range(len(pred))))
