"""Timing harness for FPS: per-frame wall times, warm-up excluded, median reported.

FPS times the whole frame a method produces (everything ``render_frame`` does), not only a
rasterizer, and records the resolution and the machine it ran on.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from wcbench.core.environment import machine_info


@dataclass
class FrameTimer:
    """Collects per-frame wall times in milliseconds.

    Parameters
    ----------
    warmup : int
        Leading frames excluded from the FPS (caches, JIT compilation).
    """

    warmup: int = 1
    frame_ms: list[float] = field(default_factory=list)

    @contextmanager
    def frame(self) -> Iterator[None]:
        """Time one frame: ``with timer.frame(): render()``."""
        start = time.perf_counter()
        yield
        self.frame_ms.append((time.perf_counter() - start) * 1e3)

    def summary(self, *, width: int, height: int) -> dict[str, Any]:
        """FPS summary for ``info.json``: median over frames after warm-up (all if too few)."""
        timed = self.frame_ms[self.warmup :] or self.frame_ms
        median = statistics.median(timed) if timed else float("nan")
        return {
            "frame_ms": [round(v, 3) for v in self.frame_ms],
            "warmup_frames": min(self.warmup, len(self.frame_ms)),
            "median_frame_ms": median,
            "fps": 1e3 / median if timed and median > 0 else None,
            "resolution": [width, height],
            "machine": machine_info(),
            "scope": "whole frame as produced by the method (render + weather + post-process)",
        }
