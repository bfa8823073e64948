"""``wcbench bench streets``: the clear sky's blue, the removal case on a hand-made street, and the quick suite on a
real scene (slow)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from paths import DATA, SHARED_DATA

torch = pytest.importorskip("torch")

from parked_car import CAMERAS, HEIGHT, UP, WIDTH, K, scene  # noqa: E402

from wcbench.bench.streets import _remove_case, clear_sky_blue, hits_as_sky_apart  # noqa: E402
from wcbench.scenes.scene import Camera  # noqa: E402


def test_clear_sky_blue_is_the_blue_of_a_clear_sky_not_of_a_car_or_an_overcast_sky():
    colors = np.array([[[0.45, 0.62, 0.90],   # a clear sky: blue
                        [0.70, 0.72, 0.76],   # an overcast sky: grey
                        [0.08, 0.12, 0.40],   # a dark blue car: too dark
                        [0.55, 0.70, 0.60]]], np.float32)  # a green facade
    np.testing.assert_array_equal(clear_sky_blue(colors)[0], [True, False, False, False])


def test_hits_as_sky_apart_are_returns_with_no_structure_drawn_within_a_pixel():
    sky = np.ones((7, 9), bool)
    sky[:, 2] = False  # a wire drawn one column wide
    hits = np.zeros_like(sky)
    hits[1, 3] = True  # its return a pixel beside it: an edge a pixel off
    hits[1, 4] = True  # two pixels beside it: the structure lost
    hits[5, 2] = True  # on it: not sky at all
    hits[6, 8] = True  # alone in the sky, at the frame's corner
    apart = hits_as_sky_apart(sky, hits)
    np.testing.assert_array_equal(np.argwhere(apart), [[1, 4], [6, 8]])
    # every hit shown as sky with nothing else around is apart; none where the sky is empty
    assert hits_as_sky_apart(np.ones_like(sky), hits).sum() == hits.sum()
    assert not hits_as_sky_apart(np.zeros_like(sky), hits).any()


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


def test_the_removal_case_counts_what_a_removed_car_leaves_filled_and_as_trained():
    # the hand-made street of tests/support/parked_car.py: as trained, the ground behind the car is
    # see-through and a strip keeps its red; filled, neither
    model, _ = scene()
    frames = [SimpleNamespace(camera=Camera(K=K, width=WIDTH, height=HEIGHT, camera_to_world=np.linalg.inv(w2c)))
              for _, w2c, _, _, _ in CAMERAS]
    street = SimpleNamespace(id="parked_car", up=UP, frames=frames)
    with torch.no_grad():
        case = _remove_case(street, model)
    e = case.extra
    assert e["removed_nodes"] == 1 and e["hidden_gaussians"] > 0 and e["ground_tiles"] > 0
    assert e["see_through_below_horizon_as_trained"] > 0.1 and e["see_through_below_horizon_filled"] == 0.0
    assert e["car_like_filled"] < e["car_like_as_trained"]
    assert case.error == e["car_like_filled"]
