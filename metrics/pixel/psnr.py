"""PSNR against a ground-truth sequence (reference-based; synthetic scenes and ``clear``)."""

from __future__ import annotations

import math

import numpy as np

from wcbench.core.parallel import parallel_map
from wcbench.metrics.base import PerFrameReferenceMetric, as_float_image_pair

_VARIANT = "mean over frames of 10 log10(1 / MSE), RGB in [0, 1], MSE over pixels and channels in float64"


def _frame_psnr(pred: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-frame PSNR [B] in dB from the float64 mean squared error; ``inf`` only for identical frames.

    Differences below ~1e-154 (float64 denormal inputs) square to 0: such a frame's error is
    rescaled by its largest difference before squaring, so a frame that differs never reads as
    identical (docs/design.md §9).
    """
    d = pred.astype(np.float64) - reference.astype(np.float64)
    n = np.prod(d.shape[1:])
    mse = np.einsum("bhwc,bhwc->b", d, d) / n
    with np.errstate(divide="ignore"):
        out = 10.0 * np.log10(1.0 / mse)
    for b in np.flatnonzero(mse == 0):
        top = float(np.abs(d[b]).max())
        if top > 0:  # differs, but the squares underflowed: mse = top^2 mean((d / top)^2)
            scaled = d[b] / top
            out[b] = -10.0 * (2.0 * np.log10(top) + np.log10(np.einsum("hwc,hwc->", scaled, scaled) / n))
    return out


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

    Raises
    ------
    ValueError
        On images that are not finite RGB in [0, 1] (or uint8), shapes that differ, or no frames.
    """
    p, r = as_float_image_pair(pred, reference, names=("pred", "reference"))
    if not len(p):
        raise ValueError("psnr: no frames")
    return float(np.mean(_frame_psnr(p, r)))


class PSNR(PerFrameReferenceMetric):
    """Peak signal-to-noise ratio per frame, averaged over the sequence (dB)."""

    name = "psnr"
    description = "PSNR (dB) against the ground-truth sequence; needs a reference"
    outputs = ("psnr",)
    higher_is_better = True
    variant = _VARIANT
    nonfinite_reason = "PSNR is infinite for identical images (MSE = 0)"
    identical_value = math.inf

    region_variant = "on the edited region: MSE over the mask's pixels and channels; frames with an empty mask left out"

    def update_region(self, pred: np.ndarray, *, source: np.ndarray | None = None, reference: np.ndarray,
                      mask: np.ndarray) -> None:
        """Per-frame PSNR over the pixels of ``mask`` [B, H, W] (bool) only (see
        :meth:`~wcbench.metrics.base.Metric.update_region`)."""
        p, r = as_float_image_pair(pred, reference, names=("pred", "reference"))
        if mask.shape != p.shape[:3]:
            raise ValueError(f"psnr: mask is {mask.shape}, expected {p.shape[:3]} (the frames' batch, height, width)")
        for b in np.flatnonzero(mask.reshape(len(mask), -1).any(axis=1)):
            inside = mask[b]
            self._values.extend(_frame_psnr(p[b][inside][None, :, None], r[b][inside][None, :, None]).tolist())

    def frame_values(self, pred: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """Per-frame PSNR [B] in dB (inf for identical frames), frames in parallel (NumPy releases the
        GIL; one frame's float64 copies stay small)."""
        values = parallel_map(lambda k: _frame_psnr(pred[k:k + 1], reference[k:k + 1]), range(len(pred)))
        return np.concatenate(values) if values else np.zeros(0)
