"""FPS of a method: from its ``info.json`` timings or the user's ``--fps``; never guessed."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from wcbench.core.options import Option
from wcbench.metrics.base import Metric, MetricContext, MetricValue


class FPS(Metric):
    """Frames per second as the method reported (median frame time after warm-up)."""

    name = "fps"
    description = "frames per second: median whole-frame time from info.json, or --fps"
    outputs = ("fps",)
    higher_is_better = True
    reads_frames = False
    OPTIONS: ClassVar[dict[str, Option] | None] = {}  # the frame rate is --fps, given to every unit

    def __init__(self) -> None:
        self._ctx: MetricContext | None = None

    def bind(self, ctx: MetricContext) -> None:
        """Remember where the timing comes from."""
        self._ctx = ctx

    def _source(self) -> tuple[float | None, str, dict[str, Any]]:
        ctx = self._ctx
        if ctx is None:
            return None, "", {}
        if ctx.fps_override is not None:
            return float(ctx.fps_override), "--fps given by the user", {}
        timings = (ctx.method_info or {}).get("timings") or {}
        if timings.get("fps"):
            keep = ("resolution", "machine", "median_frame_ms", "warmup_frames")
            extra = {k: timings[k] for k in keep if k in timings}
            return float(timings["fps"]), "info.json timings: 1000 / median frame ms after warm-up", extra
        reported = (ctx.method_info or {}).get("fps")
        if reported:
            return float(reported), "info.json 'fps' field as reported by the tool", {}
        return None, "", {}

    def skip_reason(self, ctx: MetricContext) -> str | None:
        """Skipped when neither info.json nor --fps gives a frame rate."""
        self.bind(ctx)
        if self._source()[0] is None:
            return "no timing: the predictions have no info.json with timings and --fps was not given"
        return None

    def reset(self) -> None:
        """Nothing to accumulate."""

    def update(self, pred: np.ndarray, *, source: np.ndarray | None = None,
               reference: np.ndarray | None = None) -> None:
        """Frames are not needed."""

    def compute(self) -> dict[str, MetricValue]:
        """The frame rate and where it came from."""
        fps, variant, extra = self._source()
        if fps is None:
            return {"fps": MetricValue(None, reason="no timing available", variant="")}
        return {"fps": MetricValue.from_number(fps, nonfinite_reason="invalid timing", variant=variant, extra=extra)}
