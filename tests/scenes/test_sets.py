"""Scene sets are data; names and paths resolve, and missing data is explained."""

from __future__ import annotations

import pytest

from wcbench.core.errors import InputError, UnknownNameError
from wcbench.scenes.sets import get_scene_set, list_scene_sets, resolve_scenes


def test_specs_are_listed():
    names = [n for n, _ in list_scene_sets()]
    assert {"waymo_5", "nuscenes_5", "pandaset_002", "demo"} <= set(names)


def test_waymo_5_has_the_papers_scene(tmp_path):
    for idx in ("023", "114", "327", "621", "788"):
        (tmp_path / "waymo" / "processed" / "training" / idx).mkdir(parents=True)
    s = get_scene_set("waymo_5", data_root=tmp_path)
    assert [r.id for r in s.scenes] == ["waymo_023", "waymo_114", "waymo_327", "waymo_621", "waymo_788"]
    assert all(r.options == {"camera": 0, "start": 0, "count": 30} for r in s.scenes)


def test_missing_scene_folders_are_listed(tmp_path):
    (tmp_path / "waymo" / "processed" / "training" / "023").mkdir(parents=True)
    with pytest.raises(InputError) as exc:
        get_scene_set("waymo_5", data_root=tmp_path)
    assert "4 scene folder(s) missing" in str(exc.value) and "788" in str(exc.value)


def test_data_root_from_environment(pandaset_root, monkeypatch):
    monkeypatch.setenv("WCBENCH_DATA", str(pandaset_root.parent))
    refs = resolve_scenes("pandaset_002")
    assert refs[0].path == pandaset_root and len(refs[0].load()) == 30


def test_path_and_unknown_name(pandaset_root):
    assert resolve_scenes(str(pandaset_root))[0].id == "pandaset_002"
    with pytest.raises(UnknownNameError, match="pandaset_002"):
        resolve_scenes("pandaset")


def test_demo_scene_is_generated_once(demo_scene):
    assert len(demo_scene) == 12 and demo_scene.image_size == (320, 180)
    again = resolve_scenes("demo")[0].load()
    assert again.root == demo_scene.root
    assert demo_scene.lidar(0).points.shape[0] > 1000


@pytest.mark.parametrize("set_name", ["waymo_5", "nuscenes_5", "pandaset_002"])
def test_drivestudio_scene_indices_are_names_of_the_scene(set_name, tmp_path):
    """drivestudio writes a scene to a folder named by its index zero-padded to 3 digits and its
    configs select it by the plain index (data.scene_idx=23 for 023): each spelling names the scene."""
    from wcbench.predictions import scene_names
    from wcbench.scenes.sets import _specs

    for s in _specs()[set_name]["scenes"]:
        (tmp_path / s["path"]).mkdir(parents=True)
    for ref in get_scene_set(set_name, data_root=tmp_path).scenes:
        names = {name for name, _ in scene_names(ref)}
        index = ref.id.rpartition("_")[2]  # waymo_023 -> 023, pandaset_002 -> 002
        assert {index, str(int(index))} <= names, (ref.id, names)


def test_a_name_of_two_scenes_is_refused():
    from pathlib import Path

    from wcbench.scenes.sets import SceneRef, check_scene_names

    refs = [SceneRef(id="nuscenes_002", format="drivestudio_nuscenes", path=Path("nuscenes/mini/002"), aliases=("2",)),
            SceneRef(id="pandaset_002", format="drivestudio_nuscenes", path=Path("pandaset_002"),
                     aliases=("002", "2"))]
    with pytest.raises(ValueError, match=r"names shared by several scenes \('002': nuscenes_002, pandaset_002; "
                                         r"'2': nuscenes_002, pandaset_002\)"):
        check_scene_names("mixed", refs)
    check_scene_names("one", refs[1:])


def test_a_one_scene_set_calls_its_scene_by_the_sets_name():
    """``--scenes synth_1`` runs scene ``synth_1`` (progress lines, <out>/<method>/<scene>/, results,
    report), not the generator's folder name: every built-in set of one scene does (docs/design.md §3)."""
    from wcbench.scenes.sets import _specs

    single = {name: spec["scenes"][0] for name, spec in _specs().items() if len(spec["scenes"]) == 1}
    assert {"demo", "synth_1", "synth_hard_1", "pandaset_002"} <= set(single)
    for name, scene in single.items():
        assert scene["id"] == name, (name, scene)
    # the data folders keep the generators' names: the scene's other name, which a prediction folder may carry
    assert {name: scene["path"] for name, scene in single.items() if scene["path"] != name} == {
        "demo": "demo_street", "synth_1": "synth_000", "synth_hard_1": "synth_hard_000"}
    # a set of several scenes calls each by the data's name for it, each a different one
    for name, spec in _specs().items():
        ids = [s["id"] for s in spec["scenes"]]
        assert len(set(ids)) == len(ids) and (len(ids) == 1 or name not in ids), name


def test_the_demo_scene_is_named_demo_and_its_folder_still_matches(demo_scene, tmp_path):
    from wcbench.predictions import find_scene_folder

    [ref] = resolve_scenes("demo")
    assert ref.id == demo_scene.id == "demo" and ref.path.name == "demo_street"
    # predictions written under the folder's name (an older run's layout) are still this scene's
    (tmp_path / "demo_street" / "rain").mkdir(parents=True)
    found = find_scene_folder(tmp_path, ref, n_scenes=2)
    assert (found.scene_id, found.path.name, found.matched) == ("demo", "demo_street", "demo_street")


def test_one_scene_folder_under_two_names_is_refused():
    """``demo`` and its folder by path are one scene (as ``synth_1`` is ``synth_3``'s first): given
    twice it would be rendered and scored twice under two names."""
    [ref] = resolve_scenes("demo")
    with pytest.raises(InputError, match=r"one scene folder given twice \(.*demo_street as demo, demo_street\); "
                                         r"give it once"):
        resolve_scenes(f"demo,{ref.path}")
