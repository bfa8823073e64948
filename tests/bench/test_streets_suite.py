"""``wcbench bench streets``: the clear sky's blue, and the quick suite on a real scene (slow)."""

from __future__ import annotations

import numpy as np
import pytest
from paths import DATA, SHARED_DATA

pytest.importorskip("torch")

from wcbench.bench.streets import clear_sky_blue


def test_clear_sky_blue_is_the_blue_of_a_clear_sky_not_of_a_car_or_an_overcast_sky():
    colors = np.array([[[0.45, 0.62, 0.90],   # a clear sky: blue
                        [0.70, 0.72, 0.76],   # an overcast sky: grey
                        [0.08, 0.12, 0.40],   # a dark blue car: too dark
                        [0.55, 0.70, 0.60]]], np.float32)  # a green facade
    np.testing.assert_array_equal(clear_sky_blue(colors)[0], [True, False, False, False])


@pytest.mark.slow
@pytest.mark.model
def test_bench_streets_quick_runs_on_a_real_scene_and_the_harder_street(monkeypatch):
    from wcbench.bench.schema import validate_benchmark
    from wcbench.bench.streets import SKY_MASKS_ENV, run

    monkeypatch.setenv(SKY_MASKS_ENV, str(DATA / "sky_masks"))  # the installed package is not the checkout

    if not (SHARED_DATA / "pandaset_002" / "images").is_dir():
        pytest.skip(f"{SHARED_DATA / 'pandaset_002'} not present")
    report = run(data_root=SHARED_DATA, quick=True)
    obj = report.to_json()
    validate_benchmark(obj)
    cases = {c["name"]: c for c in obj["cases"]}
    assert {"sky_pandaset_002", "editor_pandaset_002", "synth_hard"} <= set(cases)
    assert cases["sky_pandaset_002"]["iou"] > 0.85
    editor = cases["editor_pandaset_002"]
    assert editor["lidar_hits_as_sky"] == 0
    for w in ("rain", "snow", "fog"):
        # the issue's goal is none; measured 6 / 13 / 0 of the raw frames' 40,116 at roof and tree
        # edges (docs/findings.md "Weather that holds on any street"): a regression shows as more
        # than 0.1 % of the raw sky's blue left
        assert editor[f"clear_sky_blue_left_{w}"] <= 1e-3 * editor["clear_sky_blue_in_raw_sky"]
        assert editor[f"flicker_ratio_{w}"] <= 1.0
    hard = cases["synth_hard"]
    for w in ("rain", "snow", "fog"):  # above the raw frames against the truth
        assert hard[f"psnr_editor_{w}"] > hard[f"psnr_raw_{w}"]
