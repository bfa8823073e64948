"""``sim-editor``: the truth frames with a per-frame editor's errors, growing with the severity; and its
use as WeatherCity's supervision.

The test scene is the demo street with ground truth of rain attached (``filter2d``'s rain with its
streaks stands in for a synth scene's physically simulated truth) and a dynamic mask on a facade.
"""

from __future__ import annotations

import dataclasses
import itertools
import json

import cv2
import numpy as np
import pytest

from wcbench.cli import main
from wcbench.core.errors import InputError, ResultsExistError
from wcbench.core.image_io import read_rgb8, write_png
from wcbench.methods import get_method, method_options
from wcbench.methods.filter2d import Filter2DMethod
from wcbench.methods.sim_editor import (
    SimEditorMethod,
    structure_weight,
    supervision_frames,
    supervision_severity,
    warp_structures,
)
from wcbench.scenes.scene import Scene

#: Rows and columns of the "vehicle" of the dynamic masks: a textured facade, away from the lane line.
VEHICLE = (slice(60, 110), slice(10, 90))


@pytest.fixture(scope="module")
def truth_scene(tmp_path_factory: pytest.TempPathFactory) -> Scene:
    """The demo street with rain truth frames and a dynamic mask per frame."""
    from wcbench.scenes.sets import resolve_scenes

    scene = resolve_scenes("demo")[0].load()
    root = tmp_path_factory.mktemp("truth")
    (root / "rain").mkdir()
    (root / "masks").mkdir()
    truth = Filter2DMethod()
    w, h = scene.image_size
    mask = np.zeros((h, w), np.uint8)
    mask[VEHICLE] = 255
    rain, frames = [], []
    for k, f in enumerate(scene.frames):
        path = root / "rain" / f"{k:03d}.png"
        write_png(path, truth.render_frame(scene, "rain", k, seed=7))
        rain.append(path)
        mask_path = root / "masks" / f"{k:03d}.png"
        cv2.imwrite(str(mask_path), mask)
        frames.append(dataclasses.replace(f, dynamic_mask_path=mask_path))
    return dataclasses.replace(scene, frames=frames, references={"rain": rain})


def _truth(scene: Scene, weather: str, k: int) -> np.ndarray:
    paths = scene.reference_paths(weather)
    assert paths is not None
    return read_rgb8(paths[k])


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return 10 * np.log10(255.0**2 / mse) if mse else float("inf")


def _flicker(frames: list[np.ndarray]) -> float:
    """Mean |frame t - frame t+1| (0-255)."""
    return float(np.mean([np.abs(a.astype(np.int16) - b).mean() for a, b in itertools.pairwise(frames)]))


def test_severity_zero_renders_the_truth_exactly(truth_scene, tmp_path):
    method = get_method("sim-editor", severity=0.0)
    assert method_options("sim-editor") == ["severity"]
    info = method.render(truth_scene, "rain", tmp_path / "rain", frames=[0, 1], show_progress=False)
    assert info["parameters"]["severity"] == 0.0 and info["parameters"]["truth"] == "scene references"
    # it says plainly that it reads the truth frames: a calibration instrument, not a competitor
    assert info["parameters"]["truth_draw"]["used"] is True
    assert "reads the scene's ground-truth frames of rain" in info["parameters"]["truth_draw"]["note"]
    assert info["parameters"]["physics"].startswith("none: sim-editor renders no weather")
    for k in (0, 1):
        assert np.array_equal(read_rgb8(tmp_path / "rain" / f"{k:03d}.png"), _truth(truth_scene, "rain", k))
    clear, _ = SimEditorMethod(severity=0.0).render_frame(truth_scene, "clear", 2, seed=0)
    assert np.array_equal(clear, read_rgb8(truth_scene.frames[2].image_path))  # clear's truth: the raw frames


