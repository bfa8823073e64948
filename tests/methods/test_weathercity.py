"""The weathercity method end to end on the demo street (tiny settings), ``wcbench train``, and the
``filter2d`` options its supervision uses."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from wcbench.cli import main
from wcbench.methods import get_method
from wcbench.methods.filter2d import Filter2DMethod

#: Tiny training: 96x54, 24 steps, no far points (the demo street is fully covered by lidar).
TINY = '{"width": 96, "iterations": 24, "voxel_m": 0.5, "densify_from": 8, "densify_until": 16, ' \
       '"densify_interval": 8, "checkpoint_interval": 8}'


@pytest.mark.model
def test_run_weathercity_trains_at_its_resolution_renders_at_the_scenes_scores_and_records_training(tmp_path):
    pytest.importorskip("torch")
    out = tmp_path / "run"
    args = ["run", "--method", "weathercity", "--scenes", "demo", "--profile", "quick", "--out", str(out),
            "--weathers", "clear", "fog", "--metrics", "psnr", "fps", "--no-progress",
            "--method-option", f"settings={TINY}", "--method-option", "holdout=[5]"]
    assert main(args) == 0
    info = json.loads((out / "weathercity" / "demo" / "fog" / "info.json").read_text())
    assert info["size"] == [320, 180]  # the scene's size, not the training's
    assert info["timings"]["train_s"] > 0
    # the physics it rendered (the fog preset: the demo records no weather), and no draw of a truth
    assert info["parameters"]["physics"]["visibility_m"] == pytest.approx(150.0)
    assert info["parameters"]["truth_draw"]["used"] is False
    training = info["parameters"]["training"]
    assert training["iterations"] == 24 and training["resumed_at"] == 0 and training["views"]["size"] == [96, 54]
    assert training["trained_weathers"] == ["clear", "rain", "snow", "fog"]
    assert "not built" in training["scene_graph"]["skipped"]["nonrigid_nodes"]
    assert training["content_loss"].startswith("skipped:")  # no VGG16 in the test's model store
    assert np.isfinite(training["holdout"]["mean_psnr"])
    results = json.loads((out / "results.json").read_text())
    clear = results["results"]["demo"]["clear"]
    # the model trained at 96x54 renders 320x180 frames, scored against the raw ones as they are
    assert clear["psnr"]["value"] > 18.0
    assert not results.get("working_size")  # nothing resized to be scored
    # a second run finds the finished frames: nothing is trained or rendered again
    assert main(args) == 0
    again = json.loads((out / "weathercity" / "demo" / "fog" / "info.json").read_text())
    assert again["timings"]["train_s"] == info["timings"]["train_s"]
    assert json.loads((out / "results.json").read_text())["results"] == results["results"]


@pytest.mark.model
def test_train_cli_writes_facts_and_a_second_call_loads_the_checkpoint(tmp_path, capsys):
    pytest.importorskip("torch")
    args = ["train", "--scenes", "demo", "--profile", "quick", "--out", str(tmp_path / "t"), "--no-progress",
            "--checkpoint", str(tmp_path / "ckpt"), "--holdout", "5"]
    args += [f"--setting={k}={json.dumps(v)}" for k, v in json.loads(TINY).items()]
    assert main(args) == 0
    facts = json.loads((tmp_path / "t" / "demo" / "training.json").read_text())
    assert facts["iterations"] == 24 and facts["resumed_at"] == 0
    assert (tmp_path / "ckpt" / "checkpoint.json").is_file()
    assert "held-out PSNR" in capsys.readouterr().out
    assert main(args) == 0
    again = json.loads((tmp_path / "t" / "demo" / "training.json").read_text())
    assert again["resumed_at"] == 24 and again["train_seconds"] == facts["train_seconds"]


@pytest.mark.slow  # 25 s: two CLI trainings end to end
@pytest.mark.model
def test_one_scene_by_a_relative_and_an_absolute_path_trains_once(tmp_path, demo_scene, monkeypatch):
    pytest.importorskip("torch")
    root = Path(demo_scene.root).resolve()
    monkeypatch.chdir(tmp_path)
    base = ["train", "--profile", "quick", "--no-progress", "--checkpoint", str(tmp_path / "ckpt"), "--holdout", "5"]
    base += [f"--setting={k}={json.dumps(v)}" for k, v in json.loads(TINY).items()]
    resumed = []
    for spelling in (os.path.relpath(root, tmp_path), str(root)):
        assert main([*base, "--scenes", spelling, "--out", str(tmp_path / "t")]) == 0
        resumed.append(json.loads(next((tmp_path / "t").glob("*/training.json")).read_text())["resumed_at"])
    assert resumed == [0, 24]  # the second spelling loads the first's model: the key holds no path


@pytest.mark.parametrize("args, message", [
    (["--setting", "iterations"], "expected KEY=VALUE"),
    (["--setting", "colour=1"], "settings.colour=1: settings takes no option colour"),
    (["--profile", "fast"], "profile=fast: expected one of 'default', 'quick'"),
    (["--ablation", "no-sky"], "ablation=no-sky: expected one of '', 'no-wgs'"),
    (["--holdout", "40"], "has frames 0..11"),
    (["--supervision", "nowhere"], "supervision=nowhere: expected 'physical-editor', 'filter2d'"),
])
@pytest.mark.model
def test_train_cli_refuses_bad_options_by_name(tmp_path, capsys, args, message):
    pytest.importorskip("torch")
    assert main(["train", "--scenes", "demo", "--out", str(tmp_path), "--no-progress", *args]) == 2
    assert message in capsys.readouterr().err


def test_weathercity_method_refuses_bad_options():
    pytest.importorskip("torch")
    from wcbench.core.errors import InputError

    with pytest.raises(InputError, match="jitter"):
        get_method("weathercity", jitter=2.0)
    with pytest.raises(InputError, match="unknown operation"):
        get_method("weathercity", edits="explode id=3")


def test_filter2d_jitter_is_seeded_per_frame_and_supervision_drops_streaks(demo_scene):
    plain, drawn = Filter2DMethod(effects=False), Filter2DMethod()
    a = plain.render_frame(demo_scene, "rain", 3, seed=0)
    assert not np.array_equal(a, drawn.render_frame(demo_scene, "rain", 3, seed=0))  # streaks drawn or not
    jit = Filter2DMethod(effects=False, jitter=0.5)
    j1, j2 = jit.render_frame(demo_scene, "rain", 3, seed=0), jit.render_frame(demo_scene, "rain", 3, seed=0)
    assert np.array_equal(j1, j2)  # deterministic under the seed
    assert np.abs(j1.astype(int) - a).mean() > 1.0  # and perturbed
    other = jit.render_frame(demo_scene, "rain", 4, seed=0).astype(int) - plain.render_frame(demo_scene, "rain", 4,
                                                                                              seed=0)
    assert not np.allclose(other.mean(), (j1.astype(int) - a).mean(), atol=0.05)  # each frame its own draw
    assert Filter2DMethod().parameters("rain") == Filter2DMethod(effects=True, jitter=0.0).parameters("rain")


#: One process asking for the demo street's TINY model (``train_scene``, as `wcbench train` and `run`
#: do); it reports what it did and a digest of the model it ends up with. Its trainer counts every
#: training and every supervision edit (the physical editor's) and, in the process that holds the
#: lock, starts training only once the other process says it waits, so the two requests always
#: overlap however the machine schedules them.
TWO_REQUESTS = """
import hashlib, json, os, sys, time
from pathlib import Path
from wcbench.methods import scene_training
from wcbench.reference_model.training.config import make_config
from wcbench.scenes.sets import resolve_scenes

