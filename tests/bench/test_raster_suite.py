"""Smoke test of ``wcbench bench raster`` in quick mode: schema, fields and accuracy, not speed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("numba")

from wcbench.bench.phases import amdahl_serial, amdahl_speedup, parse_threads, phase_table
from wcbench.bench.raster import RASTER_PHASES
from wcbench.bench.schema import validate_benchmark

FIELDS = ("name", "gaussians", "width", "height", "pairs", "fwd_ms", "bwd_ms", "ref_fwd_ms", "ref_bwd_ms",
          "max_abs_err", "peak_mb")
# float32 per-pair math against the float64 twin on the same pairs: a few float32 ulps (the target
# on the real workload is 1e-5; these small cases sit near 1e-7).
MAX_ABS_ERR = 1e-5
DEPTH_REL_ERR = 1e-5


def test_quick_run_without_data_root(tmp_path: Path) -> None:
    from wcbench.bench.raster import run

    report = run(data_root=None, quick=True)
    obj = report.to_json()
    validate_benchmark(obj)
    assert obj["suite"] == "raster"
    names = [c["name"] for c in obj["cases"]]
    assert [n[:2] for n in names] == ["d_", "a_", "b_", "b_", "pr", "c_"]
    assert "synthetic" in names[2] and any("pandaset_002 unavailable" in n for n in obj["notes"])
    wide = obj["cases"].pop(3)  # the weather step's channels: fast path only, timed against case b
    assert wide["name"] == names[2] + "_15ch" and wide["ref_fwd_ms"] is None
    assert wide["max_abs_err"] < MAX_ABS_ERR and wide["pairs"] == obj["cases"][2]["pairs"]
    assert wide["fwd_vs_rgb"] == round(wide["fwd_ms"] / obj["cases"][2]["fwd_ms"], 3) and wide["bwd_vs_rgb"] > 0
    profile = obj["cases"].pop(3)
    assert profile["name"] == "profile_b_240x135" and profile["threads"] == [1, 2]
    rows = profile["phases"]
    assert list(rows) == [*RASTER_PHASES, "total"]
    assert abs(sum(rows[k]["ms"]["1"] for k in RASTER_PHASES) - rows["total"]["ms"]["1"]) < 1e-2
    for row in rows.values():
        assert 0.0 <= row["serial"] <= 1.0 and row["speedup"] > 0 and row["projected_16t"] >= 1.0
    assert any("Amdahl projection" in n for n in obj["notes"])
    for case in obj["cases"]:
        for key in FIELDS:
            assert key in case, f"{case['name']} lacks {key}"
        assert case["knob"] == "gaussians" and case["value"] == case["gaussians"]
        assert case["time_ms"] == case["fwd_ms"] and case["fwd_ms"] > 0 and case["pairs"] > 0
    d, *timed = obj["cases"]
    assert d["bwd_ms"] is None and d["peak_mb"] is not None and d["peak_mb"] >= 0
    for case in timed:
        assert case["bwd_ms"] > 0 and case["ref_fwd_ms"] > 0 and case["ref_bwd_ms"] > 0
        assert case["error"] == case["max_abs_err"] and case["error_unit"] == "abs"
        assert case["max_abs_err"] < MAX_ABS_ERR, case
        assert case["depth_max_rel_err"] < DEPTH_REL_ERR, case
    path = tmp_path / "raster.json"
    report.write(path)
    validate_benchmark(json.loads(path.read_text()))
    assert "note:" in report.format_table()


def test_the_groups_variable_runs_the_profiles_alone_and_names_unknown_groups(monkeypatch) -> None:
    from wcbench.bench.raster import run
    from wcbench.core.errors import InputError

    monkeypatch.setenv("WCBENCH_BENCH_RASTER_GROUPS", "profile")
    obj = run(data_root=None, quick=True).to_json()
    assert [c["name"] for c in obj["cases"]] == ["profile_b_240x135"]  # the workstation check's run
    monkeypatch.setenv("WCBENCH_BENCH_RASTER_GROUPS", "profile,speeds")
    with pytest.raises(InputError, match=r"unknown groups \['speeds'\]; known: speed, profile, start"):
        run(data_root=None, quick=True)


@pytest.mark.slow
def test_start_cases_time_a_cold_and_a_warm_process_from_the_repository_root(tmp_path) -> None:
    """The start cases (`--quick` skips them) alone, run as `python -m wcbench` from the repository root:
    their process runs `python -c "from wcbench.reference_model.kernel_warmup import ..."`, where
    `./wcbench` shadows the installed package and the checkout's finder must still reach the sibling
    folders. The suite's other cases run in `bench all --quick` (tests/bench/test_all_quick.py)."""
    import os
    import subprocess
    import sys

    from paths import REPO

    out = tmp_path / "raster.json"
    env = {**os.environ, "WCBENCH_BENCH_RASTER_GROUPS": "start"}
    done = subprocess.run([sys.executable, "-m", "wcbench", "bench", "raster", "--json", str(out)],
                          cwd=REPO, env=env, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    doc = json.loads(out.read_text())
    validate_benchmark(doc)
    cases = {c["name"]: c for c in doc["cases"]}
    assert doc["suite"] == "raster" and set(cases) == {"start_cold", "start_warm"}
    cold, warm = cases["start_cold"], cases["start_warm"]
    assert cold["time_ms"] > 0 and warm["time_ms"] > 0 and warm["default"] is True
    assert warm["cold_over_warm"] == round(cold["time_ms"] / warm["time_ms"], 2)


def test_amdahl_serial_fraction_and_projection_invert_each_other() -> None:
    for f in (0.0, 0.05, 0.1, 0.5, 1.0):
        assert amdahl_serial(amdahl_speedup(f, 2), 2) == pytest.approx(f)
    # the numbers: 1.81x from 1 to 2 threads is ~10 % serial, which caps 16 threads near 6x
    f = amdahl_serial(1.81, 2)
    assert f == pytest.approx(0.105, abs=1e-3) and amdahl_speedup(f, 16) == pytest.approx(6.21, abs=0.01)
    assert amdahl_serial(2.5, 2) == 0.0 and amdahl_serial(0.5, 2) == 1.0  # clamped: noise, contention


def test_parse_threads_takes_a_list_and_rejects_what_cannot_be_a_profile() -> None:
    assert parse_threads(None) == [1, 2] and parse_threads("1,2,4,8,16") == [1, 2, 4, 8, 16]
    assert parse_threads([2, 4]) == [2, 4]
    for bad in ("1", "0,2", "1,1", "a,b"):
        with pytest.raises(ValueError):
            parse_threads(bad)


def test_phase_table_reports_medians_speedups_and_says_the_projection_is_one() -> None:
    samples = {1: [{"a": 9.0, "b": 1.0, "total": 10.0}] * 3, 2: [{"a": 4.5, "b": 1.0, "total": 5.5}] * 3}
    fields, lines = phase_table("t", samples, [1, 2], ["a", "b"], "total")
    rows = fields["phases"]
    assert rows["a"]["speedup"] == 2.0 and rows["a"]["serial"] == 0.0 and rows["a"]["projected_16t"] == 16.0
    assert rows["b"]["serial"] == 1.0 and rows["b"]["projected_16t"] == 1.0 and rows["b"]["share"] == 0.1
    assert rows["total"]["serial"] == pytest.approx(0.1, abs=1e-4)
    assert "projection" in lines[0] and len(lines) == 2 + 3
    assert "numba threading layer" in lines[0] and fields["threading_layer"] in ("omp", "tbb", "workqueue", "none yet")
