"""The metric registry: names -> metric classes, imported lazily.

Packages add metrics through the entry-point group ``wcbench.metrics`` (a Metric subclass).
"""

from __future__ import annotations

import inspect
from typing import Any

from wcbench.core.errors import InputError
from wcbench.core.registry import LazyRegistry
from wcbench.metrics.base import Metric

METRICS: LazyRegistry[type[Metric]] = LazyRegistry(
    "metric",
    {
        "psnr": "wcbench.metrics.pixel.psnr:PSNR",
        "ssim": "wcbench.metrics.pixel.ssim:SSIM",
        "temporal_flicker": "wcbench.metrics.temporal.flicker:TemporalFlicker",
        "flow_warping_error": "wcbench.metrics.temporal.flicker:FlowWarpingError",
        "fps": "wcbench.metrics.fps:FPS",
        "clip_s": "wcbench.metrics.clip.score:ClipScore",
        "clip_ds": "wcbench.metrics.clip.score:ClipDirectionalScore",
        "sem_cs": "wcbench.metrics.semantic.consistency:SemanticConsistency",
        "lpips": "wcbench.metrics.perceptual.lpips:LPIPS",
    },
)

#: What ``wcbench evaluate`` computes when ``--metrics`` is not given. Model-based metrics whose
#: weights are not installed are reported as skipped with the command that installs them.
DEFAULT_METRICS = (
    "clip_s", "clip_ds", "sem_cs", "psnr", "ssim", "lpips", "temporal_flicker", "flow_warping_error", "fps",
)


def create_metric(name: str, **options: Any) -> Metric:
    """Instantiate the metric registered as ``name`` with ``options``.

    Raises
    ------
    InputError
        If the metric does not take one of ``options`` (the message lists the ones it takes).
    """
    cls = METRICS.get(name)
    params = inspect.signature(cls.__init__).parameters
    accepted = [p for p in params if p != "self" and params[p].kind is not inspect.Parameter.VAR_KEYWORD]
    unknown = sorted(set(options) - set(accepted))
    if unknown and not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        takes = ", ".join(accepted) or "none"
        raise InputError(f"metric {name!r} has no option {', '.join(unknown)}; it takes: {takes}")
    return cls(**options)
