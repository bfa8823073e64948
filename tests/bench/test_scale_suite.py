"""``wcbench bench scale``: the quick run reports every case, and the cluster's numbers are the local ones."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from wcbench.bench.schema import validate_benchmark

pytest.importorskip("distributed")


@pytest.mark.slow
def test_bench_scale_quick_reports_every_case_with_zero_difference(bench_all_quick: Path) -> None:
    doc = json.loads((bench_all_quick / "scale.json").read_text())  # `bench all --quick` (tests/bench/conftest.py)
    validate_benchmark(doc)
    cases = {c["name"]: c for c in doc["cases"]}
    assert set(cases) == {"local", "dask_1", "dask_2", "empty_units_1", "empty_units_2"}
    for name in ("dask_1", "dask_2"):
        assert cases[name]["error"] == 0.0 and cases[name]["time_ms"] > 0 and cases[name]["start_ms"] > 0
    assert all(cases[f"empty_units_{w}"]["time_ms"] > 0 for w in (1, 2))
