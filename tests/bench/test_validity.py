"""The validity suite's agreement statistic (Spearman with a bootstrap interval)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wcbench.bench.validity import agreement


def _spearman_twin(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson correlation of the ranks (distinct values: ranks are argsort positions)."""
    rx, ry = np.argsort(np.argsort(x)).astype(float), np.argsort(np.argsort(y)).astype(float)
    rx, ry = rx - rx.mean(), ry - ry.mean()
    return float((rx * ry).sum() / math.sqrt((rx * rx).sum() * (ry * ry).sum()))


def test_agreement_matches_the_rank_twin_and_orients() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=40)
    y = x + rng.normal(scale=0.8, size=40)
    rho, low, high = agreement(x, y)
    assert rho == pytest.approx(_spearman_twin(x, y), abs=1e-12)
    assert low < rho < high
    flipped, f_low, f_high = agreement(-x, y, sign=-1.0)  # a lower-is-better proxy, oriented
    assert flipped == pytest.approx(rho, abs=1e-12) and (f_low, f_high) == pytest.approx((low, high))
    assert agreement(x, y) == (rho, low, high)  # seeded


def test_agreement_of_perfect_and_unrelated_series() -> None:
    x = np.arange(10.0)
    assert agreement(x, x ** 3)[0] == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    _, low, high = agreement(rng.normal(size=30), rng.normal(size=30))
    assert low < 0 < high  # the interval says "no evidence either way"


def test_agreement_degenerate_inputs() -> None:
    assert all(math.isnan(v) for v in agreement(np.ones(5), np.arange(5.0)))
    assert all(math.isnan(v) for v in agreement(np.arange(2.0), np.arange(2.0)))
    with pytest.raises(ValueError, match="two series of one length"):
        agreement(np.arange(3.0), np.arange(4.0))


def test_supervision_cases_compare_per_weather_and_in_the_mean(monkeypatch, tmp_path) -> None:
    import wcbench.bench.validity as validity

    def doc(psnr: dict[str, float], flicker: dict[str, float]) -> dict:
        return {"results": {"synth_1": {w: {"psnr": {"value": psnr[w]}, "temporal_flicker": {"value": flicker[w]},
                                              "lpips": {"value": 0.1}} for w in psnr}}}

    calls = []

    def fake_run(label, name, options, scenes, root, metrics, weathers=validity.EDITED):
        calls.append((label, name, options, weathers))
        return 2.0, doc({"clear": 34.0, "rain": 31.0, "snow": 26.0, "fog": 33.0},
                        {"clear": 0.02, "rain": 0.025, "snow": 0.07, "fog": 0.03})

    monkeypatch.setattr(validity, "_run_entry", fake_run)
    units = lambda d: validity._units(d)  # noqa: E731
    editor = units(doc({"rain": 30.0, "snow": 27.0, "fog": 29.0}, {"rain": 0.04, "snow": 0.06, "fog": 0.05}))
    truth = units(doc({"rain": 99.0, "snow": 99.0, "fog": 99.0}, {"rain": 0.024, "snow": 0.039, "fog": 0.025}))
    cases = validity._supervision_cases("synth_1", tmp_path, {"truth": truth, "sim-editor_0.5": editor},
                                        ("psnr",))
    # only the supervisions whose editor entry ran get a case (here sim-editor 0.5)
    assert [c.name for c in cases] == ["supervised_sim-editor_0.5"]
    assert calls == [("weathercity_sim-editor_0.5", "weathercity",
                      {"supervision": "sim-editor:0.5", "profile": "default", "physics": "truth"},
                      ("clear", "rain", "snow", "fog"))]
    x = cases[0].extra
    assert x["psnr_clear_vs_raw"] == pytest.approx(34.0)  # the clear unit stays out of the weathers' means
    assert x["psnr_weathercity"] == pytest.approx(30.0) and x["psnr_editor"] == pytest.approx(28.666, abs=1e-3)
    assert x["closer_psnr"] is True
    assert x["closer_psnr_rain"] is True and x["closer_psnr_snow"] is False and x["closer_psnr_fog"] is True
    # snow: |0.07 - 0.039| > |0.06 - 0.039|, the editor's flicker is nearer the truth's there
    assert x["closer_flicker_snow"] is False and x["closer_flicker_rain"] is True
    assert x["flicker_truth_fog"] == pytest.approx(0.025)


def test_the_first_run_group_runs_the_first_runs_alone(monkeypatch) -> None:
    import wcbench.bench.validity as validity
    from wcbench.bench.schema import BenchCase

    def no_entries(*args, **kwargs):
        raise AssertionError("the scores group ran")

    ran = []

    def fake_first_run(scenes: str) -> BenchCase:
        ran.append(scenes)
        return BenchCase(name=f"first_run_{scenes}", knob="first_run", value=scenes, time_ms=1.0, error=None,
                         error_unit="-")

    monkeypatch.setattr(validity, "_run_entry", no_entries)
    monkeypatch.setattr(validity, "_first_run_case", fake_first_run)
    monkeypatch.setenv("WCBENCH_BENCH_VALIDITY_GROUPS", "first_run")
    report = validity.run()
    assert ran == list(validity.FIRST_RUN_LIMIT_S)
    assert [c.name for c in report.cases] == [f"first_run_{s}" for s in validity.FIRST_RUN_LIMIT_S]
    assert report.notes == []


def test_an_unknown_group_is_refused_before_any_work(monkeypatch) -> None:
    import wcbench.bench.validity as validity
    from wcbench.core.errors import InputError

    monkeypatch.setattr(validity, "_first_run_case", lambda scenes: (_ for _ in ()).throw(AssertionError("ran")))
    monkeypatch.setenv("WCBENCH_BENCH_VALIDITY_GROUPS", "first_run,speed")
    with pytest.raises(InputError, match=r"unknown groups \['speed'\]; known: scores, first_run"):
        validity.run()
