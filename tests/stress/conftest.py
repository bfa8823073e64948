"""The stress suites: hostile files, faults (kills, concurrent runs, read-only and full outputs) and
hostile numbers. A quick pass runs with the other tests; ``WCBENCH_STRESS=full`` (``tox -e stress``)
runs the full counts (tests/support/stress.py). Each suite adds the cases it tried to
``case_counter``, and the counts are printed at the end of the run."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator

import pytest
from stress import COUNTS, FULL


@pytest.fixture(scope="session")
def case_counter() -> Counter[str]:
    """Add ``counter["suite: what"] += n`` for every case tried; the totals are printed at the end."""
    return COUNTS


@pytest.fixture(scope="package", autouse=True)
def _examples_from_the_tests_alone() -> Iterator[None]:
    """Make ``derandomize=True`` mean the same examples in every run.

    Recent Hypothesis (6.170 here) also draws floats, integers and strings that it collects from the
    source of every non-test module of this repository in ``sys.modules`` ("local constants"). That
    pool depends on which modules earlier tests imported and on edits to any of them, so the
    hostile-number suite tried different examples after ``tests/reference_model/weather`` or the
    CLI tests than alone, and a rasterizer bug showed up "only sometimes". Here the pool is empty
    (Hypothesis' own constants stay): the examples depend on the tests alone. Private API, hence
    the guards; without it the suite still runs, only less reproducibly.
    """
    try:
        from hypothesis.internal.conjecture import providers
    except ImportError:
        yield
        return
    if not (hasattr(providers, "_get_local_constants") and hasattr(providers, "Constants")
            and hasattr(getattr(providers, "CONSTANTS_CACHE", None), "cache")):
        yield
        return
    empty = providers.Constants()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(providers, "_get_local_constants", lambda: empty)
        providers.CONSTANTS_CACHE.cache.clear()  # it holds the pool of earlier tests
        yield
    providers.CONSTANTS_CACHE.cache.clear()


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if not COUNTS:
        return
    terminalreporter.section(f"stress cases ({'full' if FULL else 'quick'} pass)")
    for name, n in sorted(COUNTS.items()):
        terminalreporter.write_line(f"{n:>9,d}  {name}")
