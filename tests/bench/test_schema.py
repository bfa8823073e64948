"""The one benchmark JSON schema every suite writes."""

from __future__ import annotations

import json
import sys

import pytest

from wcbench.bench.schema import BenchCase, BenchReport, validate_benchmark

if sys.version_info >= (3, 11):
    pass
else:  # pragma: no cover
    pass


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
