"""drivestudio's processed layouts as its preprocessing writes them: PandaSet read, Argoverse 2 and
nuPlan refused by name, compact ids and one class vocabulary, and the behaviours drivestudio has
on load (Waymo lidar crop, fine dynamic masks, nuScenes 2 Hz folders, Waymo source weather)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from drivestudio_fixtures import savetxt, write_instances, write_pandaset_scene, write_waymo_scene
from scene_fixtures import make_waymo_scene, write_matrix, write_rgb

from wcbench.core.classes import canonical_class, same_class
from wcbench.core.errors import InputError
from wcbench.scenes import loaders
from wcbench.scenes.loaders import detect_format, load_scene


def test_pandaset_layout_loads_as_drivestudio_writes_it(tmp_path):
    root = tmp_path / "pandaset" / "processed" / "002"
    truth = write_pandaset_scene(root)
    assert detect_format(root) == "drivestudio_pandaset"
    scene = load_scene(root)
    assert scene.source_format == "drivestudio_pandaset" and len(scene) == 4
    assert scene.image_size == truth["size"]
    np.testing.assert_allclose(scene.frames[0].camera.center, 0.0, atol=1e-9)
    np.testing.assert_allclose([f.timestamp for f in scene.frames], [0.0, 0.1, 0.2, 0.3])
    assert scene.facts["frame_rate_hz"] == 10.0
    # lidar (ego frame + ego_pose) lands on the world ground (z = 0 at the origin's height)
    sweep = scene.lidar(2)
    ground = sweep.points[np.abs(sweep.points[:, 2] + 1.6) < 1e-3]  # 1.6 m below the first camera
    assert len(ground) > 100
    # the camera sees the ground ahead: points project inside the frame below the horizon
    uv, z = scene.frames[2].camera.project(ground)
    vis = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < 96) & (uv[:, 1] >= 0) & (uv[:, 1] < 54)
    assert vis.sum() > 50 and np.all(uv[vis, 1] > truth["K"][1, 2])
    # compact ids in drivestudio's order, shared classes, PandaSet names kept
    assert [(t.id, t.class_name, t.source_class) for t in scene.tracks] == [
        ("0", "vehicle", "Car"), ("1", "pedestrian", "Pedestrian"), ("2", "cyclist", "Bicycle"),
        ("3", "vehicle", "Pickup Truck"), ("4", "vehicle", "Car")]
    assert scene.tracks[0].source_id.startswith("7b1c1e04")
    assert scene.frames[0].dynamic_mask_path is not None
    assert scene.frames[0].sky_mask_path is None  # drivestudio leaves sky_masks/ empty


@pytest.mark.parametrize("layout, cams, name", [
    ("Argoverse 2", range(7), "000"),
    ("nuPlan", range(8), "2021.05.12.22.00.38_veh-35_01008_01518"),
])
def test_argoverse_and_nuplan_layouts_are_refused_by_name(tmp_path, layout, cams, name):
    root = tmp_path / name
    for cam in cams:
        write_rgb(root / "images" / f"000_{cam}.jpg", np.zeros((8, 8, 3), np.uint8))
        c2v = np.eye(4)
        c2v[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # OpenCV camera axes, as both write them
        savetxt(root / "extrinsics" / f"{cam}.txt", c2v)
        savetxt(root / "intrinsics" / f"{cam}.txt", np.array([10.0, 10, 4, 4, 0, 0, 0, 0, 0]))
    savetxt(root / "ego_pose" / "000.txt", np.eye(4))
    with pytest.raises(InputError, match=f"drivestudio's {layout} processed layout"):
        detect_format(root)
    with pytest.raises(InputError, match=layout):
        load_scene(root, format="drivestudio_waymo")


def test_opencv_axis_extrinsics_are_not_taken_for_waymo(tmp_path):
    root = tmp_path / "000"
    make_waymo_scene(root)
    c2v = np.eye(4)
    c2v[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]
    write_matrix(root / "extrinsics" / "0.txt", c2v)
    with pytest.raises(InputError, match="Argoverse 2 or nuPlan"):
        load_scene(root)


def test_the_cli_exits_2_naming_the_layout(tmp_path, capsys):
    from wcbench.cli import main

    root = tmp_path / "000"
    for cam in range(7):
        write_rgb(root / "images" / f"000_{cam}.jpg", np.zeros((8, 8, 3), np.uint8))
    savetxt(root / "ego_pose" / "000.txt", np.eye(4))
    assert main(["scenes", "show", str(root)]) == 2
    assert "Argoverse 2" in capsys.readouterr().err


def test_class_vocabulary_aliases():
    assert {canonical_class(n) for n in ("Vehicle", "vehicle.car", "Car", "Pickup Truck", "vehicle")} == {"vehicle"}
    assert {canonical_class(n) for n in ("Pedestrian", "human.pedestrian.adult", "Pedestrian with Object")} == {
        "pedestrian"}
    assert {canonical_class(n) for n in ("Cyclist", "vehicle.bicycle", "Bicycle")} == {"cyclist"}
    assert canonical_class("animal") == canonical_class("Animals - Other") == "animal"
    assert canonical_class("Truck") == "truck"  # not a dataset's name: only itself
    assert same_class("CAR", "vehicle") and not same_class("Car", "Pedestrian")


def _tracks(root: Path, names: list[str]) -> None:
    """Objects of the given dataset class names, keyed by raw ids, 10 m ahead of the start."""
    pose = np.array([[1, 0, 0, 1010], [0, 1, 0, -2000], [0, 0, 1, 50], [0, 0, 0, 1]], float)
    write_instances(root, [{"id": f"raw-{900 + n}", "class_name": c, "frames": [0, 1, 2, 3], "poses": [pose] * 4,
                            "sizes": [[4.0, 2.0, 1.5]] * 4} for n, c in enumerate(names)])


def _edit_hidden(scene, spec: str) -> set[str]:
    """Which track ids an edit hides, through the reference model's own selector."""
    from wcbench.reference_model.editing.edits import parse_edits, placement_for

    class Obj:  # the two attributes the selector reads of a scene-graph object
        def __init__(self, t):
            self.track_id, self.class_name = t.id, t.class_name

    objects = {f"rigid:{t.id}": Obj(t) for t in scene.tracks}
    return {k.split(":")[1] for k in placement_for(parse_edits(spec), objects).hidden}  # type: ignore[arg-type]


