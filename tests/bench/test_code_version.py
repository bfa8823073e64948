"""The digests of the code a benchmark measures (wcbench.bench.code_version) and their record in the
JSON that ``wcbench bench`` writes; the digest itself is tested in tests/core/test_code_digest.py."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from wcbench.bench import MEASURES, SUITES
from wcbench.bench.code_version import code_changes, measured_code
from wcbench.bench.overview import run_all
from wcbench.bench.schema import bench_command, validate_benchmark
from wcbench.cli import main


def test_every_suite_declares_the_code_it_measures_and_each_resolves() -> None:
    # and the stress suites, whose JSON tests/stress/conftest.py writes
    assert set(MEASURES) == {*SUITES, "stress"}
    memo: dict[str, str] = {}
    for suite in MEASURES:
        code = measured_code(suite, memo=memo)
        assert code is not None and set(code["digests"]) == set(MEASURES[suite])
        assert suite == "stress" or f"wcbench.bench.{suite}" in code["digests"]  # its own module, at least
    assert measured_code("another_package_suite") is None
    assert code_changes({"suite": "another_package_suite"}) == [
        "suite 'another_package_suite' declares no measured code (wcbench.bench.MEASURES)"]


def test_taking_the_digests_imports_no_measured_module() -> None:
    """The torch-free test environments check the docs' JSON too: finding the files must not
    import what they measure (torch, numba)."""
    code = ("import sys; from wcbench.bench import MEASURES; from wcbench.bench.code_version import measured_code; "
            "[measured_code(s) for s in MEASURES]; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'numba', 'cv2')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_bench_records_the_code_and_the_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(SUITES, "fake", "bench_fakes:run")
    monkeypatch.setitem(MEASURES, "fake", ("wcbench.bench.schema",))
    monkeypatch.setenv("WCBENCH_BENCH_FAKE_GROUPS", "headline")
    out = tmp_path / "fake.json"
    assert main(["bench", "fake", "--quick", "--out", str(out)]) == 0
    obj = json.loads(out.read_text())
    validate_benchmark(obj)
    assert obj["code"] == measured_code("fake") and code_changes(obj) == []
    assert obj["command"] == f"WCBENCH_BENCH_FAKE_GROUPS=headline wcbench bench fake --quick --out {out}"

    obj["code"]["digests"]["wcbench.bench.schema"] = "0" * 64
    assert code_changes(obj) == ["wcbench.bench.schema changed"]
    obj["code"] = "0.1.0"
    with pytest.raises(ValueError, match="not a record of digests"):
        validate_benchmark(obj)


def test_bench_all_records_each_suite_alone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import bench_fakes

    monkeypatch.setitem(MEASURES, "fake", ("wcbench.bench.schema",))
    run_all({"fake": bench_fakes.run}, out=tmp_path, data_root=None, quick=True, echo=lambda line: None,
            command=lambda suite: f"wcbench bench {suite} --out {tmp_path / suite}.json")
    obj = json.loads((tmp_path / "fake.json").read_text())
    assert obj["code"] == measured_code("fake") and obj["command"] == f"wcbench bench fake --out {tmp_path}/fake.json"


def test_bench_command_quotes_what_needs_it() -> None:
    assert bench_command(["bench", "model", "--data-root", "my data"], environ={
        "WCBENCH_BENCH_MODEL_GROUPS": "knobs,skips", "WCBENCH_DATA": "/d", "HOME": "/h"}) == \
        "WCBENCH_BENCH_MODEL_GROUPS=knobs,skips wcbench bench model --data-root 'my data'"
