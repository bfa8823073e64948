"""``wcbench bench all``: the Pareto front, the summary table and the charts from suite JSON files."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from wcbench.bench.overview import pareto_front, summarize
from wcbench.bench.schema import BenchCase, BenchReport
from wcbench.cli import main


def test_pareto_front_lower_and_higher_is_better() -> None:
    pts = [(1.0, 5.0), (2.0, 3.0), (3.0, 3.0), (4.0, 1.0), (2.0, 6.0)]
    assert pareto_front(pts) == [True, True, False, True, False]
    # PSNR, higher is better: (2, 6) dominates every slower point; (1, 5) stays, being the fastest
    assert pareto_front(pts, higher_is_better=True) == [True, False, False, False, True]
    assert pareto_front([(1.0, 1.0), (1.0, 1.0)]) == [True, True]  # equal points do not dominate each other


def _write(folder: Path, suite: str, cases: list[BenchCase]) -> None:
    BenchReport(suite, cases=cases, notes=[f"{suite} note"]).write(folder / f"{suite}.json")


def test_summary_marks_defaults_off_the_front_and_draws_one_chart_per_knob(tmp_path: Path) -> None:
    _write(tmp_path, "raster", [
        BenchCase("tile_8", "tile", 8, 10.0, 1e-6, "abs"),
        BenchCase("tile_16", "tile", 16, 8.0, 1e-6, "abs", {"default": True}),
        BenchCase("tile_32", "tile", 32, 12.0, 2e-6, "abs"),
        BenchCase("alone", "other", 1, None, None, "abs"),
        BenchCase("rain", "jitter", 0.5, 5.0, 0.1, "abs", {"default": True}),  # one value on two weathers:
        BenchCase("snow", "jitter", 0.5, 5.0, 0.05, "abs", {"default": True}),  # listed, not compared
    ])
    _write(tmp_path, "model", [
        BenchCase("iterations_800", "iterations", 800, 200.0, 28.2, "psnr_db", {"default": True}),
        BenchCase("hidden_64", "hidden", 64, 240.0, 28.2, "psnr_db"),
        BenchCase("iterations_400", "iterations", 400, 100.0, 28.5, "psnr_db"),
    ])
    done = summarize(tmp_path)
    assert done["suites"] == ["model", "raster"]
    assert done["off_front"] == [("model", "iterations", "iterations_800")]  # 400 steps: quicker and better
    names = sorted(p.name for p in done["charts"])
    assert names == ["model-iterations-iterations.png", "raster-tile-tile.png"]  # one-case knobs: listed, not charted
    for p in done["charts"]:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = (tmp_path / "summary.md").read_text()
    assert "| tile_16 | tile | 16 | 8 | 1e-06 | abs | yes | yes |" in text
    assert "| tile_32 | tile | 32 | 12 | 2e-06 | abs |  | no |" in text
    assert "- model / iterations: iterations_800" in text and "![raster-tile-tile](charts/raster-tile-tile.png)" in text


def test_a_reference_default_joins_every_knob_one_setting_away(tmp_path: Path) -> None:
    """The knob rows of ``bench model`` vary one setting each from one default row: that row
    (``stands_for_knobs``) is each knob's default point, in its front and its chart."""
    _write(tmp_path, "model", [
        BenchCase("weathercity_half", "iterations", 800, 200.0, 28.2, "psnr_db",
                  {"default": True, "stands_for_knobs": True}),
        BenchCase("hidden_64", "hidden", 64, 240.0, 28.1, "psnr_db"),  # slower and worse: the default is on the front
        BenchCase("budget_100k", "budget", 100000, 150.0, 28.3, "psnr_db"),  # quicker and better: it is not
        BenchCase("other", "unrelated", 1, 5.0, 0.1, "abs"),  # another unit: not compared with it
    ])
    done = summarize(tmp_path)
    assert done["off_front"] == [("model", "budget", "weathercity_half (against budget)")]
    names = sorted(p.name for p in done["charts"])
    assert names == ["model-budget-budget.png", "model-hidden-hidden.png"]
    text = (tmp_path / "summary.md").read_text()
    assert text.count("| weathercity_half |") == 1  # listed once, under its own knob


def test_summary_of_a_foreign_or_empty_folder_is_a_clear_error(tmp_path: Path, capsys) -> None:
    with pytest.raises(ValueError, match="no benchmark JSON files"):
        summarize(tmp_path)
    (tmp_path / "broken.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"broken\.json: not a wcbench benchmark JSON"):
        summarize(tmp_path)
    (tmp_path / "broken.json").unlink()
    (tmp_path / "other.json").write_text(json.dumps({"hello": 1}))
    assert main(["bench", "all", "--summary-only", "--out", str(tmp_path)]) == 2
    assert f"{tmp_path / 'other.json'}: not a wcbench benchmark JSON" in capsys.readouterr().err


def test_summary_only_from_the_cli(tmp_path: Path, capsys) -> None:
    _write(tmp_path, "weather", [BenchCase("k_1", "k", 1, 1.0, 0.1, "rel", {"default": True}),
                                 BenchCase("k_2", "k", 2, 2.0, 0.05, "rel")])
    assert main(["bench", "all", "--summary-only", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "1 charts" in out and "off its Pareto front" not in out


def test_options_of_bench_all_are_refused_elsewhere(tmp_path: Path, capsys) -> None:
    assert main(["bench", "all", "--json", str(tmp_path / "x.json")]) == 2
    assert "writes every suite's JSON into --out" in capsys.readouterr().err
    assert main(["bench", "metrics", "--summary-only"]) == 2
    assert "--summary-only goes with `bench --all`" in capsys.readouterr().err


def test_a_suite_that_trains_weathercity_fetches_its_weights_before_it_runs(tmp_path: Path, monkeypatch) -> None:
    # bench model and bench streets train the `default` model `wcbench run` trains: with the content
    # loss's VGG16, fetched first as run fetches it, or a fresh machine would measure another model
    import sys
    import types

    import wcbench.cli.bench as bench_cli
    import wcbench.core.models.fetch as fetch

    events: list[tuple] = []
    monkeypatch.delenv(fetch.OFFLINE_ENV, raising=False)  # --offline alone decides
    monkeypatch.setattr(fetch, "fetch_missing",
                        lambda names, *, offline: events.append(("fetch", list(names), offline)) or {})
    fake = types.ModuleType("fake_bench_suites")

    def run(*, data_root, quick):
        events.append(("run", quick))
        return BenchReport(suite="streets")

    fake.run = run  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "fake_bench_suites", fake)
    monkeypatch.setitem(bench_cli.SUITES, "streets", "fake_bench_suites:run")
    assert main(["bench", "streets", "--quick"]) == 0
    assert events == [("fetch", ["vgg16"], False), ("run", True)]
    events.clear()
    out = tmp_path / "streets.json"
    assert main(["bench", "streets", "--quick", "--offline", "--out", str(out)]) == 0
    assert events == [("fetch", ["vgg16"], True), ("run", True)]
    assert "--offline" in json.loads(out.read_text())["command"]  # the command that reproduces it says so
    # a suite that reads no weights fetches none
    events.clear()
    bench_cli._fetch_weights(["raster", "metrics"], argparse.Namespace(offline=False))
    assert events == []
