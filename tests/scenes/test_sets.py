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
