"""The local executor: every unit in this process, one after the other (today's behaviour)."""

from __future__ import annotations

from collections.abc import Sequence

from wcbench.execution.base import Executor
from wcbench.units import RenderSettings, Scoring, UnitResult, WorkUnit, execute_unit, render_units

__all__ = ["LocalExecutor"]


class LocalExecutor(Executor):
    """Runs units in this process; bad input fails before any result is written.

    Every unit to score is decoded (:meth:`WorkUnit.validate`) before the first one is scored, so a
    corrupt frame anywhere stops the run before it writes anything; the decoded frames are kept for
    scoring as far as :data:`~wcbench.units.FRAME_CACHE` allows, so most are decoded only once.
    """

    name = "local"

    def render(self, plan: Sequence[Sequence[WorkUnit]], settings: RenderSettings) -> None:
        """Render the units in order; a method does its scene-level work in its first ``prepare``."""
        render_units([u for scene_units in plan for u in scene_units], settings)

    def score(self, units: Sequence[WorkUnit], scoring: Scoring, keys: Sequence[str]) -> list[UnitResult]:
        """Validate every unit left to score, then score them in order (kept results are reused)."""
        todo = [u for u, k in zip(units, keys) if u.cached_result(scoring.out, k) is None]
        for u in todo:
            u.validate(size=u.scored_size(scoring.resolution, scoring.score_size), keep=scoring.share_frames,
                       workers=None if scoring.prefetch_frames else 1, show_progress=scoring.show_progress)
        return [execute_unit(u, scoring, key=k) for u, k in zip(units, keys)]
