"""The stress suites: hostile files, faults (kills, concurrent runs, read-only and full outputs) and
hostile numbers. A quick pass runs with the other tests; ``WCBENCH_STRESS=full`` (``tox -e stress``)
runs the full counts (tests/support/stress.py). Each suite adds the cases it tried to
``case_counter`` and counts the outputs it checks for NaN and Inf; the counts are printed at the end
of the run and, with ``WCBENCH_STRESS_JSON=PATH``, written there as a benchmark JSON."""

from __future__ import annotations

import os
import shlex
import subprocess
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest
from stress import COUNTS, FULL, JSON_ENV, STRESS, stress_report

#: When this conftest was loaded (the stress tests' collection) and the load then.
_START = (time.perf_counter(), os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan"))
#: The code the run measures, as it starts (only when the counts are written: it reads every file).
_CODE: dict | None = None
if os.environ.get(JSON_ENV):
    from wcbench.bench.code_version import measured_code

    _CODE = measured_code("stress")
#: Where the JSON went (printed in the summary).
_WRITTEN: list[Path] = []


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


def _commit(root: Path) -> str | None:
    """HEAD of the repository at ``root``, ``+dirty`` with uncommitted changes to tracked files."""
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):  # no git, or not a checkout (an sdist)
        return None
    return head + ("+dirty" if dirty else "")


def pytest_configure(config: pytest.Config) -> None:
    """Refuse to write the counts from several processes: each pytest-xdist worker would hold a part."""
    # a worker's config has `workerinput`; the environment variable would also reach a pytest it starts
    if os.environ.get(JSON_ENV) and (config.getoption("numprocesses", default=None) or hasattr(config, "workerinput")):
        raise pytest.UsageError(f"{JSON_ENV} writes one process's counts: run the stress suites without -n")


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Fail a run that counted a non-finite output (each is also asserted where it is checked), then
    write the counts to ``$WCBENCH_STRESS_JSON`` when it is set."""
    if sum(STRESS.nonfinite.values()) and exitstatus == pytest.ExitCode.OK:
        session.exitstatus = exitstatus = pytest.ExitCode.TESTS_FAILED
    target = os.environ.get(JSON_ENV)
    if not target or not COUNTS:
        return
    from wcbench.core.storage import atomic_write_json

    params = session.config.invocation_params
    # the tests run in a temporary working directory (tests/conftest.py): relative to where pytest started
    path = params.dir / target
    shown = {"WCBENCH_STRESS": os.environ.get("WCBENCH_STRESS"),  # the JSON's path as seen from there
             JSON_ENV: path.relative_to(params.dir).as_posix() if path.is_relative_to(params.dir) else target}
    env = " ".join(f"{k}={shlex.quote(v)}" for k, v in shown.items() if v)
    tox = os.environ.get("TOX_ENV_NAME")
    command = f"{env} pytest {shlex.join(params.args)}" + (f" (tox env {tox})" if tox else "")
    load_end = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    obj = stress_report(STRESS, full=FULL, command=command, exit_status=int(exitstatus),
                        seconds=time.perf_counter() - _START[0], load=(_START[1], load_end),
                        commit=_commit(session.config.rootpath), code=_CODE)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, obj)
    _WRITTEN.append(path)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if not COUNTS:
        return
    terminalreporter.section(f"stress cases ({'full' if FULL else 'quick'} pass)")
    terminalreporter.write_line(f"{'cases':>9}  {'checked':>9}  {'NaN/Inf':>7}  family")
    for name, n in sorted(COUNTS.items()):
        checked = f"{STRESS.checked[name]:>9,d}  {STRESS.nonfinite[name]:>7,d}" if STRESS.checked[name] else \
            f"{'-':>9}  {'-':>7}"
        terminalreporter.write_line(f"{n:>9,d}  {checked}  {name}")
    n_cases, n_nonfinite = STRESS.total()
    terminalreporter.write_line(f"{n_cases:>9,d}  {sum(STRESS.checked.values()):>9,d}  {n_nonfinite:>7,d}  in all")
    for path in _WRITTEN:
        terminalreporter.write_line(f"counts written to {path}")