waiting, trainings, edits = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[4])
train, edit_scene = scene_training.Trainer.train, scene_training.edit_scene

def counted_edit(*args, **kwargs):
    with edits.open("a") as fh:
        fh.write(f"{os.getpid()}\\n")
    return edit_scene(*args, **kwargs)

scene_training.edit_scene = counted_edit

def counted_train(self, *args, **kwargs):
    with trainings.open("a") as fh:
        fh.write(f"{os.getpid()}\\n")
    deadline = time.monotonic() + 120
    while not waiting.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    return train(self, *args, **kwargs)

scene_training.Trainer.train = counted_train
said = []

def log(message):
    said.append(message)
    if "waiting for another process training" in message:
        waiting.touch()

scene = resolve_scenes("demo")[0].load()
model, views, facts = scene_training.train_scene(scene, make_config("quick", **json.loads(sys.argv[3])),
                                             show_progress=False, log=log)
digest = hashlib.sha256()
for name, tensor in sorted(model.state_dict().items()):
    digest.update(name.encode() + tensor.detach().cpu().numpy().tobytes())
print(json.dumps({"pid": os.getpid(), "resumed_at": facts["resumed_at"], "train_seconds": facts["train_seconds"],
                  "lock_wait_seconds": facts["lock_wait_seconds"], "checkpoint": facts["checkpoint"],
                  "model": digest.hexdigest(), "said": said,
                  # what is not a parameter (object poses, the sky's window) renders the same too
                  "renders": scene_training.evaluate_views(model, views[:3])["psnr"]}))