def test_errors_are_seeded_per_frame(truth_scene):
    method = SimEditorMethod(severity=0.5)
    a, facts = method.render_frame(truth_scene, "rain", 3, seed=0)
    b, again = SimEditorMethod(severity=0.5).render_frame(truth_scene, "rain", 3, seed=0)
    assert np.array_equal(a, b) and facts == again  # a pure function of (seed, frame, severity)
    assert not np.array_equal(a, method.render_frame(truth_scene, "rain", 3, seed=1)[0])
    assert facts["warp"] == ["lane lines", "vehicles"] and facts["particles"] > 0
    # each frame its own tone draw: the mean colour change differs from frame to frame
    d3 = (a.astype(float) - _truth(truth_scene, "rain", 3)).mean(axis=(0, 1))
    c, _ = method.render_frame(truth_scene, "rain", 4, seed=0)
    d4 = (c.astype(float) - _truth(truth_scene, "rain", 4)).mean(axis=(0, 1))
    assert np.abs(d3 - d4).max() > 0.5


@pytest.mark.parametrize("weather", ["rain", "clear"])
def test_distance_to_truth_and_flicker_grow_with_severity(truth_scene, weather):
    truth = [_truth(truth_scene, weather, k) for k in range(len(truth_scene))]
    psnr, flicker = [], []
    for severity in (0.25, 0.5, 1.0):
        method = SimEditorMethod(severity=severity)
        out = [method.render_frame(truth_scene, weather, k, seed=0)[0] for k in range(len(truth_scene))]
        psnr.append(float(np.mean([_psnr(o, t) for o, t in zip(out, truth)])))
        flicker.append(_flicker(out) - _flicker(truth))
    assert psnr[0] > psnr[1] + 1.0 and psnr[1] > psnr[2] + 1.0, psnr  # measurably, not by noise
    assert 0 < flicker[0] < flicker[1] < flicker[2], flicker


def test_warps_move_the_vehicles_and_lane_lines_and_nothing_far_from_them(truth_scene):
    raw = read_rgb8(truth_scene.frames[0].image_path)
    dynamic = np.zeros(raw.shape[:2], bool)
    dynamic[VEHICLE] = True
    weight, targets = structure_weight(raw, dynamic)
    assert weight is not None and targets == ["lane lines", "vehicles"]
    assert weight[70:100, 20:80].min() > 0.99  # inside the vehicle
    img = raw.astype(np.float32) / 255
    out = warp_structures(img, np.random.default_rng(0), 1.0, weight)
    assert np.abs(out - img)[VEHICLE].mean() > 0.01  # the vehicle moved
    lanes = weight > 0.99
    lanes[VEHICLE] = False
    assert lanes.any() and np.abs(out - img)[lanes].max() > 0.05  # and so did the lane line
    still = weight == 0
    assert still.mean() > 0.3 and np.array_equal(out[still], img[still])
    # neither vehicles nor lane lines: a global smooth warp
    flat = np.full_like(raw, 90)
    assert structure_weight(flat, None) == (None, ["global"])


def test_a_scene_without_truth_is_refused_by_name(demo_scene, tmp_path, capsys):
    with pytest.raises(InputError, match=r"sim-editor needs ground-truth frames of 'rain'.*synth_"):
        SimEditorMethod().render(demo_scene, "rain", tmp_path / "r", show_progress=False)
    assert not (tmp_path / "r").exists()
    out = tmp_path / "run"
    assert main(["run", "--method", "sim-editor", "--scenes", "demo", "--weathers", "rain", "--metrics", "psnr",
                 "--out", str(out), "--no-progress"]) == 2
    assert "needs ground-truth frames of 'rain'" in capsys.readouterr().err
    assert not list(out.rglob("*.png"))
    # the default weathers: clear could render, but the run stops before it (rain cannot)
    assert main(["run", "--method", "sim-editor", "--scenes", "demo", "--metrics", "psnr",
                 "--out", str(tmp_path / "all"), "--no-progress"]) == 2
    assert "needs ground-truth frames of 'rain'" in capsys.readouterr().err
    assert not list((tmp_path / "all").rglob("*.png"))
    # clear needs no references: its truth is the raw frames
    assert main(["run", "--method", "sim-editor", "--scenes", "demo", "--weathers", "clear", "--frames", "0-3",
                 "--metrics", "psnr", "--method-option", "severity=0.5", "--out", str(out), "--no-progress"]) == 0
    info = json.loads((out / "sim-editor" / "demo" / "clear" / "info.json").read_text())
    assert info["parameters"]["severity"] == 0.5 and info["frames"][0]["info"]["warp"] == ["lane lines"]
    psnr = json.loads((out / "results.json").read_text())["results"]["demo"]["clear"]["psnr"]["value"]
    assert 20 < psnr < 40


