"""The synthetic scene sets (synth_1, synth_3): generated once and deterministically, read by the
unchanged Waymo loader, with ground truth per weather (docs/design.md §3)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from scene_fixtures import make_waymo_scene, write_rgb

from wcbench.core.errors import InputError
from wcbench.scenes import synth
from wcbench.scenes.loaders import load_scene
from wcbench.scenes.scene import Scene
from wcbench.scenes.sets import get_scene_set, list_scene_sets, resolve_scenes
from wcbench.scenes.synth import layout

pytest.importorskip("torch", reason="the synth scenes are rendered by the reference model")


@pytest.fixture(scope="module")
def synth_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A private cache holding synth_1's scene, generated once for the module (with its editing truth)."""
    cache = tmp_path_factory.mktemp("synth_cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("WCBENCH_CACHE", str(cache))
        synth.ensure_synth_1()
    return cache


@pytest.fixture
def synth_env(synth_cache: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The module's cache as the cache folder of this test."""
    monkeypatch.setenv("WCBENCH_CACHE", str(synth_cache))
    return synth_cache


@pytest.fixture
def scene0(synth_env: Path) -> Scene:
    return resolve_scenes("synth_1")[0].load()


def _hashes(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _mask(path: Path | None) -> np.ndarray:
    assert path is not None
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None and img.ndim == 2
    return img


def _check_lidar_on_solid_pixels(scene: Scene, frames: tuple[int, ...] = (0, 10, 20, 29)) -> None:
    """Lidar points projected with the loaded cameras land where the sky mask is 0."""
    for k in frames:
        f = scene.frames[k]
        sky = _mask(f.sky_mask_path) > 0
        assert 0.05 < sky.mean() < 0.5  # some sky above the street, not most of the image
        sweep = scene.lidar(f)
        assert sweep is not None
        uv, z = f.camera.project(sweep.points)
        ij = np.floor(uv).astype(int)
        ok = (z > 0.5) & (ij[:, 0] >= 0) & (ij[:, 0] < f.camera.width) & (ij[:, 1] >= 0) & (ij[:, 1] < f.camera.height)
        assert ok.sum() > 3000, f"frame {k}: {ok.sum()} lidar points in view"
        on_sky = sky[ij[ok, 1], ij[ok, 0]]
        assert on_sky.mean() < 0.01, f"frame {k}: {on_sky.mean():.2%} of the lidar points fall on sky pixels"


def _check_moving_boxes_in_dynamic_masks(scene: Scene) -> None:
    """Moving boxes project where the dynamic mask is set, and the mask is nowhere else."""
    moving = [t for t in scene.tracks
              if np.linalg.norm(t.object_to_world[:, :3, 3] - t.object_to_world[0, :3, 3], axis=1).max() > 0.5]
    assert moving
    checked = 0
    for f in scene.frames:
        mask = _mask(f.dynamic_mask_path) > 0
        cam = f.camera
        allowed = np.zeros_like(mask)
        for t in moving:
            (k,) = np.nonzero(t.frames == f.index)[0]
            uv, z = cam.project(t.corners(int(k)))
            if not np.all(z > 0):
                continue
            u = np.clip(uv[:, 0], 0, cam.width)
            v = np.clip(uv[:, 1], 0, cam.height)
            allowed[int(v.min()):int(np.ceil(v.max())), int(u.min()):int(np.ceil(u.max()))] = True
            center, cz = cam.project(t.object_to_world[k, :3, 3][None])
            cu, cv = center[0]
            if cz[0] > 1 and 0 <= cu < cam.width and 0 <= cv < cam.height and u.max() - u.min() > 4:
                assert mask[int(cv), int(cu)], f"frame {f.index}: the box of {t.id} projects off the dynamic mask"
                checked += 1
        assert not np.any(mask & ~allowed), f"frame {f.index}: dynamic mask outside every moving box"
    assert checked >= 10


def test_synth_sets_are_listed_and_generated_once(synth_env):
    names = [n for n, _ in list_scene_sets()]
    assert {"synth_1", "synth_3"} <= set(names)
    marker = synth_env / "scenes" / f"synth-v{synth.VERSION}" / "synth_000" / layout.MARKER
    before = marker.stat().st_mtime_ns
    s = get_scene_set("synth_1")
    # called by the set's name, the one the user gives (its folder: synth_000, synth_3's first scene)
    assert [r.id for r in s.scenes] == ["synth_1"] and s.scenes[0].path == marker.parent
    from wcbench.scenes.sets import _specs

    assert _specs()["synth_3"]["scenes"][0] == {"id": "synth_000", "path": marker.parent.name}
    assert s.scenes[0].options == {"camera": 0, "start": 0, "count": 30}
    assert marker.stat().st_mtime_ns == before  # found in the cache, not built again


def test_scene_loads_through_the_waymo_loader(scene0):
    assert len(scene0) == 30 and scene0.image_size == (480, 270)
    assert scene0.source_format == "drivestudio_waymo"
    np.testing.assert_allclose(scene0.frames[0].camera.center, 0.0, atol=1e-9)
    content = synth.build_content(synth.SCENES[0])
    first = content.ego[0] @ content.camera_to_vehicle
    np.testing.assert_allclose(scene0.world_offset, first[:3, 3] + layout.GLOBAL_ORIGIN, atol=1e-9)
    # the camera drives forward at 8 m/s, 10 Hz
    steps = np.diff([f.camera.center for f in scene0.frames], axis=0)
    np.testing.assert_allclose(np.linalg.norm(steps, axis=1), 0.8, atol=1e-9)
    np.testing.assert_allclose([f.timestamp for f in scene0.frames], np.arange(30) / 10.0)
    assert all(f.lidar_path and f.sky_mask_path and f.dynamic_mask_path for f in scene0.frames)
    assert sorted(scene0.references) == ["fog", "rain", "snow"]
    for weather, paths in scene0.references.items():
        assert [p.name for p in paths] == [f"{t:03d}_0.png" for t in range(30)]
        assert all(p.parent == scene0.root / "truth" / weather for p in paths)
    assert scene0.reference_paths("clear") == [f.image_path for f in scene0.frames]


def test_lidar_lands_on_solid_pixels(scene0):
    _check_lidar_on_solid_pixels(scene0)
    sweep = scene0.lidar(5)
    assert sweep.origins is not None
    assert np.abs(sweep.origins - sweep.origins[0]).max() < 1e-4  # one sensor per sweep


def test_moving_boxes_project_into_dynamic_masks(scene0):
    _check_moving_boxes_in_dynamic_masks(scene0)


def test_pedestrians_where_specified(scene0):
    assert {t.class_name for t in scene0.tracks} == {"vehicle"}  # scene 0: cars only
    with_pedestrian = []
    for spec in synth.SCENES:
        movers = synth.build_content(spec).movers
        walkers = [m for m in movers if m.class_name == "Pedestrian"]
        assert len(walkers) == (spec.pedestrian is not None)
        for m in walkers:
            speed = np.linalg.norm(m.velocity, axis=1)
            assert np.all((speed > 1.0) & (speed < 1.6))
        assert all(np.allclose(m.velocity, 0) for m in movers if not m.moving)
        with_pedestrian.append(bool(walkers))
    assert with_pedestrian == [False, True, True]


def test_truth_weathers_and_materials(scene0):
    info = json.loads((scene0.root / "truth" / "weather.json").read_text(encoding="utf-8"))
    assert {w: info[w]["preset"] for w in ("rain", "snow", "fog")} == {"rain": "heavy", "snow": "heavy",
                                                                        "fog": "moderate"}
    assert all(info[w]["seed"] == synth.SCENES[0].seed for w in ("rain", "snow", "fog"))
    assert info["rain"]["rate_mm_h"] == 25.0 and info["snow"]["rate_mm_h"] == 2.5
    assert info["fog"]["visibility_m"] == pytest.approx(150.0)
    assert info["rain"]["materials"]["light"] < 0.8
    # the weathers act on the picture as they should: snow whitens the road, rain darkens it, fog
    # turns the far street towards the fog colour
    k = 12
    clear = cv2.imread(str(scene0.frames[k].image_path)).astype(float)
    road = slice(200, 270)
    truth = {w: cv2.imread(str(scene0.references[w][k])).astype(float) for w in ("rain", "snow", "fog")}
    assert truth["snow"][road].mean() > clear[road].mean() + 40
    assert truth["rain"][road].mean() < clear[road].mean()
    far = (slice(100, 150), slice(200, 280))
    fog_bgr = np.array(info["fog"]["renderer"]["fog"]["color"])[::-1] * 255
    assert np.abs(truth["fog"][far] - fog_bgr).mean() < np.abs(clear[far] - fog_bgr).mean() - 20


def test_partial_truth_folder_is_refused(tmp_path):
    root = tmp_path / "scene"
    make_waymo_scene(root, n_frames=4)
    rng = np.random.default_rng(0)
    for t in (0, 1, 3):
        write_rgb(root / "truth" / "rain" / f"{t:03d}_0.png", rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    with pytest.raises(InputError, match=r"truth/rain.*1 missing: 002_0\.png"):
        load_scene(root)
    write_rgb(root / "truth" / "rain" / "002_0.png", rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    scene = load_scene(root)
    assert sorted(scene.references) == ["rain"] and len(scene.references["rain"]) == 4
    assert load_scene(root, start=1, count=2).references["rain"][0].name == "001_0.png"
    write_rgb(root / "truth" / "rain" / "002_0.png", rng.integers(0, 255, (24, 32, 3), dtype=np.uint8))
    with pytest.raises(InputError, match=r"002_0\.png: ground-truth frame is \(32, 24\)"):
        load_scene(root)


def test_generation_is_deterministic(tmp_path):
    """Two generations give byte-identical files (two frames of the curved scene with a pedestrian)."""
    a, b = tmp_path / "a", tmp_path / "b"
    synth.write_synth_scene(a, 1, n_frames=2)
    synth.write_synth_scene(b, 1, n_frames=2)
    ha, hb = _hashes(a), _hashes(b)
    assert len(ha) > 20 and ha == hb


def test_sets_import_without_torch_and_generation_says_what_is_missing(tmp_path):
    code = (
        "import sys; sys.modules['torch'] = None\n"
        "import wcbench.scenes.sets as sets, wcbench.scenes.synth\n"
        "from wcbench.core.errors import InputError\n"
        "try:\n    sets.get_scene_set('synth_1')\nexcept InputError as exc:\n    print('InputError:', exc)\n"
    )
    env = {**os.environ, "WCBENCH_CACHE": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    assert "InputError:" in out and 'pip install "wcbench[model]"' in out
    assert not (tmp_path / "scenes" / f"synth-v{synth.VERSION}" / "synth_000").exists()


@pytest.mark.slow
def test_full_generation_is_byte_identical(synth_cache, tmp_path, monkeypatch):
    monkeypatch.setenv("WCBENCH_CACHE", str(tmp_path))
    again = synth.ensure_synth_1() / "synth_000"
    first = synth_cache / "scenes" / f"synth-v{synth.VERSION}" / "synth_000"
    assert _hashes(again) == _hashes(first)


@pytest.mark.slow
def test_synth_3_scenes_with_pedestrians_load(synth_env):
    refs = resolve_scenes("synth_3")
    assert [r.id for r in refs] == ["synth_000", "synth_001", "synth_002"]
    for ref in refs[1:]:
        scene = ref.load()
        walkers = [t for t in scene.tracks if t.class_name == "pedestrian"]
        assert len(walkers) == 1 and sorted(scene.references) == ["fog", "rain", "snow"]
        _check_lidar_on_solid_pixels(scene)
        _check_moving_boxes_in_dynamic_masks(scene)


def test_weathercity_renders_the_truths_requested_weather_never_its_seed(scene0: Scene, demo_scene: Scene) -> None:
    from wcbench.methods.scene_training import training_hazes
    from wcbench.methods.weather_spec import requested_fields, truth_physics
    from wcbench.methods.weathercity import WeatherCityMethod
    from wcbench.reference_model.weather.conditions import Weather

    truth = json.loads((scene0.root / "truth" / "weather.json").read_text(encoding="utf-8"))
    method = WeatherCityMethod(profile="quick", physics="truth")
    physics = truth_physics(scene0)
    assert sorted(physics) == ["fog", "rain", "snow"]
    for kind in ("rain", "snow", "fog"):
        chosen = method.weather_for(kind, 7, scene0)
        # what the truth asked for (preset, rate, visibility, wind...), drawn with the run's seed 7
        assert requested_fields(chosen) == requested_fields(Weather.from_json(truth[kind]["weather"]))
        assert chosen.seed == 7 != truth[kind]["seed"]
    assert method.weather_for("snow", 7, scene0).max_particles == 30000
    # without a recorded weather: the preset, seeded by the run; "auto" (the default) reads the record
    assert WeatherCityMethod(physics="presets").weather_for("rain", 7, scene0).seed == 7
    assert WeatherCityMethod().weather_for("rain", 7, scene0) == method.weather_for("rain", 7, scene0)
    assert WeatherCityMethod().weather_for("rain", 7, demo_scene).seed == 7
    # the truth's own seed is refused for the particles unless the physics option names it
    with pytest.raises(InputError, match="draw the truth's own particles"):
        WeatherCityMethod().weather_for("rain", truth["rain"]["seed"], scene0)
    method.check_scene(scene0, "snow")
    # training composes the haze the renderer of the truth's weather adds
    hazes = training_hazes(method.config, method.training_physics(scene0), ("clear", "rain", "snow", "fog"))
    assert sorted(hazes) == ["fog", "rain", "snow"]
    assert hazes["fog"].beta == pytest.approx(truth["fog"]["renderer"]["fog"]["density_per_m"], rel=1e-9)
    assert hazes["rain"].beta == pytest.approx(truth["rain"]["renderer"]["fog"]["density_per_m"], rel=1e-9)
    assert hazes["rain"].offset_m == truth["rain"]["renderer"]["fog"]["offset_m"] > 0
    with pytest.raises(InputError, match=r"truth[/\\]weather\.json: not found"):
        method.check_scene(demo_scene, "rain")
    with pytest.raises(InputError, match="physics must be"):
        WeatherCityMethod(physics="sunny")


# --------------------------------------------------------------------------- the editing truth
#: sha256 of files of synth_000 as generated before the editing truth existed (the v1 cache's
#: bytes): the editing truth is written beside them and changes none.
_V1_BYTES = {
    "images/000_0.png": "f772ec1329f5b1060dc04e5aeb7b646a788c5d2bdde59ba5c062f6783694e16b",
    "truth/rain/010_0.png": "bc9f767843e0767e4d19f56b4557039b55b35e70a5c22518deb40b8c65ffc342",
    "truth/fog/029_0.png": "910ada8c9c0692ca90ddd99cffcdb7c1e11dc3e55fb784f3d5085b2f8f852729",
    "truth/weather.json": "c7b1be91a2d610ca08086640e2e47145dae6cde7d1dcc8926097d50a5dad0fe5",
    "synth.json": "a113b16bdf1995caed87b4416e6a4aa7c909505dabb12030c965df0b80b088cb",
}


def _gray(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None
    return img.astype(int)


def test_old_truth_is_byte_identical_beside_the_editing_truth(synth_env):
    root = synth_env / "scenes" / f"synth-v{synth.VERSION}" / "synth_000"
    for name, digest in _V1_BYTES.items():
        assert hashlib.sha256((root / name).read_bytes()).hexdigest() == digest, name


def test_editing_truth_layout_and_ids(scene0: Scene):
    from wcbench.reference_model.editing.edits import parse_edits

    record = json.loads((scene0.root / "truth" / "edits" / "edits.json").read_text())
    assert [e["name"] for e in record["edits"]] == ["remove_9", "translate_9"]
    assert [t.name for t in scene0.edit_truths] == ["remove_9", "translate_9"]
    track = next(t for t in scene0.tracks if t.id == "9")
    # the oncoming car: the only moving tracked car, named by its compact instance id
    assert track.class_name == "vehicle" and track.source_id == "synth_000_car_oncoming"
    assert np.ptp(track.object_to_world[:, 0, 3]) > 10
    for e, truth in zip(record["edits"], scene0.edit_truths):
        (parsed,) = parse_edits(e["edit"])  # the text form is what --edit takes, and means the same
        assert parsed.to_json() == truth.edit and scene0.edit_truth([parsed.to_json()]) is truth
        assert sorted(truth.references) == ["clear", "fog", "rain", "snow"]
        assert all(len(p) == len(scene0) for p in truth.references.values()) and len(truth.masks) == len(scene0)
        assert sum(n > 0 for n in e["mask_pixels"]) >= 0.9 * len(scene0)
    assert scene0.edit_truths[1].edit["by"] == [10.0, 0.0, 0.0]


def test_removal_changes_pixels_only_inside_the_mask(scene0: Scene):
    remove = scene0.edit_truths[0]
    for k in (0, 12, 26):
        mask = _gray(remove.masks[k]) > 0
        assert mask.any()
        for w in ("clear", "rain", "snow", "fog"):
            plain = scene0.frames[k].image_path if w == "clear" else scene0.references[w][k]
            d = np.abs(_gray(plain) - _gray(remove.references[w][k])).max(axis=-1)
            assert d[~mask].max() <= 1, (k, w)  # rounding of a weight below the mask's threshold
            assert (d[mask] > 8).mean() > 0.3, (k, w)  # the car is gone where it was


def test_translation_is_in_the_scene_graphs_world_frame(scene0: Scene):
    """The moved car's box centre, moved by ``by`` in the loaded world, projects into the mask."""
    move = scene0.edit_truths[1]
    track = next(t for t in scene0.tracks if t.id == move.edit["ids"][0])
    hits = 0
    for k in range(0, 26, 5):
        centre = track.object_to_world[k, :3, 3] + np.asarray(move.edit["by"])
        uv, z = scene0.frames[k].camera.project(centre[None])
        u, v = np.floor(uv[0]).astype(int)
        if z[0] > 1 and 0 <= u < 480 and 0 <= v < 270:
            assert _gray(move.masks[k])[v, u] == 255, k
            hits += 1
    assert hits >= 4


def test_a_cached_scene_without_editing_truth_is_extended(synth_env, tmp_path, monkeypatch):
    """A scene cached before the editing truth (or with another version of it) gets it on the next
    use, rendered into place; its other files are left as they were."""
    src = synth_env / "scenes" / f"synth-v{synth.VERSION}" / "synth_000"
    root = tmp_path / "scenes" / f"synth-v{synth.VERSION}" / "synth_000"
    shutil.copytree(src, root)
    shutil.rmtree(root / "truth" / "edits")
    marker = json.loads((root / layout.MARKER).read_text())
    (root / layout.MARKER).write_text(json.dumps({**marker, "frames": 2}))  # 2 frames: quick
    before = _hashes(root)
    monkeypatch.setenv("WCBENCH_CACHE", str(tmp_path))
    synth.ensure_synth_1()
    after = _hashes(root)
    added = {k for k in after if k.startswith("truth/edits/")}
    assert {k: after[k] for k in after if k not in added} == before
    assert len(added) == 1 + 2 * 5 * 2  # edits.json, 2 edits x (4 weathers + mask) x 2 frames
    for name in added - {"truth/edits/edits.json"}:
        assert after[name] == _hashes(src)[name]  # the same bytes as generated with the scene
    assert not [p for p in (root / "truth").iterdir() if p.name.startswith(".")]


def test_a_cached_scene_without_editing_truth_still_loads_without_torch(synth_env, tmp_path):
    root = tmp_path / "scenes" / f"synth-v{synth.VERSION}" / "synth_000"
    shutil.copytree(synth_env / "scenes" / f"synth-v{synth.VERSION}" / "synth_000", root)
    shutil.rmtree(root / "truth" / "edits")
    code = ("import sys; sys.modules['torch'] = None\n"
            "from wcbench.scenes.sets import resolve_scenes\n"
            "print('edit truths:', len(resolve_scenes('synth_1')[0].load().edit_truths))\n")
    env = {**os.environ, "WCBENCH_CACHE": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    assert "edit truths: 0" in out and not (root / "truth" / "edits").exists()
