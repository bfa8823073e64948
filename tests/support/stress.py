"""Sizes and counts of the stress suites (tests/stress): a quick pass with the other tests, the full
counts under ``WCBENCH_STRESS=full`` (``tox -e stress``).

Every suite adds the cases it tries to ``case_counter`` (:data:`COUNTS`) and checks its outputs for
NaN and Inf through :func:`finite`, which counts each output checked and each non-finite one before
the test asserts on it. The counts are printed at the end of the run and, with
``WCBENCH_STRESS_JSON=PATH``, written as a benchmark JSON (suite ``stress``, the schema of
``wcbench/bench/schema.py``) by :func:`stress_report`.
"""

from __future__ import annotations

import os
import re
from collections import Counter
from typing import Any

import numpy as np

#: ``WCBENCH_STRESS=full``: the full counts; anything else: the quick pass.
FULL = os.environ.get("WCBENCH_STRESS", "").lower() == "full"
#: Where to write the run's counts as JSON (a path relative to where pytest was started), if set.
JSON_ENV = "WCBENCH_STRESS_JSON"
#: The unit of a family's ``error`` in the JSON: outputs or gradients with a NaN or Inf.
NONFINITE_UNIT = "non-finite outputs"


def cases(quick: int, full: int) -> int:
    """How many cases a suite tries: ``full`` under ``WCBENCH_STRESS=full``, else ``quick``."""
    return full if FULL else quick


class StressCounts:
    """Per family (``"suite: what"``): cases tried, outputs checked for NaN and Inf, the cases
    among them with a checked output, and the outputs that held a NaN or Inf.

    A family counts a case with ``counts.cases[family] += 1`` before it computes anything, then
    passes each output that must be finite to :meth:`finite` (or a yes/no check to :meth:`record`)
    and asserts on the answer: the count is kept whatever the test does next. Every example a test
    body runs is a case, including those Hypothesis discards (a draw inside the test that overran)
    and, after a failure, those it tries while shrinking: the counts describe the examples tried,
    not distinct failures.
    """

    def __init__(self) -> None:
        self.cases: Counter[str] = Counter()
        self.checked: Counter[str] = Counter()
        self.cases_checked: Counter[str] = Counter()
        self.nonfinite: Counter[str] = Counter()
        self._last_case: dict[str, int] = {}

    def record(self, family: str, ok: bool) -> bool:
        """Count one output of ``family`` checked for NaN and Inf (``ok``: it held none); returns ``ok``."""
        self.checked[family] += 1
        if self._last_case.get(family) != self.cases[family]:  # the first output of this case
            self._last_case[family] = self.cases[family]
            self.cases_checked[family] += 1
        if not ok:
            self.nonfinite[family] += 1
        return ok

    def finite(self, family: str, x: Any) -> bool:
        """Whether ``x`` (a number, array or torch tensor, any shape) holds no NaN or Inf, counted
        under ``family`` (:meth:`record`)."""
        a = x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x, dtype=np.float64)
        return self.record(family, bool(np.all(np.isfinite(a))))

    def total(self) -> tuple[int, int]:
        """(cases tried, non-finite outputs) over every family."""
        return sum(self.cases.values()), sum(self.nonfinite.values())


#: The counts of this run (``case_counter`` is its ``cases``).
STRESS = StressCounts()
#: Cases tried per family, printed at the end of the run (tests/stress/conftest.py).
COUNTS = STRESS.cases
finite = STRESS.finite
record = STRESS.record


def case_name(family: str) -> str:
    """The JSON case name of a family: ``"hostile numbers: metric psnr"`` -> ``numbers_metric_psnr``."""
    return re.sub(r"[^a-z0-9]+", "_", family.lower().removeprefix("hostile ")).strip("_")


def stress_report(counts: StressCounts, *, full: bool, command: str, exit_status: int, seconds: float,
                  load: tuple[float, float], commit: str | None, code: dict[str, Any] | None) -> dict[str, Any]:
    """The run's counts as a benchmark JSON object (suite ``stress``).

    Parameters
    ----------
    counts : StressCounts
        What the run counted.
    full : bool
        Whether the run had the full counts (``WCBENCH_STRESS=full``).
    command : str
        The command line that ran the suites.
    exit_status : int
        pytest's exit status (0: every test passed).
    seconds : float
        Wall time of the run, s.
    load : (float, float)
        1-minute load average at the start and the end of the run (the machine may be shared).
    commit : str or None
        The repository's commit (``+dirty`` with uncommitted changes to tracked files), if known.
    code : dict or None
        The digests of the code measured, taken as the run started
        (``wcbench.bench.code_version.measured_code("stress")``).

    Returns
    -------
    dict
        The schema of ``wcbench/bench/schema.py`` (with ``code`` and ``command``) plus
        ``exit_status``, ``commit`` and ``totals`` (in all, and per suite under ``parts``:
        ``numbers``, ``files``, ``faults``). One case per family: ``value`` its cases,
        ``error`` its non-finite outputs (``null`` for families that check no numbers: files,
        faults), ``outputs_checked`` and ``cases_checked`` (cases that computed outputs rather
        than raising a clean error).

    Raises
    ------
    ValueError
        When two families would get the same case name.
    """
    from wcbench.bench.schema import BenchCase, BenchReport
    from wcbench.core.environment import package_versions

    n_cases, n_nonfinite = counts.total()
    n_checked = sum(counts.checked.values())
    report = BenchReport(suite="stress", notes=[
        f"{'full' if full else 'quick'} pass (WCBENCH_STRESS={'full' if full else 'unset'}), "
        f"pytest exit status {exit_status} ({'every test passed' if exit_status == 0 else 'FAILED'})",
        f"{n_cases:,d} cases in all, {n_nonfinite:,d} non-finite of {n_checked:,d} outputs checked for NaN and Inf",
        f"wall time {seconds / 60:.1f} min; 1-minute load average {load[0]:.2f} at the start, {load[1]:.2f} at the "
        "end (a shared machine: times move with it, counts do not)",
        "value: cases tried (every example a test ran: a few more than Hypothesis' max_examples where a draw "
        "inside the test overran); error: outputs or gradients with a NaN or Inf (null: the family checks exit "
        "codes and files, not numbers); cases_checked: cases that computed outputs instead of raising a clean "
        "error",
    ])
    for family in sorted(counts.cases):
        checked = counts.checked[family]
        report.cases.append(BenchCase(
            name=case_name(family), knob="cases", value=counts.cases[family], time_ms=None,
            error=counts.nonfinite[family] if checked else None, error_unit=NONFINITE_UNIT if checked else "n/a",
            extra={"family": family, "outputs_checked": checked, "cases_checked": counts.cases_checked[family]}))
    report.code, report.command = code, command
    obj = report.to_json()  # raises on duplicate case names
    obj["versions"] = package_versions(("hypothesis", "pytest"))
    parts: dict[str, dict[str, int]] = {}
    for case in obj["cases"]:  # per suite: numbers, files, faults (the case names' first word)
        part = parts.setdefault(case["name"].split("_")[0], dict.fromkeys(
            ("cases", "cases_checked", "outputs_checked", "nonfinite_outputs"), 0))
        part["cases"] += case["value"]
        part["cases_checked"] += case["cases_checked"]
        part["outputs_checked"] += case["outputs_checked"]
        part["nonfinite_outputs"] += case["error"] or 0
    obj.update(exit_status=exit_status, commit=commit,
               totals={"cases": n_cases, "outputs_checked": n_checked, "nonfinite_outputs": n_nonfinite,
                       "parts": parts})
    return obj