@pytest.mark.parametrize("names", [
    ["Vehicle", "Pedestrian", "Vehicle", "Vehicle", "Cyclist"],  # Waymo
    ["vehicle.car", "human.pedestrian.adult", "vehicle.truck", "vehicle.bus.rigid", "vehicle.bicycle"],  # nuScenes
    ["Car", "Pedestrian", "Pickup Truck", "Semi-truck", "Bicycle"],  # PandaSet
])
def test_edit_by_shared_class_and_compact_ids_works_on_every_dataset(tmp_path, names):
    pytest.importorskip("torch")
    root = tmp_path / "000"
    make_waymo_scene(root)
    _tracks(root, names)
    scene = load_scene(root)
    assert [t.id for t in scene.tracks] == ["0", "1", "2", "3", "4"]
    assert [t.class_name for t in scene.tracks] == ["vehicle", "pedestrian", "vehicle", "vehicle", "cyclist"]
    assert _edit_hidden(scene, "remove class=vehicle except ids=0,3") == {"2"}
    assert _edit_hidden(scene, f"remove class={names[0]}") == {"0", "2", "3"}  # the dataset's name is an alias


def test_synth_scene_ids_and_classes(tmp_path):
    """The synth scenes' instances_info (written like drivestudio's Waymo one) give ids 0, 1, ...
    and shared classes: the same edit selects the same way."""
    pytest.importorskip("torch")
    from wcbench.scenes.sets import resolve_scenes

    scene = resolve_scenes("synth_1")[0].load()
    assert [t.id for t in scene.tracks] == [str(n) for n in range(len(scene.tracks))]
    assert {t.class_name for t in scene.tracks} == {"vehicle"}
    hidden = _edit_hidden(scene, "remove class=vehicle except ids=0,3")
    assert hidden == {t.id for t in scene.tracks} - {"0", "3"}


def test_scenes_show_lists_compact_ids_and_classes(tmp_path, capsys):
    from wcbench.cli import main

    root = tmp_path / "pandaset" / "002"
    write_pandaset_scene(root)
    assert main(["scenes", "show", str(root)]) == 0
    out = capsys.readouterr().out
    assert "tracks       5 vehicle: 3, pedestrian: 1, cyclist: 1" in out
    lines = [ln.split() for ln in out.splitlines() if ln.strip()[:2] in ("0 ", "1 ", "2 ", "3 ", "4 ")]
    assert [ln[:2] for ln in lines] == [["0", "vehicle"], ["1", "pedestrian"], ["2", "cyclist"], ["3", "vehicle"],
                                        ["4", "vehicle"]]
    assert "Pickup Truck / 5d4c3b2a" in out


def test_waymo_lidar_is_cropped_like_drivestudio(tmp_path):
    root = tmp_path / "000"
    pts = np.array([[-5.0, 0, 0], [-1.9, 0, 0], [10.0, 1, 0], [79.9, 0, 0], [85.0, 0, 0], [-30, 4, 1]])
    write_waymo_scene(root, n_frames=1, points_vehicle=pts)
    scene = load_scene(root)
    sweep = scene.lidar(0)
    assert len(sweep.points) == 3  # x in (-2, 80) m of the vehicle frame
    assert scene.facts["lidar_crop_x_m"] == [-2.0, 80.0]


