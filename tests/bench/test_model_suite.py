"""``wcbench bench model``: the suite runs on the demo street and reports every case (slow)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

pytest.importorskip("torch")


@pytest.mark.slow
def test_bench_model_quick_runs_and_reports_every_case(bench_all_quick: Path) -> None:
    from wcbench.bench.schema import validate_benchmark

    obj = json.loads((bench_all_quick / "model.json").read_text())  # `bench all --quick` (tests/bench/conftest.py)
    validate_benchmark(obj)
    cases = {c["name"]: c for c in obj["cases"]}
    assert {"plain", "weathercity", "weathercity_half", "one_pass_vs_per_weather", "skip_frustum_cull",
            "skip_static_tracks", "skip_unsupervised_weather", "content_interval_2", "content_interval_8",
            "profile_step", "render_rain"} <= set(cases)
    profile = cases["profile_step"]
    assert profile["threads"] == [1, 2] and profile["non_raster_speedup"] > 0
    assert set(profile["phases"]) == {"data", "scene_graph", "decoders", "sky", "raster_fwd", "losses", "raster_bwd",
                                      "backward_rest", "stats", "optimizer", "densify", "log", "total", "non_raster"}
    assert profile["phases"]["raster_fwd"]["ms"]["1"] > 0 and profile["phases"]["densify"]["ms"]["1"] >= 0
    for name in ("plain", "weathercity", "weathercity_half", "content_interval_2"):
        assert 15.0 < cases[name]["error"] < 60.0 and cases[name]["steps"] > 0
    # the baseline gets the method's wall clock (it steps until the clock has passed)
    assert cases["plain"]["time_ms"] >= cases["weathercity"]["time_ms"]
    assert cases["weathercity"]["steps"] == 2 * cases["weathercity_half"]["steps"]
    assert cases["weathercity"]["fps_rain_fog"] > 0 and math.isfinite(cases["weathercity"]["vs_plain_db"])
    half_rows = [c for c in cases.values() if c["name"] == "weathercity_half" or "psnr_vs_default" in c]
    assert any(c["pareto"] for c in half_rows) and all(isinstance(c["pareto"], bool) for c in half_rows)
    assert cases["one_pass_vs_per_weather"]["error"] < 1e-4  # the same images either way
    render = cases["render_rain"]  # the fixed rows against the concatenating twin: the same frames
    assert render["error"] <= 1 and render["fps_ratio"] > 0 and render["lidar_init_fps"] > 0
    assert render["new_raster_fwd_blend_ms"] > 0 and render["old_write_png_ms"] > 0
    # the inference-only compositing: its own row, within one uint8 level of the training kernel's frames
    assert render["image_fps_ratio"] > 0 and render["image_raster_fwd_blend_ms"] > 0
    assert render["error_image_new_uint8"] <= 1 and render["error_new_old_uint8"] <= 1
    assert cases["skip_unsupervised_weather"]["gaussians"] == cases["skip_unsupervised_weather"]["gaussians_without"]
    assert any("demo street" in n for n in obj["notes"])
    temporal = [c for c in obj["cases"] if c["name"].startswith("temporal_")]
    assert {c["name"] for c in temporal} == {"temporal_rain", "temporal_snow", "temporal_fog"}
    for c in temporal:
        assert 0.0 < c["raw_error"] and 0.0 < c["error"] and 0.0 < c["supervision_error"]
