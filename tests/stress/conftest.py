"""The stress suites: hostile files, faults (kills, concurrent runs, read-only and full outputs) and
hostile numbers. A quick pass runs with the other tests; ``WCBENCH_STRESS=full`` (``tox -e stress``)
runs the full counts (tests/support/stress.py). Each suite adds the cases it tried to
``case_counter``, and the counts are printed at the end of the run."""

from __future__ import annotations

from collections import Counter

import pytest
from stress import COUNTS, FULL


@pytest.fixture(scope="session")
def case_counter() -> Counter[str]:
    """Add ``counter["suite: what"] += n`` for every case tried; the totals are printed at the end."""
    return COUNTS


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if not COUNTS:
        return
    terminalreporter.section(f"stress cases ({'full' if FULL else 'quick'} pass)")
    for name, n in sorted(COUNTS.items()):
        terminalreporter.write_line(f"{n:>9,d}  {name}")
