"""Metrics for weather editing: a functional API on float RGB arrays in [0, 1] and Metric classes.

Functional forms (images [H, W, 3] or [T, H, W, 3], float RGB in [0, 1] or uint8):

- :func:`clip_s`, :func:`clip_ds` (CLIP-S and both CLIP-DS forms; need CLIP weights in the model
  store, see ``wcbench models``);
- :func:`sem_cs` (frequency-weighted IoU of two label maps or segmentations);
- :func:`lpips` (``net="alex"`` or ``"vgg"``), :func:`psnr`, :func:`ssim` against a reference;
- :func:`temporal_flicker` and :func:`flow_warping_error` on sequences [T, H, W, 3] (``flow_warp_error``
  is its deprecated alias, kept for one release).

Metric classes (update/compute) are listed by ``wcbench metrics list`` and resolved through
:data:`wcbench.metrics.registry.METRICS`. Names are imported on first use, so importing this
package imports neither torch nor onnxruntime.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from wcbench.core.models.store import ModelStore
    from wcbench.core.models.store_errors import ModelMissingError
    from wcbench.metrics.base import Metric, MetricContext, MetricValue
    from wcbench.metrics.clip.score import clip_ds, clip_s
    from wcbench.metrics.perceptual.lpips import lpips
    from wcbench.metrics.pixel.psnr import psnr
    from wcbench.metrics.pixel.ssim import ssim
    from wcbench.metrics.semantic.consistency import sem_cs
    from wcbench.metrics.temporal.flicker import flow_warp_error, flow_warping_error, temporal_flicker

_LAZY = {
    "Metric": "wcbench.metrics.base",
    "MetricContext": "wcbench.metrics.base",
    "MetricValue": "wcbench.metrics.base",
    "clip_s": "wcbench.metrics.clip.score",
    "clip_ds": "wcbench.metrics.clip.score",
    "flow_warping_error": "wcbench.metrics.temporal.flicker",
    "flow_warp_error": "wcbench.metrics.temporal.flicker",  # deprecated alias of flow_warping_error
    "temporal_flicker": "wcbench.metrics.temporal.flicker",
    "lpips": "wcbench.metrics.perceptual.lpips",
    "ModelStore": "wcbench.core.models.store",
    "ModelMissingError": "wcbench.core.models.store",
    "psnr": "wcbench.metrics.pixel.psnr",
    "sem_cs": "wcbench.metrics.semantic.consistency",
    "ssim": "wcbench.metrics.pixel.ssim",
}

__all__ = [
    "Metric",
    "MetricContext",
    "MetricValue",
    "ModelMissingError",
    "ModelStore",
    "clip_ds",
    "clip_s",
    "flow_warp_error",
    "flow_warping_error",
    "lpips",
    "psnr",
    "sem_cs",
    "ssim",
    "temporal_flicker",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