"""


@pytest.mark.slow  # 22 s: two processes; the lock itself is tested in tests/core/test_locking.py
@pytest.mark.model
def test_two_processes_training_one_model_train_once_and_the_second_loads_it(tmp_path, demo_scene):
    pytest.importorskip("torch")
    import subprocess
    import sys

    # the demo scene is in the session's cache (demo_scene), so both processes only read it
    args = [str(tmp_path / "waiting"), str(tmp_path / "trainings"), TINY, str(tmp_path / "edits")]
    procs = [subprocess.Popen([sys.executable, "-c", TWO_REQUESTS, *args], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outs = [p.communicate(timeout=600) for p in procs]
    for p, (_, err) in zip(procs, outs):
        assert p.returncode == 0, err[-2000:]
    reports = [json.loads(out.strip().splitlines()[-1]) for out, _ in outs]
    trainings = (tmp_path / "trainings").read_text().split()
    assert len(trainings) == 1  # one training in all
    trained, loaded = sorted(reports, key=lambda r: r["resumed_at"])
    assert trained["pid"] == int(trainings[0]) and trained["resumed_at"] == 0
    # the waiting process waited before the supervision: it edited nothing (it once edited every
    # weather again before it waited, 1.4x one training in all)
    assert (tmp_path / "edits").read_text().split() == [str(trained["pid"])]
    assert loaded["resumed_at"] == 24  # loaded the finished checkpoint: no step of its own
    assert loaded["train_seconds"] == trained["train_seconds"] and loaded["checkpoint"] == trained["checkpoint"]
    assert loaded["model"] == trained["model"]  # the same model, parameter for parameter
    assert loaded["renders"] == trained["renders"]
    waits = [m for m in loaded["said"] if "waiting for another process" in m]
    assert len(waits) == 1 and f"training demo (pid {trained['pid']}, since " in waits[0]
    assert not [m for m in trained["said"] if "waiting" in m]
    assert trained["lock_wait_seconds"] == 0 and loaded["lock_wait_seconds"] > 0


@pytest.mark.model
def test_render_frame_from_fixed_rows_equals_its_concatenating_twin(demo_scene):
    # the fast path (FrameRows, only the objects' rows written per frame) against render_frame_concat:
    # the same Gaussians in the same relative order, the objects' centres equal within float32 rounding:
    # uint8 frames within 1 (a pixel whose alpha threshold an ulp flips) on under 0.1 % of the pixels
    torch = pytest.importorskip("torch")
    import weather_models as wm

    from wcbench.methods.weathercity import WeatherCityMethod
    from wcbench.reference_model.model.decoders import WeatherDecoders
    from wcbench.reference_model.model.objects import RigidObject
    from wcbench.reference_model.model.scene_model import WeatherCityModel
    from wcbench.reference_model.model.sky import SkyModel

    def ahead(k: int, metres: float) -> np.ndarray:
        shift = np.eye(4)
        shift[2, 3] = metres
        return demo_scene.frames[k].camera.camera_to_world @ shift

    # a hand-made model in the demo street's frame: the wall 10 m ahead of the first camera, a car 6 m
    # ahead of each camera in every other frame (absent in the others)
    wall = wm.wall()
    first = torch.from_numpy(ahead(0, 0.0).astype(np.float32))
    with torch.no_grad():
        wall.means.copy_(wall.means @ first[:3, :3].T + first[:3, 3])
    frames = np.arange(0, len(demo_scene), 2)
    car = RigidObject(wm.car(200), track_id="9", class_name="Car", frames=frames,
                      object_to_world=np.stack([ahead(k, 6.0) for k in frames]), box_size=np.full(3, 1.6),
                      n_frames=len(demo_scene))
    weathers = ("clear", "rain", "snow", "fog")
    model = WeatherCityModel(wall, [car], [], WeatherDecoders(weathers, feature_dim=8, hidden=16),
                             SkyModel(weathers, up=demo_scene.up, heading=ahead(0, 1.0)[:3, 2], rows=8, cols=16))
    for weather in ("rain", "clear"):
        fast, slow = WeatherCityMethod(size=(96, 54)), WeatherCityMethod(size=(96, 54))
        for method in (fast, slow):
            method.use_model(demo_scene, model, {})
            method.prepare(demo_scene, weather, seed=3)
        for k in [*range(6), 0]:  # the car present, absent, present... and back to the first frame
            got, info = fast.render_frame(demo_scene, weather, k, seed=3)
            ref, _ = slow.render_frame_concat(demo_scene, weather, k, seed=3)
            diff = np.abs(got.astype(np.int16) - ref)
            assert diff.max() <= 1 and (diff > 0).mean() < 1e-3, (weather, k)  # see FrameRows: float32 rounding
            # the car's rows are culled for their zero opacity where it is absent
            assert info["raster_meta"]["culled_transparent"] >= (200 if k % 2 else 0)


class _Prepared(Exception):
    """Raised instead of making a training's inputs (the supervision's editing): the request was not
    found."""


@pytest.mark.slow  # 35 s of CPU: one tiny training, then six requests
@pytest.mark.model
def test_a_request_made_again_loads_its_model_without_editing_and_any_change_edits_again(
        tmp_path, demo_scene, monkeypatch):
    pytest.importorskip("torch")
    import dataclasses
    import shutil

    import cv2

    from wcbench.methods import scene_training
    from wcbench.reference_model.training.config import make_config
    from wcbench.scenes.sets import resolve_scenes

    root = tmp_path / "demo_street"  # a copy whose files this test changes
    shutil.copytree(demo_scene.root, root)
    scene = resolve_scenes(str(root))[0].load()
    config = make_config("quick", **json.loads(TINY))
    # trained here, or loaded by its model key when another test of the session trained the demo street
    model, _, facts = scene_training.train_scene(scene, config, show_progress=False, log=lambda m: None)

    def refuse(*args, **kwargs):
        raise _Prepared

    monkeypatch.setattr(scene_training, "training_inputs", refuse)
    said: list[str] = []
    again, views, loaded = scene_training.train_scene(scene, config, show_progress=False, log=said.append)
    assert loaded["resumed_at"] == 24 and loaded["key"] == facts["key"] and loaded["request"] == facts["request"]
    assert {k: v for k, v in loaded.items() if k not in ("resumed_at", "prepare_seconds")} == \
        {k: v for k, v in facts.items() if k not in ("resumed_at", "prepare_seconds")}
    assert any("loaded the model trained for this request" in m for m in said)
    assert all(set(v.images) == {"clear"} for v in views)  # no supervision made
    psnr = [scene_training.evaluate_views(m, views[:2])["psnr"] for m in (again, model)]
    assert psnr[0] == psnr[1]  # what is not a parameter (object poses, the sky's window) renders the same too
    # every part of the request is in its key: other supervision, physics or scene data edit again
    with pytest.raises(_Prepared):
        scene_training.train_scene(scene, config, supervision="filter2d", show_progress=False, log=lambda m: None)
    physics = scene_training.resolve_physics(scene, "presets")
    physics["fog"] = dataclasses.replace(physics["fog"], visibility_m=80.0, fog_density=None)
    with pytest.raises(_Prepared):
        scene_training.train_scene(scene, config, physics=physics, show_progress=False, log=lambda m: None)
    image = cv2.imread(str(root / "images" / "003_0.png"))
    image[0, 0] ^= 1
    cv2.imwrite(str(root / "images" / "003_0.png"), image)
    with pytest.raises(_Prepared):
        scene_training.train_scene(scene, config, show_progress=False, log=lambda m: None)
    image[0, 0] ^= 1
    cv2.imwrite(str(root / "images" / "003_0.png"), image)
    scene_training.train_scene(scene, config, show_progress=False, log=lambda m: None)  # loaded again
    # a record whose checkpoint is gone is not trusted
    shutil.rmtree(facts["checkpoint"])
    with pytest.raises(_Prepared):
        scene_training.train_scene(scene, config, show_progress=False, log=lambda m: None)


@pytest.mark.slow  # 15 s of CPU: two tiny trainings
@pytest.mark.model
def test_a_model_of_other_code_is_trained_anew_not_loaded_or_resumed(tmp_path, demo_scene, monkeypatch):
    pytest.importorskip("torch")
    from wcbench.methods import scene_training
    from wcbench.reference_model.training.config import make_config

    config = make_config("quick", **json.loads(TINY))
    folder = tmp_path / "ckpt"
    _, _, facts = scene_training.train_scene(demo_scene, config, folder=folder, show_progress=False,
                                             log=lambda m: None)
    assert facts["resumed_at"] == 0
    # the same request by other code (an update of the package): the finished checkpoint in the same
    # folder is of another model key, so it is trained over, from the first step
    monkeypatch.setattr(scene_training, "_source_digest", lambda: "0" * 64)
    _, _, again = scene_training.train_scene(demo_scene, config, folder=folder, show_progress=False,
                                             log=lambda m: None)
    assert again["resumed_at"] == 0 and again["key"] != facts["key"] and again["request"] != facts["request"]
    assert json.loads((folder / "checkpoint.json").read_text())["key"] == again["key"]


@pytest.mark.model
def test_an_object_of_another_scene_is_carried_in_on_the_ground_and_recorded(tmp_path):
    """``insert scene=... at=``: the method finds the other scene (a folder, one beside, or a
    built-in set), sets the object down on the lidar's ground and records the fit in ``describe``;
    bad names fail before any training. The models are the hand-made ones (no training here)."""
    pytest.importorskip("torch")
    import weather_models as wm

    from wcbench.core.errors import InputError
    from wcbench.scenes.sets import get_scene_set

    scene = get_scene_set("synth_1").scenes[0].load()
    method = get_method("weathercity", edits=["remove class=vehicle", "insert scene=synth_1 id=5 at=20,1,30"])
    method.check_scene(scene, "rain")
    method._sources["synth_1"] = wm.make_model(("clear", "rain"))  # stands for the trained source model
    method.use_model(scene, wm.make_model(("clear", "rain")), {})
    (placed,) = method.describe()["placed_objects"]
    assert placed["node"] == "rigid:synth_1/5#1" and placed["carried"] and placed["clear_error"] < 0.02
    pose = np.asarray(placed["object_to_world"])
    ground = np.percentile(scene.all_lidar_points()[:, 2], 5)  # the synthetic street is flat
    assert pose[:2, 3] == pytest.approx([20.0, 1.0])
    assert pose[2, 3] - 0.8 == pytest.approx(ground, abs=0.1)  # its box (1.6 m tall) on the ground
    assert method._placement.hidden == {"rigid:5"}  # the removal came first: the carried car stays
    for edits, match in [("insert scene=nowhere id=5 at=0,0,0", "no scene 'nowhere'"),
                         ("insert scene=synth_1 id=99 at=0,0,0", "has no track '99'"),
                         ("insert id=99 at=0,0,0", "has no track '99'")]:
        with pytest.raises(InputError, match=match):
            get_method("weathercity", edits=edits).check_scene(scene, "rain")


def test_the_source_scene_is_a_path_or_a_folder_beside_the_scene(tmp_path, demo_scene):
    """``insert scene=NAME``: NAME as a path, then as a folder beside the scene's own, then a built-in set."""
    pytest.importorskip("torch")
    import shutil

    from wcbench.methods.weathercity import source_scene
    from wcbench.scenes.loaders import load_scene

    for name in ("street_a", "street_b"):
        shutil.copytree(demo_scene.root, tmp_path / name)
    here = load_scene(tmp_path / "street_a")
    assert Path(source_scene(here, "street_b").root) == tmp_path / "street_b"  # beside
    assert Path(source_scene(here, str(tmp_path / "street_b")).root) == tmp_path / "street_b"  # a path
    with pytest.raises(ValueError, match="no scene 'street_c'"):
        source_scene(here, "street_c")
