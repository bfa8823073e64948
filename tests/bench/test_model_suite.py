"""``wcbench bench model``: the suite runs on the demo street and reports every case (slow)."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("torch")


@pytest.mark.slow
def test_bench_model_quick_runs_and_reports_every_case() -> None:
    from wcbench.bench.model import run
    from wcbench.bench.schema import validate_benchmark

    obj = run(data_root=None, quick=True).to_json()
    validate_benchmark(obj)
    cases = {c["name"]: c for c in obj["cases"]}
    assert {"plain", "weathercity", "one_pass_vs_per_weather", "skip_frustum_cull", "skip_static_tracks",
            "skip_unsupervised_weather", "content_interval_1", "content_interval_4"} <= set(cases)
    for name in ("plain", "weathercity", "content_interval_1"):
        assert 15.0 < cases[name]["error"] < 60.0 and cases[name]["steps"] > 0
    assert cases["weathercity"]["fps_rain_fog"] > 0 and math.isfinite(cases["weathercity"]["vs_plain_db"])
    assert cases["one_pass_vs_per_weather"]["error"] < 1e-4  # the same images either way
    assert cases["skip_unsupervised_weather"]["gaussians"] == cases["skip_unsupervised_weather"]["gaussians_without"]
    assert any("demo street" in n for n in obj["notes"])
