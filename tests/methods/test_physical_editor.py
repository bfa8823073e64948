"""``physical-editor``: runs as a method, stays still from frame to frame, refuses a scene without
lidar, and the one weather spec: supervision checked against the run's physics."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from wcbench.cli import main
from wcbench.core.errors import InputError
from wcbench.core.image_io import read_rgb8

pytest.importorskip("torch")

from wcbench.methods.weather_spec import (
    check_consistent,
    parse_physics,
    physics_record,
    resolve_physics,
)
from wcbench.reference_model.weather.conditions import Weather


@pytest.mark.model
def test_run_edits_every_weather_without_flicker_and_records_its_physics(tmp_path, demo_scene):
    out = tmp_path / "run"
    args = ["run", "--method", "physical-editor", "--scenes", "demo", "--out", str(out), "--no-progress",
            "--metrics", "temporal_flicker"]
    assert main(args) == 0
    root = out / "physical-editor" / "demo"
    # the demo street is 320x180, under the editor's 480 px: edited at its own size, clear is the raw frame
    np.testing.assert_array_equal(read_rgb8(root / "clear" / "003.png"), read_rgb8(demo_scene.frames[3].image_path))
    results = json.loads((out / "results.json").read_text())["results"]["demo"]
    for kind in ("rain", "snow", "fog"):
        info = json.loads((root / kind / "info.json").read_text())
        physics = info["parameters"]["physics"]
        assert physics["weather"]["kind"] == kind
        assert physics == physics_record(Weather(kind=kind))  # the presets (the demo records no weather)
        edited = read_rgb8(root / kind / "003.png").astype(float)
        assert np.abs(edited - read_rgb8(demo_scene.frames[3].image_path)).mean() > 5.0
        # anchored in the world: no more flicker than the raw sequence (the bound: 1.1)
        assert results[kind]["temporal_flicker_ratio"]["value"] <= 1.1
    fog = json.loads((root / "fog" / "info.json").read_text())["parameters"]["physics"]
    assert fog["visibility_m"] == pytest.approx(150.0)
    rain = json.loads((root / "rain" / "info.json").read_text())["parameters"]["physics"]
    assert rain["rate_mm_h"] == 7.6


@pytest.mark.model
def test_frames_are_deterministic(tmp_path, demo_scene):
    from wcbench.methods import get_method

    a = get_method("physical-editor").render(demo_scene, "snow", tmp_path / "a", frames=[2, 7], show_progress=False)
    b = get_method("physical-editor").render(demo_scene, "snow", tmp_path / "b", frames=[2, 7], show_progress=False)
    assert [f["sha256"] for f in a["frames"]] == [f["sha256"] for f in b["frames"]]


@pytest.mark.model
def test_a_scene_without_lidar_exits_2_naming_what_is_missing(tmp_path, demo_scene, capsys):
    scene = tmp_path / "no_lidar"
    shutil.copytree(demo_scene.root, scene)
    shutil.rmtree(scene / "lidar")
    out = tmp_path / "run"
    assert main(["run", "--method", "physical-editor", "--scenes", str(scene), "--weathers", "rain",
                 "--metrics", "psnr", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert str(scene) in err and "needs the scene's lidar" in err
    assert not list(out.rglob("*.png"))


def test_physics_option_and_resolution(demo_scene):
    assert parse_physics(None, who="m") == "auto"
    with pytest.raises(InputError, match="m: physics must be 'auto', 'truth', 'presets'"):
        parse_physics("sunny", who="m")
    with pytest.raises(InputError, match=r"physics\['hail'\]: not an edited weather"):
        parse_physics({"hail": {}}, who="m")
    with pytest.raises(InputError, match=r"physics\['rain'\]"):
        parse_physics({"rain": {"rate_mm_h": -1}}, who="m")
    given = parse_physics({"fog": {"visibility_m": 60}}, who="m")
    physics = resolve_physics(demo_scene, given, seed=5)
    assert physics["fog"].visibility_m == 60 and physics["rain"] == Weather(kind="rain", seed=5)
    # "auto" on a scene that records no weather: the presets
    assert resolve_physics(demo_scene, "auto", seed=5) == resolve_physics(demo_scene, "presets", seed=5)
    with pytest.raises(InputError, match=r"truth[/\\]weather\.json: not found"):
        resolve_physics(demo_scene, "truth")


def test_a_contradicting_weather_is_refused_with_both_values():
    fog = Weather(kind="fog", visibility_m=150.0)
    check_consistent("fog", fog, physics_record(Weather(kind="fog", visibility_m=150.0 * 1.001)), source="x")
    with pytest.raises(InputError, match=r"edits/fog/info\.json: its fog was made with visibility 60 m, "
                                         r"the run's physics fog has visibility 150 m"):
        check_consistent("fog", fog, physics_record(Weather(kind="fog", visibility_m=60.0)),
                         source="edits/fog/info.json")
    with pytest.raises(InputError, match=r"made at 2\.5 mm/h, the run's physics rain is 25\.0 mm/h"):
        check_consistent("rain", Weather(kind="rain", preset="heavy"),
                         physics_record(Weather(kind="rain", preset="light")), source="s")


@pytest.mark.model
def test_weathercity_supervision_is_checked_against_its_physics(tmp_path, demo_scene):
    from wcbench.methods import get_method
    from wcbench.methods.filter2d import Filter2DMethod
    from wcbench.methods.scene_training import supervision_frames

    physics = {"fog": Weather(kind="fog", visibility_m=150.0)}
    # filter2d fogs at the run's physics visibility (here another than the scene's), and says so
    dense = {"fog": Weather(kind="fog", visibility_m=60.0)}
    frames, record = supervision_frames(demo_scene, "filter2d", ("fog", "rain"), 0.0, 0, physics=dense)
    assert record["weather_check"]["fog"] == "consistent: filter2d fogs at the run's physics visibility 60 m"
    assert record["weather_check"]["rain"].startswith("unverified: filter2d's rain and snow are a 2D grade")
    assert record["parameters"]["fog"]["visibility_m"] == pytest.approx(60.0)
    assert record["physics"]["fog"]["visibility_m"] == pytest.approx(60.0)
    own = Filter2DMethod(effects=False).render_frame(demo_scene, "fog", 4, seed=0)  # the scene's 150 m
    assert np.abs(frames["fog"][4].astype(float) - own.astype(float)).mean() > 1.0
    # a folder of edits that records its weather: the same physics reads as consistent...
    edits = tmp_path / "edits"
    editor = get_method("physical-editor", physics={"fog": {"visibility_m": 60.0}})
    editor.render(demo_scene, "fog", edits / "fog", show_progress=False)
    with pytest.raises(InputError, match=r"fog[/\\]info\.json: its fog was made with visibility 60 m, the run's "
                                         r"physics fog has visibility 150 m"):
        supervision_frames(demo_scene, f"physical-editor:{edits}", ("fog",), 0.0, 0, physics=physics)
    _, ok = supervision_frames(demo_scene, f"physical-editor:{edits}", ("fog",), 0.0, 0,
                                physics={"fog": Weather(kind="fog", visibility_m=60.0)})
    assert ok["weather_check"]["fog"].startswith("consistent")
    # ...and a folder that records none is used, marked unverified
    bare = tmp_path / "bare"
    shutil.copytree(edits, bare)
    (bare / "fog" / "info.json").unlink()
    _, unverified = supervision_frames(demo_scene, f"folder:{bare}", ("fog",), 0.0, 0, physics=physics)
    assert unverified["weather_check"]["fog"].startswith("unverified")


def test_precipitation_rate_of_every_kind_of_weather():
    assert Weather(kind="rain", preset="heavy").precipitation_rate() == 25.0
    assert Weather(kind="snow", rate_mm_h=1.2).precipitation_rate() == 1.2
    # a fixed-count preset has no rate of its own: the kind's default preset's stands for it
    assert Weather(kind="rain", preset="paper").precipitation_rate() == 7.6
    assert Weather(kind="snow", count=5000).precipitation_rate() == 0.5
    assert Weather(kind="fog").precipitation_rate() == 0.0 and Weather().precipitation_rate() == 0.0


def test_jitter_without_filter2d_supervision_is_refused_before_training():
    from wcbench.methods import get_method

    with pytest.raises(InputError, match="jitter perturbs the filter2d supervision only"):
        get_method("weathercity", jitter=0.5)  # the default supervision is the physical editor
    assert get_method("weathercity", supervision="filter2d", jitter=0.5).jitter == 0.5