def test_the_render_key_covers_the_truth_frames(truth_scene, tmp_path):
    method = SimEditorMethod(severity=0.5)
    method.render(truth_scene, "rain", tmp_path, frames=[0], show_progress=False)
    refs = list(truth_scene.references["rain"])
    refs[0] = truth_scene.frames[0].image_path  # another truth of frame 0
    with pytest.raises(ResultsExistError):
        method.render(dataclasses.replace(truth_scene, references={"rain": refs}), "rain", tmp_path, frames=[0],
                      show_progress=False)


def test_severity_is_checked():
    with pytest.raises(InputError, match=r"severity=1.5: expected a number in \[0, 1\]"):
        get_method("sim-editor", severity=1.5)


def test_supervision_option_parses_a_severity_and_refuses_a_bad_one(truth_scene):
    assert supervision_severity("sim-editor:0.3") == 0.3
    assert supervision_severity("sim-editor") == 0.5
    assert supervision_severity("filter2d") is None and supervision_severity("qwen-image:edits/") is None
    for bad in ("sim-editor:2", "sim-editor:-0.1", "sim-editor:x", "sim-editor:"):
        with pytest.raises(InputError, match=r"severity must be"):
            supervision_severity(bad)
    frames, record = supervision_frames(truth_scene, 0.3, ("rain", "snow"), seed=4)
    assert list(frames) == ["rain"] and len(frames["rain"]) == len(truth_scene)
    assert np.array_equal(frames["rain"][5], SimEditorMethod(severity=0.3).render_frame(truth_scene, "rain", 5,
                                                                                        seed=4)[0])
    assert record["method"] == "sim-editor" and record["severity"] == 0.3 and record["seed"] == 4
    assert len(record["truth"]["rain"]) == len(truth_scene) and "snow" in record["not_supervised"]
    with pytest.raises(InputError, match="no ground-truth frames"):
        supervision_frames(truth_scene, 0.3, ("snow", "fog"), seed=0)


def test_weathercity_takes_sim_editor_supervision(truth_scene):
    pytest.importorskip("torch")
    from wcbench.methods.scene_training import supervision_frames

    with pytest.raises(InputError, match=r"must be in \[0, 1\]"):
        get_method("weathercity", supervision="sim-editor:2")
    with pytest.raises(InputError, match="jitter"):
        get_method("weathercity", supervision="sim-editor:0.3", jitter=0.5)
    assert get_method("weathercity", supervision="sim-editor:0.3").parameters("rain")["supervision"] == \
        "sim-editor:0.3"
    frames, record = supervision_frames(truth_scene, "sim-editor:0.3", ("rain",), 0.0, 0)
    assert record["method"] == "sim-editor" and record["severity"] == 0.3 and len(frames["rain"]) == 12
    assert record["weather_check"] == {"rain": "unverified: the scene records no weather of its truth"}
    # the filter2d record: its settings and how its weather relates to the physics
    _, f2d = supervision_frames(truth_scene, "filter2d", ("rain",), 0.0, 0)
    assert set(f2d) == {"method", "effects", "jitter", "seed", "parameters", "physics", "weather_check"}
    assert f2d["physics"]["rain"]["unverified"].startswith("filter2d's rain is a 2D grade with no rate")
    with pytest.raises(InputError, match="'filter2d', sim-editor\\[:SEVERITY\\] or READER:DIR"):
        supervision_frames(truth_scene, "nowhere", ("rain",), 0.0, 0)
