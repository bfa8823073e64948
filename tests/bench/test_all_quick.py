"""``wcbench bench all --quick``: one quick pass of every suite, and each suite's smoke test on its JSON (slow).

Each suite's smoke test used to run its own quick pass, and ``bench all``'s test ran them all again:
every suite twice. Here ``bench all --quick`` runs once for the module (no data root: the built-in
scenes and stand-ins; ``bench streets`` on the real scene has its own test) and each test reads its
suite's JSON. One module, so that the two processes of the tests (``--dist loadfile``, tox.ini) run
it once.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

pytest.importorskip("torch")

from wcbench.bench.schema import validate_benchmark


@pytest.fixture(scope="module")
def bench_all_quick(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The folder of one ``wcbench bench all --quick`` run: ``<suite>.json`` for every suite,
    ``summary.md`` and ``charts/``."""
    from wcbench.cli import main

    out = tmp_path_factory.mktemp("bench_all_quick")
    assert main(["bench", "all", "--quick", "--out", str(out)]) == 0
    return out


@pytest.mark.slow
def test_bench_all_quick_runs_every_suite(bench_all_quick: Path) -> None:
    from wcbench.bench import SUITES

    assert {p.stem for p in bench_all_quick.glob("*.json")} == set(SUITES)
    assert (bench_all_quick / "summary.md").is_file() and list((bench_all_quick / "charts").glob("*.png"))


@pytest.mark.slow
def test_bench_model_quick_runs_and_reports_every_case(bench_all_quick: Path) -> None:
    obj = json.loads((bench_all_quick / "model.json").read_text())
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


@pytest.mark.slow
def test_bench_weather_quick_runs_and_reports_every_case(bench_all_quick: Path) -> None:
    obj = json.loads((bench_all_quick / "weather.json").read_text())
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


@pytest.mark.slow
def test_bench_scale_quick_reports_every_case_with_zero_difference(bench_all_quick: Path) -> None:
    pytest.importorskip("distributed")
    doc = json.loads((bench_all_quick / "scale.json").read_text())
    validate_benchmark(doc)
    cases = {c["name"]: c for c in doc["cases"]}
    assert set(cases) == {"local", "dask_1", "dask_2", "empty_units_1", "empty_units_2"}
    for name in ("dask_1", "dask_2"):
        assert cases[name]["error"] == 0.0 and cases[name]["time_ms"] > 0 and cases[name]["start_ms"] > 0
    assert all(cases[f"empty_units_{w}"]["time_ms"] > 0 for w in (1, 2))
