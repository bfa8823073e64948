"""Each tool's real output tree, rebuilt from what its released code writes, scored end to end.

The trees follow the tools' code (names, zero padding, formats, sibling folders, frame counts and
sizes), never wcbench's own conventions, and are read without renaming a file and without
``--pattern``:

* TurboEdit (GiilDe/turbo-edit main.py): ``{output_dir}/output_{i}.png``, no padding, 512x512.
* FRESCO (williamyang1991/FRESCO): ``keys/%04d.png`` (keyframes), ``video/%04d.png`` (the unedited
  input, resized), ``blend/%04d.jpg`` + ``blend.mp4`` up to the last keyframe (30 frames give 25);
  short side 512, sides multiples of 64.
* ClimateNeRF (Climate_NeRF render.py): ``frames/{:03d}-rgb.png`` beside ``{:03d}-depth.png``,
  ``render_traj.mp4``; effects smog, water, snow.
* WeatherCity (tools/eval.py, tools/train.py, tools/add_weather_effect.py): ``videos_eval/<weather>/
  full_set_<step>_rgbs/{t:03d}_{cam:03d}.png`` beside ``_gt_rgbs`` and ``_depths``, an mp4 a row and
  a column short, ``raw`` always rendered; train.py's own final evaluation in ``videos/<weather>/``
  (no depths; ``images/<w>/step_*`` visualisations beside); ``images/<weather>/effects/
  effects_{i:03d}.png``; runs to ``end_timestep: -1`` (more frames than the scene, ``--frames``) and
  from a later ``start_timestep`` (``--frame-offset``).
* ControlNet writes no files: its documented wcbench convention (``<weather>/<source stem>``),
  short side 512, sides multiples of 64.
* Qwen-Image: WeatherCity's README layout ``<scene_idx>/images/<weather>/<raw name>.jpg`` in
  drivestudio's processed folders (``788``, not ``waymo_788``; PandaSet's ``002``), ~1 megapixel,
  sides multiples of 32; every image of the folder edited when the scene is a window of it.

Fast: the built-in demo scene (12 frames, 320x180) and a generated 30-frame ``waymo_5`` data root
(64x48 frames).
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from scene_fixtures import make_waymo_scene

from wcbench.cli import main
from wcbench.core.errors import InputError
from wcbench.core.image_io import read_rgb8, write_mp4
from wcbench.methods import get_method
from wcbench.predictions import find_scene_folder, match_predictions
from wcbench.scenes.sets import SceneRef

WAYMO_IDS = ("023", "114", "327", "621", "788")
CHEAP = ["--metrics", "temporal_flicker", "psnr", "fps", "--fps", "2.5"]


# --------------------------------------------------------------------------- helpers
def _street(t: int, size: tuple[int, int], seed: int) -> np.ndarray:
    """A smooth frame that moves with t (uint8 RGB [H, W, 3])."""
    w, h = size
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    rgb = np.stack([128 + 90 * np.sin((x + 2 * t + 7 * seed) / 9.0),
                    128 + 90 * np.cos((y - t + 3 * seed) / 7.0),
                    128 + 60 * np.sin((x + y + 3 * t) / 11.0)], axis=-1)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def _edit(img: np.ndarray, weather: str) -> np.ndarray:
    """A stand-in for a tool's weather edit at the tool's own size (uint8 RGB)."""
    f = img.astype(np.float32)
    if weather == "rain":
        f = f * 0.75
        f[:, ::9] = np.minimum(255, f[:, ::9] + 70)  # streaks
    elif weather == "snow":
        f = 0.65 * f + 0.35 * 245
    else:  # fog / smog
        f = 0.5 * f + 0.5 * 200
    return np.clip(f, 0, 255).astype(np.uint8)


def _write(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fast_png = [cv2.IMWRITE_PNG_COMPRESSION, 0] if path.suffix == ".png" else []  # same pixels, faster
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), fast_png)


def _short_side_512(w: int, h: int) -> tuple[int, int]:
    """(W, H) with the short side scaled to 512 and both rounded to multiples of 64 (FRESCO's
    and ControlNet's resize_image)."""
    k = 512 / min(w, h)
    return int(np.round(w * k / 64)) * 64, int(np.round(h * k / 64)) * 64


def _about_one_megapixel(w: int, h: int) -> tuple[int, int]:
    """(W, H) of about 1024x1024 pixels at the input's aspect, sides multiples of 32 (Qwen-Image)."""
    k = (1024 * 1024 / (w * h)) ** 0.5
    return int(np.round(w * k / 32)) * 32, int(np.round(h * k / 32)) * 32


def _tool_size(img: np.ndarray, size: tuple[int, int], *, lanczos: bool = False) -> np.ndarray:
    """``img`` at a tool's size: INTER_AREA to shrink; to enlarge, Lanczos as FRESCO's and ControlNet's
    resize_image do, or a cheap linear filter where the pixels do not matter (the stand-in edits)."""
    up = size[0] * size[1] > img.shape[0] * img.shape[1]
    interp = (cv2.INTER_LANCZOS4 if lanczos else cv2.INTER_LINEAR) if up else cv2.INTER_AREA
    return cv2.resize(img, size, interpolation=interp)


def _frames(scene) -> list[np.ndarray]:
    return [read_rgb8(f.image_path) for f in scene.frames]


def _evaluate(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["evaluate", *args])
    out, err = capsys.readouterr()
    return code, out, err


def _results(out: Path) -> dict:
    return json.loads((out / "results.json").read_text())


@pytest.fixture(scope="module")
def waymo_root(tmp_path_factory) -> Path:
    """A data root holding the five scenes of ``waymo_5``: 30 frames of 64x48 each."""
    root = tmp_path_factory.mktemp("waymo_data")
    for seed, idx in enumerate(WAYMO_IDS):
        scene_dir = root / "waymo" / "processed" / "training" / idx
        make_waymo_scene(scene_dir, n_frames=30, size=(64, 48))
        for t in range(30):
            _write(scene_dir / "images" / f"{t:03d}_0.jpg", _street(t, (64, 48), seed))
    return root


@pytest.fixture(scope="module")
def waymo_scenes(waymo_root):
    from wcbench.scenes.sets import resolve_scenes

    return {ref.path.name: ref.load() for ref in resolve_scenes("waymo_5", data_root=waymo_root)}


# --------------------------------------------------------------------------- TurboEdit
def test_turboedit_output_tree_scores_as_written(demo_scene, tmp_path, capsys):
    """main.py: one --output_dir per (scene, weather), output_{i}.png for the i-th JSON entry, 512x512."""
    frames = _frames(demo_scene)
    preds = tmp_path / "turbo"
    for weather in ("rain", "snow"):
        for i, img in enumerate(frames):
            _write(preds / "demo_street" / weather / f"output_{i}.png", _tool_size(_edit(img, weather), (512, 512)))
    names = sorted(p.name for p in (preds / "demo_street" / "rain").iterdir())
    assert "output_10.png" in names and "output_010.png" not in names  # no padding
    out = tmp_path / "out"
    code, _, err = _evaluate(capsys, "--method", "turboedit", "--scenes", "demo", "--predictions", str(preds),
                             "--out", str(out), *CHEAP)
    assert code == 0, err
    doc = _results(out)
    res = doc["results"]["demo"]
    assert set(res) == {"rain", "snow"}
    assert len(res["rain"]["temporal_flicker"]["per_frame"]) == len(frames) - 1
    assert res["rain"]["fps"]["value"] == 2.5
    # psnr needs a ground truth: none for edited weathers
    assert {(s["weather"], s["metric"]) for s in doc["skipped"]} == {("rain", "psnr"), ("snow", "psnr")}
    # the preset declares that TurboEdit resizes: resized once, recorded with the interpolation
    assert doc["resized"] == [
        {"scene": "demo", "weather": w, "from": [[512, 512]], "to": [320, 180],
         "interpolation": doc["config"]["resize_interpolation"]} for w in ("rain", "snow")]
    assert "INTER_AREA" in doc["config"]["resize_interpolation"]
    assert doc["partial"] == [] and doc["warnings"] == []
    # the same tree under the generic reader: a size mismatch stays an error
    code, _, err = _evaluate(capsys, "--method", "folder", "--scenes", "demo", "--predictions", str(preds),
                             "--out", str(tmp_path / "o2"), "--pattern", "{weather}/output_{frame}.png", *CHEAP)
    assert code == 2 and "512x512, expected 320x180" in err and "--resize" in err


def test_turboedit_frame_offset_maps_output_i_to_scene_frame_i_plus_n(demo_scene, tmp_path):
    """A prompts JSON that started at scene frame 2: output_i is scene frame i + 2. TurboEdit does not
    declare that it can end early, so the scene frames without an output stay an error naming them."""
    frames = _frames(demo_scene)
    root = tmp_path / "turbo"
    for i, img in enumerate(frames[2:]):
        _write(root / "rain" / f"output_{i}.png", _edit(cv2.resize(img, (512, 512)), "rain"))
    reader = get_method("turboedit")
    with pytest.raises(InputError, match=r"missing frames \[0, 1\] \(frames \[0, 1\] come before the tool's first "
                                         r"frame with --frame-offset 2"):
        reader.open_predictions(demo_scene, "rain", root, frame_offset=2)
    with pytest.raises(InputError, match=r"missing frames \[10, 11\]"):
        reader.open_predictions(demo_scene, "rain", root)


# --------------------------------------------------------------------------- FRESCO
def _fresco_run(save_path: Path, frames: list[np.ndarray], weather: str, *, keys: list[int]) -> tuple[int, int]:
    """FRESCO's save_path after run_fresco.py (video/, keys/) and video_blend.py (blend/%04d.jpg from
    the first to the last keyframe, blend.mp4). Returns FRESCO's frame size."""
    size = _short_side_512(frames[0].shape[1], frames[0].shape[0])
    resized = [_tool_size(img, size, lanczos=True) for img in frames]
    for i, img in enumerate(resized):
        _write(save_path / "video" / f"{i:04d}.png", img)  # the unedited input, resized
    for k in keys:
        _write(save_path / "keys" / f"{k:04d}.png", _edit(resized[k], weather))
    blended = [_edit(img, weather) for img in resized[: keys[-1]]]
    for i, img in enumerate(blended):
        _write(save_path / "blend" / f"{i:04d}.jpg", img)
    write_mp4(save_path / "blend.mp4", blended)
    return size


@pytest.fixture(scope="module")
def fresco_runs(waymo_scenes, tmp_path_factory) -> Path:
    """FRESCO's save_path of scene 788 in rain, keyframes 0, 9, 17, 25 (copied by tests that change it)."""
    root = tmp_path_factory.mktemp("fresco_runs")
    assert _fresco_run(root / "rain", _frames(waymo_scenes["788"]), "rain", keys=[0, 9, 17, 25]) == (704, 512)
    return root


def _copy_run(fresco_runs: Path, dst: Path, weathers: tuple[str, ...] = ("rain",)) -> Path:
    for w in weathers:
        shutil.copytree(fresco_runs / w, dst / w)
    return dst


def test_fresco_tree_scores_the_blended_frames_and_names_the_missing_tail(waymo_scenes, fresco_runs, tmp_path,
                                                                          capsys):
    """30 input frames whose last keyframe is 25: blend/ holds 0000-0024.jpg; frames 25-29 are named."""
    scene = waymo_scenes["788"]
    preds = fresco_runs  # short side 512, sides multiples of 64: 704x512
    assert sorted(p.name for p in (preds / "rain").iterdir()) == ["blend", "blend.mp4", "keys", "video"]
    assert len(list((preds / "rain" / "blend").glob("*.jpg"))) == 25
    assert len(list((preds / "rain" / "video").glob("*.png"))) == 30
    out = tmp_path / "out"
    code, stdout, err = _evaluate(capsys, "--method", "fresco", "--scenes", str(scene.root), "--predictions",
                                  str(preds), "--out", str(out), *CHEAP)
    assert code == 0, err
    doc = _results(out)
    assert [(p["weather"], p["scored"], p["missing"], p["n_scene_frames"]) for p in doc["partial"]] == [
        ("rain", [0, 24], [25, 26, 27, 28, 29], 30)]
    assert "video_blend.py" in doc["partial"][0]["reason"]
    flicker = doc["results"]["788"]["rain"]["temporal_flicker"]
    assert len(flicker["per_frame"]) == 24  # pairs (0,1) ... (23,24): never 24 against 29
    assert doc["inputs"]["scenes"]["788"]["rain"]["frames"] == list(range(25))
    assert doc["inputs"]["scenes"]["788"]["rain"]["layout"] == "{weather}/blend/{frame}.jpg"
    assert "partial: 788 rain: scored frames 0-24 of 30, missing 25-29" in stdout
    df = pd.read_csv(out / "results.csv", dtype={"missing_frames": str})
    assert set(df["missing_frames"]) == {"25-29"} and set(df["n_frames"]) == {25}
    assert doc["warnings"] == []


def test_fresco_blend_video_and_frame_offset(waymo_scenes, fresco_runs, tmp_path):
    """blend.mp4 alone is read the same way; a video that started at scene frame 5 maps frame i to 5 + i."""
    scene = waymo_scenes["788"]
    run = _copy_run(fresco_runs, tmp_path / "fresco") / "rain"
    shutil.rmtree(run / "blend")
    reader = get_method("fresco")
    seq = reader.open_predictions(scene, "rain", tmp_path / "fresco")
    assert seq.is_video and seq.frame_indices == list(range(25)) and seq.missing == [25, 26, 27, 28, 29]
    assert len(list(seq)) == 25
    seq = reader.open_predictions(scene, "rain", tmp_path / "fresco", frame_offset=5)
    assert seq.frame_indices == list(range(5, 30)) and seq.missing == [0, 1, 2, 3, 4]
    with pytest.raises(InputError, match="video frames 24 fall outside the scene with --frame-offset 6"):
        reader.open_predictions(scene, "rain", tmp_path / "fresco", frame_offset=6)


def test_fresco_save_path_given_directly_for_one_weather(waymo_scenes, fresco_runs, tmp_path, capsys):
    """FRESCO's save_path holds one (scene, weather): with one scene and one --weathers, both folder
    levels may be left out."""
    scene = waymo_scenes["788"]
    save_path = fresco_runs / "rain"
    code, _, err = _evaluate(capsys, "--method", "fresco", "--scenes", str(scene.root), "--predictions",
                             str(save_path), "--weathers", "rain", "--out", str(tmp_path / "out"), *CHEAP)
    assert code == 0, err
    assert _results(tmp_path / "out")["partial"][0]["missing"] == [25, 26, 27, 28, 29]


def test_fresco_keyframes_only_says_to_run_the_blend(waymo_scenes, fresco_runs, tmp_path, capsys):
    """Without video_blend.py there are only keyframes: an error that says so, not "folder not found"."""
    scene = waymo_scenes["788"]
    run = _copy_run(fresco_runs, tmp_path / "fresco") / "rain"
    shutil.rmtree(run / "blend")
    (run / "blend.mp4").unlink()
    code, _, err = _evaluate(capsys, "--method", "fresco", "--scenes", str(scene.root), "--predictions",
                             str(tmp_path / "fresco"), "--out", str(tmp_path / "out"), *CHEAP)
    assert code == 2 and not (tmp_path / "out").exists()
    assert str(tmp_path / "fresco" / "rain" / "keys") in err and "video_blend.py" in err
    assert "resized input frames, not an edit" in err
    # the same when the save_path itself is given for one weather
    code, _, err = _evaluate(capsys, "--method", "fresco", "--scenes", str(scene.root), "--predictions", str(run),
                             "--weathers", "rain", "--out", str(tmp_path / "out"), *CHEAP)
    assert code == 2 and str(run / "keys") in err and "video_blend.py" in err


def test_fresco_blend_with_a_hole_is_an_error(waymo_scenes, fresco_runs, tmp_path):
    """The tool may end early, never skip a frame in the middle."""
    scene = waymo_scenes["788"]
    _copy_run(fresco_runs, tmp_path)
    (tmp_path / "rain" / "blend" / "0007.jpg").unlink()
    with pytest.raises(InputError, match=r"missing frames \[7\] inside the sequence"):
        get_method("fresco").open_predictions(scene, "rain", tmp_path)


def test_pointing_at_frescos_video_folder_warns_that_the_frames_equal_the_source(waymo_scenes, fresco_runs, tmp_path,
                                                                                capsys):
    """FRESCO's video/ holds the unedited input (resized): scored by mistake, it is flagged."""
    scene = waymo_scenes["788"]
    save_path = fresco_runs / "rain"
    out = tmp_path / "out"
    code, _, err = _evaluate(capsys, "--method", "folder", "--resize", "--scenes", str(scene.root),
                             "--predictions", str(save_path / "video"), "--weathers", "rain", "--out", str(out),
                             "--metrics", "temporal_flicker")
    assert code == 0, err
    assert "warning: 788 rain: all 30 rain frames" in err and "look like the unedited input" in err
    doc = _results(out)
    (w,) = doc["warnings"]
    assert w["kind"] == "unedited" and not w["identical"] and w["max_thumbnail_difference"] < 1.0
    # the real edit of the same run raises no warning
    code, _, err = _evaluate(capsys, "--method", "fresco", "--scenes", str(scene.root), "--predictions",
                             str(save_path), "--weathers", "rain", "--out", str(tmp_path / "out2"),
                             "--metrics", "temporal_flicker")
    assert code == 0 and "warning" not in err and _results(tmp_path / "out2")["warnings"] == []


def test_byte_identical_frames_warn_and_clear_never_does(demo_scene, tmp_path, capsys):
    preds = tmp_path / "preds"
    for f in demo_scene.frames:
        for weather in ("clear", "snow"):
            (preds / weather).mkdir(parents=True, exist_ok=True)
            shutil.copy(f.image_path, preds / weather / f"{f.index:03d}.png")
    out = tmp_path / "out"
    code, _, err = _evaluate(capsys, "--method", "folder", "--scenes", "demo", "--predictions", str(preds),
                             "--out", str(out), "--metrics", "temporal_flicker")
    assert code == 0
    (w,) = _results(out)["warnings"]
    assert (w["weather"], w["identical"]) == ("snow", True) and "byte-identical" in w["message"]
    assert err.count("warning:") == 1
    # a re-run reuses the stored result and still warns
    code, stdout, err = _evaluate(capsys, "--method", "folder", "--scenes", "demo", "--predictions", str(preds),
                                  "--out", str(out), "--metrics", "temporal_flicker")
    assert code == 0 and "up to date" in stdout and "byte-identical" in err


# --------------------------------------------------------------------------- ClimateNeRF
def _depth_image(t: int, size: tuple[int, int]) -> np.ndarray:
    w, h = size
    depth = np.tile(np.linspace(0, 255, w, dtype=np.float32), (h, 1)) * (0.5 + 0.02 * t)
    return cv2.applyColorMap(np.clip(depth, 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO)


def test_climatenerf_results_tree_ignores_depth_maps_and_reads_smog_as_fog(demo_scene, tmp_path, capsys):
    """render.py with --exp_name demo_street/<effect>: frames/{:03d}-rgb.png and {:03d}-depth.png,
    render_traj.mp4 and render_traj_depth.mp4; the water effect exists but is no weather."""
    frames = _frames(demo_scene)
    results = tmp_path / "results" / "colmap"
    for effect in ("smog", "snow", "water"):
        exp = results / "demo_street" / effect
        rendered = [_edit(cv2.GaussianBlur(img, (3, 3), 0), "fog" if effect == "water" else effect) for img in frames]
        for i, img in enumerate(rendered):
            _write(exp / "frames" / f"{i:03d}-rgb.png", img)
            _write(exp / "frames" / f"{i:03d}-depth.png", _depth_image(i, (320, 180)))
        write_mp4(exp / "render_traj.mp4", rendered)
        write_mp4(exp / "render_traj_depth.mp4", [_depth_image(i, (320, 180)) for i in range(len(frames))])
    out = tmp_path / "out"
    code, _, err = _evaluate(capsys, "--method", "climatenerf", "--scenes", "demo", "--predictions", str(results),
                             "--out", str(out), *CHEAP)
    assert code == 0, err
    doc = _results(out)
    assert sorted(doc["results"]["demo"]) == ["fog", "snow"]
    fog = doc["inputs"]["scenes"]["demo"]["fog"]
    assert fog["location"] == str(results / "demo_street" / "smog" / "frames")
    assert fog["ignored"] == [f"{i:03d}-depth.png" for i in range(12)]
    assert doc["config"]["scene_folders"]["demo"]["matched"] == "demo_street"
    # the same folder read without the ignore rule: the depth siblings are extra files
    with pytest.raises(InputError, match=r"extra files \['000-depth.png'"):
        match_predictions(demo_scene, "snow", results / "demo_street", pattern="{weather}/frames/{frame}-rgb.png")
    # ClimateNeRF makes no rain
    code, _, err = _evaluate(capsys, "--method", "climatenerf", "--scenes", "demo", "--predictions", str(results),
                             "--out", str(tmp_path / "o2"), "--weathers", "rain")
    assert code == 2 and "does not support weather 'rain' (supports snow, fog)" in err


def test_climatenerf_fog_under_both_names_is_ambiguous(demo_scene, tmp_path):
    for name in ("smog", "fog"):
        for i, img in enumerate(_frames(demo_scene)):
            _write(tmp_path / name / "frames" / f"{i:03d}-rgb.png", img)
    with pytest.raises(InputError, match="matches 2 places for weather 'fog'") as exc:
        get_method("climatenerf").open_predictions(demo_scene, "fog", tmp_path)
    assert str(tmp_path / "smog" / "frames") in str(exc.value) and str(tmp_path / "fog" / "frames") in str(exc.value)


# --------------------------------------------------------------------------- WeatherCity
def _weathercity_eval_run(run: Path, scene, weathers: list[str], *, step: int = 30000) -> None:
    """tools/eval.py of one run: videos_eval/<w>/full_set_<step>_<key>/{t:03d}_000.png for the render
    keys, full_set_<step>_<key>.mp4 (a row and a column short), metrics_eval/<w>/*.json; "raw" first."""
    frames = _frames(scene)
    w, h = scene.image_size
    for weather in ["raw", *weathers]:
        base = run / "videos_eval" / weather
        gt = frames if weather == "raw" else [_edit(f, weather) for f in frames]  # the training targets
        renders = {
            "rgbs": [cv2.GaussianBlur(f, (3, 3), 0) for f in gt],
            "gt_rgbs": gt,
            "Background_rgbs": [np.full_like(f, (0, 177, 64)) for f in gt],
            "depths": [cv2.cvtColor(_depth_image(t, (w, h)), cv2.COLOR_BGR2RGB) for t in range(len(gt))],
        }
        for key, images in renders.items():
            for t, img in enumerate(images):
                _write(base / f"full_set_{step}_{key}" / f"{t:03d}_000.png", img)
            write_mp4(base / f"full_set_{step}_{key}.mp4", [img[: h - 1, : w - 1] for img in images])
        metrics = run / "metrics_eval" / weather
        metrics.mkdir(parents=True, exist_ok=True)
        (metrics / "images_full_2026-01-01_00-00-00.json").write_text(json.dumps({"psnr": 30.0}))
    (run / "config.yaml").write_text("data:\n  scene_idx: 0\n")


def test_weathercity_eval_runs_of_five_scenes(waymo_root, waymo_scenes, tmp_path, capsys):
    """output/<project>/<scene>_1_cam_000_029 per scene (README): raw is read as clear, the step is
    any number, _gt_rgbs/_depths/_Background_rgbs and the mp4s are left alone."""
    project = tmp_path / "output" / "waymo_weathercity"
    for idx, scene in waymo_scenes.items():
        name = {"023": "23", "621": "waymo_621"}.get(idx, idx)  # data.scene_idx=23 for 023; a run named by id
        run_name = f"{name}_1_cam_000_029"
        _weathercity_eval_run(project / run_name, scene, ["rain", "snow"])
    out = tmp_path / "out"
    code, stdout, err = _evaluate(capsys, "--method", "weathercity-release", "--scenes", "waymo_5", "--data-root",
                                  str(waymo_root), "--predictions", str(project), "--out", str(out), *CHEAP)
    assert code == 0, err
    doc = _results(out)
    assert sorted(doc["results"]) == [f"waymo_{i}" for i in WAYMO_IDS]
    for res in doc["results"].values():
        assert sorted(res) == ["clear", "rain", "snow"]
        assert 25 < res["clear"]["psnr"]["value"] < 60  # raw render against the raw frames
    folders = doc["config"]["scene_folders"]
    assert folders["waymo_788"]["folder"] == str(project / "788_1_cam_000_029")
    assert "folder pattern '{scene}_*'" in folders["waymo_788"]["rule"]
    assert folders["waymo_023"]["matched"] == "23" and "alias" in folders["waymo_023"]["rule"]
    assert "scene waymo_788: predictions from" in stdout and "788_1_cam_000_029" in stdout
    assert f"scene waymo_621: predictions from {project / 'waymo_621_1_cam_000_029'}" in stdout
    clear = doc["inputs"]["scenes"]["waymo_788"]["clear"]
    assert clear["location"] == str(project / "788_1_cam_000_029" / "videos_eval" / "raw" / "full_set_30000_rgbs")
    assert doc["resized"] == [] and doc["partial"] == [] and doc["warnings"] == []


def test_weathercity_step_wildcard_and_other_cameras(waymo_scenes, tmp_path):
    scene = waymo_scenes["788"]
    run = tmp_path / "788"
    _weathercity_eval_run(run, scene, ["rain"])
    reader = get_method("weathercity-release")
    # other cameras of a multi-camera run sit beside the front camera's frames
    for t in range(30):
        _write(run / "videos_eval" / "rain" / "full_set_30000_rgbs" / f"{t:03d}_001.png", _street(t, (64, 48), 9))
    seq = reader.open_predictions(scene, "rain", run)
    assert [p.name for p in seq.files] == [f"{t:03d}_000.png" for t in range(30)]
    assert len(seq.ignored) == 30
    # {step} is digits only: full_set_best_rgbs is no step
    rain = run / "videos_eval" / "rain"
    shutil.copytree(rain / "full_set_30000_rgbs", rain / "full_set_best_rgbs")
    seq = reader.open_predictions(scene, "rain", run)
    assert seq.location.name == "full_set_30000_rgbs" and seq.passed_over == []
    # eval.py run on an earlier checkpoint too: the highest step is read, the other one named
    shutil.copytree(rain / "full_set_30000_rgbs", rain / "full_set_20000_rgbs")
    shutil.copytree(rain / "full_set_30000_rgbs", rain / "full_set_100000_rgbs")  # numbers, not text order
    seq = reader.open_predictions(scene, "rain", run)
    assert seq.location.name == "full_set_100000_rgbs"
    assert seq.passed_over == ["videos_eval/rain/full_set_20000_rgbs", "videos_eval/rain/full_set_30000_rgbs"]
    assert seq.left_out() == {"passed_over": seq.passed_over}
    seq = reader.open_predictions(scene, "rain", run,
                                  pattern="videos_eval/{weather}/full_set_20000_rgbs/{frame}_000.png")
    assert seq.location.name == "full_set_20000_rgbs" and seq.passed_over == []
    # one step under two spellings is no order: ambiguous, both named
    shutil.copytree(rain / "full_set_100000_rgbs", rain / "full_set_0100000_rgbs")
    with pytest.raises(InputError, match="matches 2 places for weather 'rain'") as exc:
        reader.open_predictions(scene, "rain", run)
    assert "full_set_0100000_rgbs" in str(exc.value) and "full_set_100000_rgbs" in str(exc.value)


def test_weathercity_effects_run(waymo_scenes, tmp_path, capsys):
    """tools/add_weather_effect.py: images/<w>/effects/effects_{i:03d}.png, images/<w>/raw/raw_{i:03d}.png,
    videos/<w>/effects.mp4 and raw.mp4, for rain, snow and fog."""
    scene = waymo_scenes["788"]
    run = tmp_path / "output_effects" / "waymo_weathercity_effects" / "788_1_cam_000_029_effects"
    frames = _frames(scene)
    for weather in ("rain", "snow", "fog"):
        raw = [cv2.GaussianBlur(f, (3, 3), 0) for f in frames]
        effects = [_edit(f, weather) for f in raw]
        for i, (e, r) in enumerate(zip(effects, raw)):
            _write(run / "images" / weather / "effects" / f"effects_{i:03d}.png", e)
            _write(run / "images" / weather / "raw" / f"raw_{i:03d}.png", r)
        write_mp4(run / "videos" / weather / "effects.mp4", effects)
        write_mp4(run / "videos" / weather / "raw.mp4", raw)
    (run / "config.yaml").write_text("seed: 0\n")
    (run / "weather_effects_config.yaml").write_text("fog:\n  intensity: 0.1\n")
    out = tmp_path / "out"
    code, _, err = _evaluate(capsys, "--method", "weathercity-release", "--scenes", str(scene.root), "--predictions",
                             str(run), "--out", str(out), *CHEAP)
    assert code == 0, err
    doc = _results(out)
    assert sorted(doc["results"]["788"]) == ["fog", "rain", "snow"]
    assert doc["inputs"]["scenes"]["788"]["fog"]["layout"] == "images/{weather}/effects/effects_{frame}.png"
    assert doc["config"]["scene_folders"]["788"]["rule"] == "the predictions folder itself: one scene is scored"


# --------------------------------------------------------------------------- ControlNet
def test_controlnet_documented_convention(demo_scene, tmp_path, capsys):
    """ControlNet writes no files; its wcbench convention is <weather>/<source stem>.<ext> at
    ControlNet's size (short side 512, multiples of 64), as `methods list -v` shows."""
    size = _short_side_512(*demo_scene.image_size)
    assert size == (896, 512)
    preds = tmp_path / "controlnet"
    for f, img in zip(demo_scene.frames, _frames(demo_scene)):
        _write(preds / "demo_street" / "snow" / f"{f.image_path.stem}.png", _tool_size(_edit(img, "snow"), size))
    out = tmp_path / "out"
    code, _, err = _evaluate(capsys, "--method", "controlnet", "--scenes", "demo", "--predictions", str(preds),
                             "--out", str(out), *CHEAP)
    assert code == 0, err
    doc = _results(out)
    assert list(doc["results"]["demo"]) == ["snow"]
    assert doc["resized"][0]["from"] == [[896, 512]]
    assert main(["methods", "list", "-v"]) == 0
    listing = capsys.readouterr().out
    assert "rain/000_0.png" in listing and "for images/000_0.jpg" in listing


# --------------------------------------------------------------------------- Qwen-Image
def test_qwen_image_edits_in_weathercity_readme_layout(waymo_root, waymo_scenes, tmp_path, capsys):
    """<scene_idx>/images/<weather>/<raw name>.jpg inside drivestudio's processed folders: folders 788...
    are matched to waymo_788..., ~1 megapixel frames with sides multiples of 32."""
    training = tmp_path / "data" / "waymo" / "processed" / "training"
    size = _about_one_megapixel(64, 48)
    assert size == (1184, 896) and size[0] % 32 == 0 and size[1] % 32 == 0
    for idx, scene in waymo_scenes.items():
        for f, img in zip(scene.frames, _frames(scene)):
            _write(training / idx / "images" / "raw" / f.image_path.name, img)
            _write(training / idx / "images" / "rain" / f.image_path.name, _tool_size(_edit(img, "rain"), size))
        (training / idx / "sky_masks").mkdir()
    out = tmp_path / "out"
    code, stdout, err = _evaluate(capsys, "--method", "qwen-image", "--scenes", "waymo_5", "--data-root",
                                  str(waymo_root), "--predictions", str(training), "--out", str(out),
                                  "--metrics", "temporal_flicker")
    assert code == 0, err
    doc = _results(out)
    assert sorted(doc["results"]) == [f"waymo_{i}" for i in WAYMO_IDS]
    assert {sid: f["matched"] for sid, f in doc["config"]["scene_folders"].items()} == {
        f"waymo_{i}": i for i in WAYMO_IDS}
    assert "scene waymo_788: predictions from" in stdout and "(named like the scene's data folder, 788)" in stdout
    assert doc["resized"][0]["from"] == [[1184, 896]]
    # a folder under both names is ambiguous: an error naming both
    (training / "waymo_788").mkdir()
    code, _, err = _evaluate(capsys, "--method", "qwen-image", "--scenes", "waymo_5", "--data-root",
                             str(waymo_root), "--predictions", str(training), "--out", str(tmp_path / "o2"),
                             "--metrics", "temporal_flicker")
    assert code == 2 and "several folders could hold scene 'waymo_788'" in err
    assert "  788  (named like the scene's data folder, 788)" in err and "  waymo_788  (the scene id)" in err


def test_scene_folder_names_from_the_scene_set(tmp_path):
    ref = SceneRef(id="waymo_023", format="drivestudio_waymo", path=tmp_path / "data" / "023", aliases=("23",))
    preds = tmp_path / "preds"
    (preds / "23_1_cam_000_029").mkdir(parents=True)
    (preds / "230_1_cam_000_029").mkdir()
    with pytest.raises(InputError, match="no folder for scene 'waymo_023'"):
        find_scene_folder(preds, ref, n_scenes=5)
    found = find_scene_folder(preds, ref, n_scenes=5, folder_patterns=["{scene}_*"])
    assert (found.path.name, found.matched) == ("23_1_cam_000_029", "23")
    (preds / "023").mkdir()
    with pytest.raises(InputError, match="several folders could hold scene 'waymo_023'"):
        find_scene_folder(preds, ref, n_scenes=5, folder_patterns=["{scene}_*"])


# --------------------------------------------------------------------------- drivestudio's naming, longer renders
def _weathercity_train_run(run: Path, scene, weathers: list[str], *, step: int = 30000,
                           n_frames: int | None = None) -> None:
    """What tools/train.py leaves in its log dir: setup() makes images/, videos/, metrics/,
    buffer_maps/ per weather ("raw" first), config.yaml, configs_bk/, backup/; the training loop
    writes images/<w>/step_<s>_<key>.png visualisations; at the last step do_evaluation (no "_eval"
    postfix) writes videos/<w>/full_set_<step>_<key>/{t:03d}_000.png and full_set_<step>_<key>.mp4
    for train.py's render keys (no depths) and metrics/<w>/images_full_<time>.json. ``n_frames``:
    how many timesteps the run rendered (more than the scene for end_timestep -1)."""
    frames = _frames(scene)
    n = n_frames or len(frames)
    frames = [frames[t % len(frames)] if t < len(frames) else _street(t, scene.image_size, 5) for t in range(n)]
    w, h = scene.image_size
    for folder in ("configs_bk", "backup"):
        (run / folder).mkdir(parents=True, exist_ok=True)
    for weather in ["raw", *weathers]:
        for folder in ("images", "videos", "metrics", "buffer_maps"):
            (run / folder / weather).mkdir(parents=True, exist_ok=True)
        gt = frames if weather == "raw" else [_edit(f, weather) for f in frames]
        renders = {"gt_rgbs": gt, "rgbs": [cv2.GaussianBlur(f, (3, 3), 0) for f in gt],
                   "Background_rgbs": [np.full_like(f, (0, 177, 64)) for f in gt]}
        base = run / "videos" / weather
        for key, images in renders.items():
            for t, img in enumerate(images):
                _write(base / f"full_set_{step}_{key}" / f"{t:03d}_000.png", img)
            write_mp4(base / f"full_set_{step}_{key}.mp4", [img[: h - 1, : w - 1] for img in images])
            _write(run / "images" / weather / f"step_0_{key}.png", images[0])
        (run / "metrics" / weather / "images_full_2026-01-01_00-00-00.json").write_text(json.dumps({"psnr": 30.0}))
    (run / "config.yaml").write_text("data:\n  scene_idx: 788\n  start_timestep: 0\n  end_timestep: -1\n")


def test_weathercity_training_run_is_read_from_its_final_evaluation(waymo_scenes, tmp_path, capsys):
    """tools/train.py alone (no tools/eval.py): videos/<w>/full_set_<step>_rgbs/ is read, raw as clear."""
    scene = waymo_scenes["788"]
    project = tmp_path / "output" / "waymo_weathercity"
    run = project / "788_1_cam_000_029"
    _weathercity_train_run(run, scene, ["rain", "snow"])
    out = tmp_path / "out"
    code, stdout, err = _evaluate(capsys, "--method", "weathercity-release", "--scenes", str(scene.root),
                                  "--predictions", str(project), "--out", str(out), *CHEAP)
    assert code == 0, err
    doc = _results(out)
    assert sorted(doc["results"]["788"]) == ["clear", "rain", "snow"]
    assert 25 < doc["results"]["788"]["clear"]["psnr"]["value"] < 60  # the raw render against the raw frames
    rec = doc["inputs"]["scenes"]["788"]["rain"]
    assert rec["location"] == str(run / "videos" / "rain" / "full_set_30000_rgbs")
    assert rec["layout"] == "videos/{weather}/full_set_{step}_rgbs/{frame}_000.png"
    assert rec["frames"] == list(range(30)) and "passed_over" not in rec and "outside_scene" not in rec
    assert doc["config"]["scene_folders"]["788"]["folder"] == str(run)
    assert f"scene 788: predictions from {run}" in stdout
    # training continued to 50000 in the same log dir: the highest step is read, the other named
    _weathercity_train_run(run, scene, ["rain", "snow"], step=50000)
    code, _, err = _evaluate(capsys, "--method", "weathercity-release", "--scenes", str(scene.root),
                             "--predictions", str(project), "--out", str(tmp_path / "out2"), *CHEAP)
    assert code == 0, err
    rec = _results(tmp_path / "out2")["inputs"]["scenes"]["788"]["clear"]
    assert rec["location"] == str(run / "videos" / "raw" / "full_set_50000_rgbs")
    assert rec["passed_over"] == ["videos/raw/full_set_30000_rgbs"]
    # tools/eval.py run afterwards: its videos_eval/ is read first
    _weathercity_eval_run(run, scene, ["rain"], step=50000)
    seq = get_method("weathercity-release").open_predictions(scene, "rain", run)
    assert seq.location == run / "videos_eval" / "rain" / "full_set_50000_rgbs"
    seq = get_method("weathercity-release").open_predictions(scene, "snow", run)  # not in videos_eval/
    assert seq.location == run / "videos" / "snow" / "full_set_50000_rgbs"


def test_weathercity_training_run_killed_before_its_evaluation_says_so(waymo_scenes, tmp_path, capsys):
    """train.py makes videos/<w>/ at set-up and fills it at its last step: an empty one is explained."""
    scene = waymo_scenes["788"]
    run = tmp_path / "788_1_cam_000_029"
    _weathercity_train_run(run, scene, ["rain"])
    shutil.rmtree(run / "videos" / "rain")
    (run / "videos" / "rain").mkdir()
    code, _, err = _evaluate(capsys, "--method", "weathercity-release", "--scenes", str(scene.root),
                             "--predictions", str(run), "--weathers", "rain", "--out", str(tmp_path / "out"))
    assert code == 2 and str(run / "videos" / "rain") in err
    assert "tools/train.py writes its final evaluation" in err and "tools/eval.py" in err


@pytest.fixture
def pandaset_data(demo_scene, tmp_path) -> Path:
    """A data root holding ``pandaset_002`` (the demo street's 12 frames stand in for its pixels)."""
    root = tmp_path / "data"
    shutil.copytree(demo_scene.root, root / "pandaset_002")
    return root


def test_pandaset_002_is_matched_under_drivestudios_names(pandaset_data, demo_scene, tmp_path, capsys):
    """drivestudio's PandaSet preprocessing writes processed/002/ (sequence id zero-padded to 3 digits)
    and its configs select it as data.scene_idx=2: Qwen-Image edits in processed/002/images/<w>/ and a
    WeatherCity run named after scene_idx 2 are both matched to pandaset_002."""
    processed = tmp_path / "pandaset" / "processed"
    size = _about_one_megapixel(*demo_scene.image_size)
    for f, img in zip(demo_scene.frames, _frames(demo_scene)):
        _write(processed / "002" / "images" / "raw" / f.image_path.name, img)
        _write(processed / "002" / "images" / "fog" / f.image_path.name, _tool_size(_edit(img, "fog"), size))
    (processed / "002" / "lidar").mkdir()
    (processed / "001" / "images").mkdir(parents=True)  # another processed sequence beside it
    out = tmp_path / "out"
    code, stdout, err = _evaluate(capsys, "--method", "qwen-image", "--scenes", "pandaset_002", "--data-root",
                                  str(pandaset_data), "--predictions", str(processed), "--out", str(out),
                                  "--metrics", "temporal_flicker")
    assert code == 0, err
    folder = _results(out)["config"]["scene_folders"]["pandaset_002"]
    assert (folder["folder"], folder["matched"]) == (str(processed / "002"), "002") and "alias" in folder["rule"]
    assert f"scene pandaset_002: predictions from {processed / '002'}" in stdout

    project = tmp_path / "output" / "pandaset_weathercity"
    _weathercity_eval_run(project / "2_1_cam_000_011", demo_scene, ["rain"])
    (project / "1_1_cam_000_011").mkdir()
    out = tmp_path / "out_wc"
    code, _, err = _evaluate(capsys, "--method", "weathercity-release", "--scenes", "pandaset_002", "--data-root",
                             str(pandaset_data), "--predictions", str(project), "--out", str(out), *CHEAP)
    assert code == 0, err
    doc = _results(out)
    assert sorted(doc["results"]["pandaset_002"]) == ["clear", "rain"]
    folder = doc["config"]["scene_folders"]["pandaset_002"]
    assert (folder["folder"], folder["matched"]) == (str(project / "2_1_cam_000_011"), "2")


def test_weathercity_render_of_the_whole_sequence_needs_frames(pandaset_data, demo_scene, tmp_path, capsys):
    """The dataset configs render to end_timestep -1: a run of a 20-frame sequence holds 000_000 ...
    019_000 for a 12-frame scene. Refused with the way out named; with --frames 0-11 the scene's
    frames are read and the 8 others counted."""
    project = tmp_path / "output" / "pandaset_weathercity"
    run = project / "2_1_cam_000_019"
    _weathercity_train_run(run, demo_scene, ["snow"], n_frames=20)
    args = ["--method", "weathercity-release", "--scenes", "pandaset_002", "--data-root", str(pandaset_data),
            "--predictions", str(project), *CHEAP]
    code, _, err = _evaluate(capsys, *args, "--out", str(tmp_path / "refused"))
    assert code == 2 and not (tmp_path / "refused").exists()
    assert str(run / "videos") in err and "extra files ['012_000.png'" in err
    assert "frames 12-19 beyond the scene's frames 0-11" in err and "--frames 0-11" in err and "--frame-offset" in err
    out = tmp_path / "out"
    code, _, err = _evaluate(capsys, *args, "--frames", "0-11", "--out", str(out))
    assert code == 0, err
    doc = _results(out)
    for weather in ("clear", "snow"):
        rec = doc["inputs"]["scenes"]["pandaset_002"][weather]
        assert rec["frames"] == list(range(12)) and rec["outside_scene"] == {"count": 8, "frames": "12-19"}
        assert len(doc["results"]["pandaset_002"][weather]["temporal_flicker"]["per_frame"]) == 11
    assert doc["partial"] == []


def test_weathercity_render_from_a_later_start_timestep(waymo_scenes, tmp_path, capsys):
    """data.start_timestep=5 data.end_timestep=29: 000_000 is timestep 5, 25 frames. The errors name
    --frame-offset; with it and --frames 5-29 the run is scored on the frames it rendered."""
    scene = waymo_scenes["788"]
    run = tmp_path / "788_1_cam_005_029"
    frames = _frames(scene)
    for t, img in enumerate(frames[5:]):
        _write(run / "videos_eval" / "rain" / "full_set_30000_rgbs" / f"{t:03d}_000.png", _edit(img, "rain"))
    args = ["--method", "weathercity-release", "--scenes", str(scene.root), "--predictions", str(run),
            "--weathers", "rain", "--metrics", "temporal_flicker"]
    code, _, err = _evaluate(capsys, *args, "--out", str(tmp_path / "o1"))
    assert code == 2 and "missing frames [25, 26, 27, 28, 29]" in err
    assert "--frame-offset N when the tool's first frame is scene frame N" in err
    code, _, err = _evaluate(capsys, *args, "--frame-offset", "5", "--out", str(tmp_path / "o2"))
    assert code == 2 and "frames [0, 1, 2, 3, 4] come before the tool's first frame with --frame-offset 5" in err
    code, _, err = _evaluate(capsys, *args, "--frame-offset", "5", "--frames", "5-29", "--out", str(tmp_path / "o3"))
    assert code == 0, err
    rec = _results(tmp_path / "o3")["inputs"]["scenes"]["788"]["rain"]
    assert rec["frames"] == list(range(5, 30)) and "outside_scene" not in rec
    seq = get_method("weathercity-release").open_predictions(scene, "rain", run, frame_offset=5, frames=range(5, 30))
    assert [p.name for p in seq.files[:2]] == ["000_000.png", "001_000.png"] and seq.frame_indices[0] == 5


def test_qwen_image_edits_of_the_whole_processed_folder(waymo_root, tmp_path):
    """WeatherCity's README has every image of the processed folder edited; a scene that is a window
    of it (start 5, 20 frames) reads its own frames with --frames and counts the others, numbered
    like scene frames (-5 ... -1 before it, 20 ... 24 after it)."""
    ref = SceneRef(id="waymo_788", format="drivestudio_waymo", path=waymo_root / "waymo" / "processed" / "training" /
                   "788", options={"camera": 0, "start": 5, "count": 20})
    scene = ref.load()
    assert scene.frames[0].image_path.name == "005_0.jpg"
    training = tmp_path / "training"
    for img_path in sorted((ref.path / "images").glob("*_0.jpg")):
        _write(training / "788" / "images" / "rain" / img_path.name, _edit(read_rgb8(img_path), "rain"))
    _write(training / "788" / "images" / "rain" / "notes.jpg", np.zeros((8, 8, 3), np.uint8))
    reader = get_method("qwen-image")
    with pytest.raises(InputError, match=r"extra files \['notes.jpg'\]"):
        reader.open_predictions(scene, "rain", training / "788", frames=range(20))
    (training / "788" / "images" / "rain" / "notes.jpg").unlink()
    with pytest.raises(InputError, match=r"frames -5 to -1,20-24 beyond the scene's frames 0-19") as exc:
        reader.open_predictions(scene, "rain", training / "788")
    assert "--frames 0-19" in str(exc.value) and "--frame-offset" not in str(exc.value)  # names fix the frame
    seq = reader.open_predictions(scene, "rain", training / "788", frames=range(20))
    assert [p.name for p in seq.files] == [f"{t:03d}_0.jpg" for t in range(5, 25)]
    assert seq.left_out() == {"outside_scene": {"count": 10, "frames": "-5 to -1,20-24"}}


# --------------------------------------------------------------------------- listing
def test_methods_list_verbose_shows_each_readers_tree(capsys):
    assert main(["methods", "list", "-v"]) == 0
    listing = capsys.readouterr().out
    for needle in (
        "output_0.png output_1.png",                # turboedit
        "blend/0000.jpg", "video/0000.png",         # fresco
        "frames/000-depth.png", "water effect",     # climatenerf
        "full_set_30000_rgbs/000_000.png", "full_set_30000_gt_rgbs/",  # weathercity-release
        "images/rain/000_0.jpg",                    # qwen-image
        "reads {weather}/blend/{frame}.jpg, else {weather}/blend.mp4",
        "may end early", "ignores sibling files *-depth.png", "fog as 'smog'", "clear as 'raw'",
        "videos/raw/ videos/rain/", "tools/train.py's final evaluation",  # weathercity-release, train.py
        "the highest step is read", "needs --frame-offset N", "need --frames 0-29",
        "more frames than the scene (a render of a longer sequence): pass --frames",
        "more frames than the scene (edits of the whole processed folder): pass --frames",
        "--frame-offset N: the tool's frame i is scene frame i + N",
    ):
        assert needle in listing, needle
    rows = {line.split()[0]: line.split()[1:3] for line in listing.splitlines() if line and not line[0].isspace()}
    assert rows["weathercity-release"] == ["reader", "clear,rain,snow,fog"]
    assert rows["climatenerf"] == ["reader", "snow,fog"]


@pytest.mark.parametrize(("change", "message"), [
    ({"pattern": "{weather}/{frame}"}, "unknown keys ['pattern']"),
    ({"layouts": []}, "'layouts' is empty"),
    ({"layouts": "{weather}/{frame}"}, "'layouts' must be of type"),
    ({"weathers": ["rain", "hail"]}, "unknown weathers in weathers: ['hail']"),
    ({"weather_names": {"smog": ["fog"]}}, "unknown weathers in weather_names: ['smog']"),
    ({"resizes": "yes"}, "'resizes' must be of type"),
])
def test_presets_are_checked(change, message):
    from wcbench.methods.readers import check_preset, load_preset

    spec = {**load_preset("fresco"), **change}
    with pytest.raises(ValueError, match=re.escape(message)):
        check_preset(spec, name="fresco")
