"""The metric registry: names -> metric classes, imported lazily.

Packages add metrics through the entry-point group ``wcbench.metrics`` (a Metric subclass).
"""

from __future__ import annotations

from typing import Any

from wcbench.metrics.base import Metric
from wcbench.registry import LazyRegistry

METRICS: LazyRegistry[type[Metric]] = LazyRegistry(
    "metric",
    {
        "psnr": "wcbench.metrics.psnr:PSNR",
        "ssim": "wcbench.metrics.ssim:SSIM",
        "temporal_flicker": "wcbench.metrics.flicker:TemporalFlicker",
        "flow_warping_error": "wcbench.metrics.flicker:FlowWarpingError",
        "fps": "wcbench.metrics.fps:FPS",
        "clip_s": "wcbench.metrics.clip_score:ClipScore",
        "clip_ds": "wcbench.metrics.clip_score:ClipDirectionalScore",
    },
)

#: What ``wcbench evaluate`` computes when ``--metrics`` is not given. Model-based metrics whose
#: weights are not installed are reported as skipped with the command that installs them.
DEFAULT_METRICS = ("clip_s", "clip_ds", "psnr", "ssim", "temporal_flicker", "flow_warping_error", "fps")


def create_metric(name: str, **options: Any) -> Metric:
    """Instantiate the metric registered as ``name`` with ``options``."""
    return METRICS.get(name)(**options)