def test_fine_dynamic_masks_are_preferred(tmp_path):
    root = tmp_path / "000"
    make_waymo_scene(root)
    coarse = np.zeros((48, 64), np.uint8)
    for t in range(4):
        (root / "dynamic_masks" / "all").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / "dynamic_masks" / "all" / f"{t:03d}_0.png"), coarse)
    assert load_scene(root).frames[0].dynamic_mask_path.parent.parent.name == "dynamic_masks"
    (root / "fine_dynamic_masks" / "all").mkdir(parents=True)
    for t in range(3):  # frame 3 has no fine mask: its coarse one stays
        cv2.imwrite(str(root / "fine_dynamic_masks" / "all" / f"{t:03d}_0.png"), coarse)
    scene = load_scene(root)
    assert [f.dynamic_mask_path.parent.parent.name for f in scene.frames] == ["fine_dynamic_masks"] * 3 + [
        "dynamic_masks"]
    assert scene.facts["dynamic_masks"] == "fine_dynamic_masks"


def _nuscenes_scene(root: Path, n: int = 3) -> None:
    for t in range(n):
        write_rgb(root / "images" / f"{t:03d}_0.jpg", np.zeros((8, 8, 3), np.uint8))
        pose = np.eye(4)
        pose[0, 3] = t
        savetxt(root / "extrinsics" / f"{t:03d}_0.txt", pose)
    savetxt(root / "intrinsics" / "0.txt", np.array([10.0, 10, 4, 4, 0, 0, 0, 0, 0]))


def test_nuscenes_frame_rate_follows_drivestudio_folder_names(tmp_path):
    keyframes = tmp_path / "nuscenes" / "processed" / "mini" / "000"
    _nuscenes_scene(keyframes)
    scene = load_scene(keyframes)
    assert [f.timestamp for f in scene.frames] == [0.0, 0.5, 1.0]  # 2 Hz keyframes, no interpolation
    assert scene.facts["frame_rate_hz"] == 2.0
    ten = tmp_path / "nuscenes" / "processed_10Hz" / "mini" / "000"
    _nuscenes_scene(ten)
    np.testing.assert_allclose([f.timestamp for f in load_scene(ten).frames], [0.0, 0.1, 0.2])


def test_nuscenes_folder_of_unknown_rate_warns_once(tmp_path):
    root = tmp_path / "somewhere" / "scene"
    _nuscenes_scene(root)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(root)
        load_scene(root)
    msgs = [str(w.message) for w in caught if "timestamps.json" in str(w.message)]
    assert len(msgs) == 1 and "10 Hz" in msgs[0] and "2 Hz" in msgs[0]
    assert scene.facts["frame_rate_assumed"] is True
    (root / "timestamps.json").write_text(json.dumps([0.0, 0.05, 0.1]), encoding="utf-8")
    assert "frame_rate_hz" not in load_scene(root).facts


def test_waymo_source_weather_is_recorded_and_rain_flagged(tmp_path):
    clear = tmp_path / "clear"
    write_waymo_scene(clear, n_frames=1, weather="sunny")
    assert load_scene(clear).facts["source_weather"] == "clear"
    assert "source_weather_flag" not in load_scene(clear).facts
    rainy = tmp_path / "rainy"
    write_waymo_scene(rainy, n_frames=1, weather="rain")
    loaders._warned.discard((str(rainy), "weather"))
    with pytest.warns(UserWarning, match="'rain' weather, not clear"):
        scene = load_scene(rainy)
    assert scene.facts["source_weather"] == "rain"
    assert "frame_info.json" in scene.facts["source_weather_flag"]
    json.dumps(scene.facts)  # results can carry the facts as they are


def test_results_carry_the_source_weather_and_flag_a_rainy_source(tmp_path):
    from wcbench.evaluation import EvaluateConfig, evaluate
    from wcbench.methods import get_method
    from wcbench.units import RenderSettings

    rainy = tmp_path / "rainy"
    write_waymo_scene(rainy, n_frames=3, weather="rain")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cfg = EvaluateConfig(method="identity", scenes=str(rainy), predictions=tmp_path / "p", out=tmp_path / "o",
                             weathers=["clear"], metrics=["psnr"], render=RenderSettings(show_progress=False),
                             show_progress=False)
        doc = evaluate(cfg, method=get_method("identity")).results
    (facts,) = doc["scene_facts"].values()
    assert facts["source_weather"] == "rain"
    (flag,) = [w for w in doc["warnings"] if w["kind"] == "source_weather"]
    assert "'rain' weather, not clear" in flag["message"]


@pytest.mark.slow
def test_pandaset_fixture_trains_and_renders_quick(tmp_path, capsys):
    """The drivestudio PandaSet fixture goes through `wcbench run --method weathercity --profile
    quick` (train, render, evaluate) with an edit naming a compact id and a shared class."""
    pytest.importorskip("torch")
    from wcbench.cli import main

    root = tmp_path / "processed" / "002"
    write_pandaset_scene(root, n_frames=4)
    out = tmp_path / "run"
    code = main(["run", "--method", "weathercity", "--scenes", str(root), "--profile", "quick",
                 "--edit", "remove class=vehicle except ids=0,3", "--out", str(out), "--no-progress"])
    assert code == 0, capsys.readouterr().err
    pngs = sorted(out.rglob("*.png"))
    assert len(pngs) >= 4
