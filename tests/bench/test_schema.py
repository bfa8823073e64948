"""The one benchmark JSON schema every suite writes."""

from __future__ import annotations

import json

import pytest

from wcbench.bench.schema import BenchCase, BenchReport, validate_benchmark


def test_benchmark_schema_round_trip(tmp_path):
    report = BenchReport("demo", notes=["a note"])
    report.cases.append(BenchCase("a", "pixels", 100, 1.5, 1e-7, "abs", extra={"ref_ms": 3.0}))
    report.write(tmp_path / "b.json")
    obj = json.loads((tmp_path / "b.json").read_text())
    validate_benchmark(obj)
    assert obj["cases"][0] == {"name": "a", "knob": "pixels", "value": 100, "time_ms": 1.5, "error": 1e-7,
                               "error_unit": "abs", "ref_ms": 3.0}
    assert obj["machine"]["cores"] >= 1 and "numpy" in obj["versions"]
    with pytest.raises(ValueError, match="shadow"):
        BenchCase("b", "k", 1, None, None, "abs", extra={"time_ms": 1}).to_json()


def test_the_table_fits_the_terminal_and_says_what_it_left_for_the_json():
    report = BenchReport("demo", notes=["n"])
    for i in range(3):
        extra = {f"field_{k:02d}": 1000.0 * k + i for k in range(30) if (k + i) % 3}  # two cases of three
        extra["often"] = 1.0
        report.cases.append(BenchCase(f"case_{i}", "knob", i, 1.0, 0.5, "abs", extra=extra))
    report.cases[0].extra["rare"] = 2.0
    lines = report.format_table().splitlines()
    assert max(len(line) for line in lines if not line.startswith("note")) <= 120
    header = lines[0].split()
    assert header[:6] == ["name", "knob", "value", "time_ms", "error", "error_unit"]
    assert "often" in header and "rare" not in header  # fields most cases fill go first
    left = 32 - (len(header) - 6)
    assert lines[-2] == f"({left} more fields per case in the JSON: --out FILE)" and lines[-1] == "note: n"
    everything = report.format_table(width=None).splitlines()
    assert len(everything[0].split()) == 6 + 32 and "more field" not in everything[-2]


def _stand_in_suite(*, data_root, quick):
    report = BenchReport("fake", stand_ins=["pandaset_002 not found: the demo street stood in"])
    report.cases.append(BenchCase("a", "k", 1, 1.0, 0.0, "abs"))
    return report


def test_stand_in_data_is_recorded_and_warned_about(tmp_path, capsys, monkeypatch):
    from wcbench.bench import SUITES, schema
    from wcbench.cli import main

    monkeypatch.setitem(SUITES, "fake", f"{__name__}:_stand_in_suite")
    assert main(["bench", "fake", "--json", str(tmp_path / "b.json")]) == 0
    err = capsys.readouterr().err
    assert "WARNING: stand-in data: pandaset_002 not found: the demo street stood in" in err
    obj = json.loads((tmp_path / "b.json").read_text())
    schema.validate_benchmark(obj)
    assert obj["stand_ins"] == ["pandaset_002 not found: the demo street stood in"]
