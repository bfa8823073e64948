"""PSNR against a ground-truth sequence (reference-based; synthetic scenes and ``clear``)."""

from __future__ import annotations

import numpy as np

from wcbench.metrics.base import (
    Metric,
    MetricValue,
    as_float_images,
    check_same_shape,
    finite_or_none,
)

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


class PSNR(Metric):
    """Peak signal-to-noise ratio per frame, averaged over the sequence (dB)."""

    name = "psnr"
    description = "PSNR (dB) against the ground-truth sequence; needs a reference"
    outputs = ("psnr",)
    higher_is_better = True
    needs_reference = True

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the per-frame MSEs."""
        self._mse: list[float] = []

    def update(self, pred: np.ndarray, *, source: np.ndarray | None = None,
               reference: np.ndarray | None = None) -> None:
        """Accumulate per-frame MSE of ``pred`` [B, H, W, 3] against ``reference``."""
        if reference is None:
            raise ValueError("psnr: a reference batch is required")
        p, r = as_float_images(pred, name="pred"), as_float_images(reference, name="reference")
        check_same_shape(p, r, names=("pred", "reference"))
        self._mse.extend(_squared_errors(p, r).tolist())

    def compute(self) -> dict[str, MetricValue]:
        """Mean per-frame PSNR; identical frames give inf, stored as null with a reason."""
        per = _psnr_from_mse(np.asarray(self._mse, np.float64))
        return {
            "psnr": MetricValue.from_number(
                float(np.mean(per)) if per.size else float("nan"),
                nonfinite_reason="PSNR is infinite for identical images (MSE = 0)" if per.size else "no frames",
                per_frame=finite_or_none(per), variant=_VARIANT,
            )
        }
