"""``wcbench bench weather``: the suite runs and reports every case (slow)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")


UP = np.array([0.0, -1.0, 0.0])  # camera at the origin with OpenCV axes: world up is -y


@pytest.mark.slow
def test_bench_weather_quick_runs_and_reports_every_case(bench_all_quick: Path) -> None:
    from wcbench.bench.schema import validate_benchmark

    obj = json.loads((bench_all_quick / "weather.json").read_text())  # `bench all --quick` (tests/bench/conftest.py)
    validate_benchmark(obj)
    names = {c["name"] for c in obj["cases"]}
    assert {"clear", "rain_paper", "snow_paper", "fog_exact", "fog_postprocess"} <= names
    assert not any("target_met" in c for c in obj["cases"])  # targets are for the full-size run
    errors = [c for c in obj["cases"] if c["name"].startswith("fog_error_")]
    assert errors
    for c in errors:
        assert 0 <= c["error"] <= c["max_abs"] <= 1 and c["p99_abs"] <= c["max_abs"]
    stages = {c["name"]: c for c in obj["cases"] if c["name"].startswith("stage_")}
    assert set(stages) == {"stage_particles_rain_paper", "stage_particles_snow_paper", "stage_fog_exact"}
    for c in stages.values():
        assert c["error"] < 1e-4 and c["reference_ms"] > 0 and c["items"] > 0
