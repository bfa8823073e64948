"""The digest of the code a benchmark measures (wcbench.bench.code_version) and its record in the
JSON that ``wcbench bench`` writes."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from wcbench.bench import MEASURES, SUITES
from wcbench.bench.code_version import code_changes, code_text, measured_code, source_digest
from wcbench.bench.overview import run_all
from wcbench.bench.schema import bench_command, validate_benchmark
from wcbench.cli import main

_MODULE = '''"""A module."""

import math  # the one import

RATE = 2.0
"""The rate (a documented attribute)."""


def area(r):
    """Area of a circle.

    Of radius ``r``.
    """
    # pi r^2
    return math.pi * r ** RATE  # exact
'''


@pytest.fixture
def package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An importable package ``digestpkg`` of a module and a TOML data file."""
    root = tmp_path / "digestpkg"
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text("")
    (root / "sub" / "geometry.py").write_text(_MODULE)
    (root / "presets.toml").write_text("# presets\nrate = 2.0\n")
    (root / "notes.md").write_text("not code")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    return root


def test_code_text_leaves_out_comments_docstrings_and_blank_lines() -> None:
    assert code_text(_MODULE) == ("import math\nRATE = 2.0\ndef area(r):\n    return math.pi * r ** RATE")
    kept = 'x = 1; "not alone on its line"\ny = f("an argument")  # a comment\n'
    assert code_text(kept) == 'x = 1; "not alone on its line"\ny = f("an argument")'
    with pytest.raises(ValueError, match=r"m\.py: not valid Python"):
        code_text("def (", name="m.py")


def test_the_digest_follows_the_code_not_its_prose(package: Path) -> None:
    module = package / "sub" / "geometry.py"
    before = source_digest("digestpkg")
    assert source_digest("digestpkg.sub.geometry") != before  # one file against the whole package

    module.write_text(_MODULE.replace("# pi r^2", "# the area").replace("Of radius", "For a radius") + "\n\n")
    (package / "presets.toml").write_text("# the presets\n\nrate = 2.0\n")
    (package / "notes.md").write_text("other prose")
    assert source_digest("digestpkg") == before

    (package / "presets.toml").write_text("rate = 3.0\n")
    assert source_digest("digestpkg") != before
    (package / "presets.toml").write_text("rate = 2.0\n")
    assert source_digest("digestpkg") == before
    module.write_text(_MODULE.replace("** RATE", "** RATE * 1.0"))
    assert source_digest("digestpkg") != before
    with pytest.raises(ValueError, match=r"no module 'digestpkg\.absent'"):
        source_digest("digestpkg.absent")


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
