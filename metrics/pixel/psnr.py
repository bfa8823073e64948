"""PSNR against a ground-truth sequence (reference-based; synthetic scenes and ``clear``)."""

from __future__ import annotations

import numpy as np

from wcbench.metrics.base import PerFrameReferenceMetric, as_float_images, check_same_shape

_VARIANT = "mean over frames of 10 log10(1 / MSE), RGB in [0, 1], MSE over pixels and channels in float64"


def _squared_errors(pred: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-frame mean squared error [B] in float64."""
    d = pred.astype(np.float64) - reference.astype(np.float64)
    return np.einsum("bhwc,bhwc->b", d, d) / np.prod(d.shape[1:])


def _psnr_from_mse(mse: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(1.0 / mse)


def psnr(pred: np.ndarray, reference: np.ndarray) -> float:
    """Mean PSNR (dB) of a frame or a sequence against its reference.

    Parameters
    ----------
    pred, reference : ndarray [H, W, 3] or [T, H, W, 3]
        Float RGB in [0, 1] (or uint8, divided by 255).

    Returns
    -------
    float
        Mean over frames of per-frame PSNR with data range 1; ``inf`` for identical images.
    """
    p, r = as_float_images(pred, name="pred"), as_float_images(reference, name="reference")
    check_same_shape(p, r, names=("pred", "reference"))
    return float(np.mean(_psnr_from_mse(_squared_errors(p, r))))


class PSNR(PerFrameReferenceMetric):
    """Peak signal-to-noise ratio per frame, averaged over the sequence (dB)."""

    name = "psnr"
    description = "PSNR (dB) against the ground-truth sequence; needs a reference"
    outputs = ("psnr",)
    higher_is_better = True
    variant = _VARIANT
    nonfinite_reason = "PSNR is infinite for identical images (MSE = 0)"

    def frame_values(self, pred: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """Per-frame PSNR [B] in dB (inf for identical frames)."""
        return _psnr_from_mse(_squared_errors(pred, reference))
