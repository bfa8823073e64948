"""The metric registry: names -> metric classes, imported lazily.

Packages add metrics through the entry-point group ``wcbench.metrics`` (a Metric subclass).
Each metric declares the options of its constructor (:attr:`Metric.OPTIONS`), checked by
:func:`validate_metric_options` before any work (docs/guide.md, "Metric options").
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

from wcbench.core.options import Option, OptionError, describe_value, validate_options
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


def _any_value(value: Any) -> Any:
    return value


def metric_schema(name: str) -> dict[str, Option]:
    """The declared options of the metric registered as ``name`` (:attr:`Metric.OPTIONS`: type, range
    or choices, default, meaning of each keyword of its constructor). A metric that declares none (a
    plugin's) has its keyword parameters, each taking any value (and, with ``**options``, any key:
    :func:`validate_metric_options`).

    Raises
    ------
    UnknownNameError
    """
    cls = METRICS.get(name)
    if cls.OPTIONS is not None:
        return dict(cls.OPTIONS)
    params = inspect.signature(cls.__init__).parameters
    return {p: Option(p, "custom", "an undeclared option of the metric's constructor", check=_any_value,
                      allowed="any value")
            for p, v in params.items() if p != "self" and v.kind in (v.KEYWORD_ONLY, v.POSITIONAL_OR_KEYWORD)}


def validate_metric_options(name: str, options: Mapping[str, Any]) -> dict[str, Any]:
    """Check ``options`` against the declared options of metric ``name`` (each one, then the rules
    between them: :meth:`Metric.check_options`) before anything is built, fetched or written;
    return them as the constructor takes them.

    Raises
    ------
    OptionError
        One line naming the metric, the first unknown option or bad value, and what is allowed
        (``metric option lpips.net=vgg2: expected one of 'alex', 'vgg'``), spelled as
        ``--metric-option`` takes it.
    UnknownNameError
    """
    cls = METRICS.get(name)
    params = inspect.signature(cls.__init__).parameters.values()
    if cls.OPTIONS is None and any(p.kind is p.VAR_KEYWORD for p in params):
        return dict(options)  # an undeclared plugin taking **options: only the metric itself can tell
    values = validate_options(metric_schema(name), options, prefix="metric option ", path=name,
                              owner=f"metric {name!r}")
    try:
        cls.check_options(values)
    except OptionError as exc:
        raise OptionError(f"metric option {name}.{exc.path}={describe_value(values.get(exc.path))}: {exc}",
                          path=f"{name}.{exc.path}") from None
    return values


def create_metric(name: str, **options: Any) -> Metric:
    """Instantiate the metric registered as ``name`` with ``options``, checked first
    (:func:`validate_metric_options`).

    Raises
    ------
    OptionError
        If the metric does not take one of ``options``, or not its value (one line saying what it
        takes).
    UnknownNameError
    """
    return METRICS.get(name)(**validate_metric_options(name, options))
