"""The executor interface and the error a distributed run reports its failed units with."""

from __future__ import annotations

import traceback
from abc import ABC, abstractmethod
from collections.abc import Sequence
from types import TracebackType

from wcbench.core.errors import WcbenchError
from wcbench.units import RenderSettings, Scoring, UnitResult, WorkUnit

__all__ = ["Executor", "UnitsFailedError"]


class Executor(ABC):
    """Runs planned units: renders them (``wcbench run``) and scores them.

    Executors are context managers; :meth:`close` releases what they started (a cluster).
    """

    #: Registry name (``"local"``, ``"dask"``).
    name: str

    @abstractmethod
    def render(self, plan: Sequence[Sequence[WorkUnit]], settings: RenderSettings) -> None:
        """Render every unit of a runnable method; ``plan`` groups the units by scene.

        A scene's shared work (:meth:`~wcbench.methods.runnable.FrameRenderer.setup_scene`, e.g.
        training) happens once, before its weathers render. Finished folders are left alone.
        """

    @abstractmethod
    def score(self, units: Sequence[WorkUnit], scoring: Scoring, keys: Sequence[str]) -> list[UnitResult]:
        """Score every opened unit whose result is not kept under its key yet; the results of all.

        Parameters
        ----------
        units : sequence of WorkUnit
            Opened (:meth:`WorkUnit.open`).
        scoring : Scoring
        keys : sequence of str
            Each unit's key (:meth:`WorkUnit.key`), in the order of ``units``.

        Returns
        -------
        list of UnitResult
            In the order of ``units``, each read from its unit file in ``scoring.out``.
        """

    def close(self) -> None:  # noqa: B027 - nothing to release by default
        """Release what the executor started."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


class UnitsFailedError(WcbenchError):
    """Units of a distributed run failed; the others finished and are kept in ``OUT/.work/``.

    The message names each failed unit with its error (input errors as their message, anything
    else with the end of its traceback). Exit status 2 when every failure is an input error, 1
    otherwise.
    """

    def __init__(self, failures: Sequence[tuple[str, BaseException]], *, finished: int, phase: str):
        lines = []
        for label, exc in failures:
            if isinstance(exc, WcbenchError):
                text = str(exc)
            else:
                text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__, limit=-3)).rstrip()
            lines.append(f"  {label}: " + text.replace("\n", "\n    "))
        super().__init__(
            f"{len(failures)} unit(s) failed while {phase}, {finished} finished (kept; a re-run only redoes "
            "the failed ones):\n" + "\n".join(lines)
        )
        self.failures = list(failures)
        self.exit_code = 2 if all(isinstance(e, WcbenchError) for _, e in failures) else 1
