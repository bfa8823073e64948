"""The stress suites' counts (tests/support/stress.py) and their JSON (``WCBENCH_STRESS_JSON``):
cases, outputs checked for NaN and Inf and the non-finite ones, per family, in the benchmark schema."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from paths import REPO, TESTS
from stress import JSON_ENV, NONFINITE_UNIT, StressCounts, case_name, stress_report

from wcbench.bench.code_version import code_changes, measured_code
from wcbench.bench.schema import validate_benchmark


def _env(**extra: str) -> dict[str, str]:
    """This environment for a pytest subprocess: the quick pass (even inside ``tox -e stress``)."""
    env = {k: v for k, v in os.environ.items() if k not in ("WCBENCH_STRESS", JSON_ENV)}
    return {**env, **extra}


def test_counts_cases_outputs_and_nonfinite_per_family() -> None:
    counts = StressCounts()
    fog, files = "hostile numbers: fog x", "hostile files: y"
    counts.cases[fog] += 1
    assert counts.finite(fog, np.ones((2, 3), np.float32)) and counts.finite(fog, 0.5)
    counts.cases[fog] += 1
    assert not counts.finite(fog, [1.0, np.inf])
    assert not counts.record(fog, False)
    counts.cases[fog] += 1  # a case refused before any output: counted, not checked
    counts.cases[files] += 4
    assert (counts.cases[fog], counts.checked[fog], counts.cases_checked[fog], counts.nonfinite[fog]) == (3, 4, 2, 2)
    assert counts.total() == (7, 2)

    obj = stress_report(counts, full=False, command="pytest tests/stress", exit_status=1, seconds=3.0,
                        load=(0.5, 1.0), commit="abc", code=None)
    validate_benchmark(obj)
    json.dumps(obj, allow_nan=False)
    cases = {c["name"]: c for c in obj["cases"]}
    assert set(cases) == {"numbers_fog_x", "files_y"}
    assert cases["numbers_fog_x"] | {"time_ms": 0} == {
        "name": "numbers_fog_x", "knob": "cases", "value": 3, "time_ms": 0, "error": 2, "error_unit": NONFINITE_UNIT,
        "family": fog, "outputs_checked": 4, "cases_checked": 2}
    assert cases["files_y"]["value"] == 4 and cases["files_y"]["error"] is None  # checks no numbers
    assert obj["totals"] == {"cases": 7, "outputs_checked": 4, "nonfinite_outputs": 2, "parts": {
        "numbers": {"cases": 3, "cases_checked": 2, "outputs_checked": 4, "nonfinite_outputs": 2},
        "files": {"cases": 4, "cases_checked": 0, "outputs_checked": 0, "nonfinite_outputs": 0}}}
    assert obj["suite"] == "stress" and obj["exit_status"] == 1 and obj["commit"] == "abc"
    assert "hypothesis" in obj["versions"] and any("FAILED" in n for n in obj["notes"])


def test_families_whose_names_collide_are_refused() -> None:
    counts = StressCounts()
    counts.cases["hostile numbers: a-b"] += 1
    counts.cases["numbers: a b"] += 1
    assert case_name("hostile numbers: a-b") == case_name("numbers: a b") == "numbers_a_b"
    with pytest.raises(ValueError, match="duplicate case names"):
        stress_report(counts, full=True, command="", exit_status=0, seconds=1.0, load=(0.0, 0.0), commit=None,
                      code=None)


def test_a_tiny_run_writes_its_counts_where_it_was_started(tmp_path: Path) -> None:
    """One hostile-number test's quick pass in a new pytest: the JSON lands relative to the directory
    pytest started in (the tests themselves run elsewhere) and holds that test's family alone."""
    test = TESTS / "stress" / "test_hostile_numbers.py"
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--rootdir", str(REPO),
                           f"{test}::test_fog_density_and_visibility"], cwd=tmp_path, capture_output=True,
                          text=True, env=_env(**{JSON_ENV: "out/stress.json"}), timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    obj = json.loads((tmp_path / "out" / "stress.json").read_text())
    validate_benchmark(obj)
    assert [c["family"] for c in obj["cases"]] == ["hostile numbers: fog density <-> visibility"]
    (case,) = obj["cases"]
    assert case["value"] >= 200 and case["error"] == 0 and 0 < case["cases_checked"] <= case["value"]
    assert case["outputs_checked"] >= case["cases_checked"]
    assert obj["exit_status"] == 0 and obj["totals"]["cases"] == case["value"]
    assert obj["code"] == measured_code("stress") and code_changes(obj) == []  # fresh: the docs test's check
    assert obj["command"].startswith(f"{JSON_ENV}=out/stress.json pytest ") and "test_fog_density" in obj["command"]
    assert "quick pass" in obj["notes"][0] and "counts written to" in proc.stdout


def test_a_counted_nonfinite_output_fails_the_run_even_unasserted(tmp_path: Path) -> None:
    """The stress conftest fails a run that counted a NaN or Inf although no test asserted on it,
    and the JSON says so."""
    shutil.copy(TESTS / "stress" / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "test_tiny.py").write_text(
        "from stress import COUNTS, finite\n\n\n"
        "def test_unasserted():\n"
        "    COUNTS['hostile numbers: tiny'] += 1\n"
        "    finite('hostile numbers: tiny', [1.0, float('nan')])\n", encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-c",
                           str(REPO / "pyproject.toml"), "--rootdir", str(REPO), str(tmp_path / "test_tiny.py")],
                          cwd=tmp_path, capture_output=True, text=True, env=_env(**{JSON_ENV: "s.json"}), timeout=300)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    obj = json.loads((tmp_path / "s.json").read_text())
    assert obj["exit_status"] == 1 and obj["totals"]["nonfinite_outputs"] == 1
    assert obj["totals"]["parts"] == {"numbers": {"cases": 1, "cases_checked": 1, "outputs_checked": 1,
                                                  "nonfinite_outputs": 1}}
