"""The harder synthetic set (synth_hard_1): sun shadows in the clear frames only, buildings above the
lidar's reach, no sky masks, untracked movers, truth masks; deterministic (docs/design.md §3)."""

from __future__ import annotations

import hashlib
import json
import math
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
import pytest

from wcbench.reference_model.weather.conditions import load_presets
from wcbench.scenes import synth
from wcbench.scenes.scene import Scene
from wcbench.scenes.synth import layout
from wcbench.scenes.synth.content import Content, boxes_at, build_content
from wcbench.scenes.synth.light import overcast_irradiance, srgb_to_linear
from wcbench.scenes.synth.materials import physical_materials
from wcbench.scenes.synth.raycast import RayBundle, box_entry, sphere_entry

pytest.importorskip("torch", reason="the synth scenes are rendered by the reference model")

SPEC = synth.HARD_SCENES[0]
MASKS = ("sky", "shadow", "movers")


@pytest.fixture
def hard(synth_hard: Scene) -> Scene:
    """synth_hard_1, generated once for the session (conftest)."""
    return synth_hard


@pytest.fixture(scope="module")
def content() -> Content:
    return build_content(SPEC)


def _gray(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None and img.ndim == 2, path
    return img


def _linear(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, path
    return srgb_to_linear(img[..., ::-1] / 255.0)


def _to_street(scene: Scene) -> np.ndarray:
    """Add to a loaded scene's world point to get street coordinates (the writer's global frame is
    the street's moved by GLOBAL_ORIGIN; the loader re-bases it by the scene's world offset)."""
    return scene.world_offset - layout.GLOBAL_ORIGIN


def _pixel_rays(scene: Scene, k: int) -> np.ndarray:
    """[H, W, 3] unit rays of frame k's pixels (world axes)."""
    cam = scene.frames[k].camera
    jj, ii = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    d = np.stack([(jj - cam.K[0, 2]) / cam.K[0, 0], (ii - cam.K[1, 2]) / cam.K[1, 1], np.ones_like(jj)], -1)
    d = d @ cam.camera_to_world[:3, :3].T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _first_shape_hit(content: Content, k: int, origin: np.ndarray, rays: np.ndarray, reach: float = np.inf
                     ) -> np.ndarray:
    """[...] distance (m) from ``origin`` (street) along ``rays`` to the first box or canopy of frame k
    (inf beyond ``reach`` m: shapes wholly farther are not tested)."""
    flat = rays.reshape(-1, 3)
    best = np.full(len(flat), np.inf)
    boxes = boxes_at(content, k)
    for c, R, h in zip(boxes.center, boxes.R, boxes.half):
        if np.linalg.norm(c - origin) - np.linalg.norm(h) < reach:
            best = np.minimum(best, box_entry(R.T @ (origin - c), flat @ R, h))
    for s in content.spheres:
        if np.linalg.norm(s[:3] - origin) - s[3] < reach:
            best = np.minimum(best, sphere_entry(s[:3] - origin, flat, float(s[3])))
    return best.reshape(rays.shape[:-1])


def test_set_loads_without_sky_masks_with_truth_masks(hard: Scene) -> None:
    assert hard.id == "synth_hard_1" and hard.root.name == "synth_hard_000"  # the set's name; the generator's folder
    assert len(hard) == 30 and hard.image_size == (480, 270)
    assert hard.source_format == "drivestudio_waymo"
    assert not (hard.root / "sky_masks").exists()
    assert all(f.sky_mask_path is None and f.lidar_path is not None for f in hard.frames)
    assert sorted(hard.references) == ["fog", "rain", "snow"]
    for name in MASKS:
        paths = sorted((hard.root / "truth" / "masks" / name).glob("*.png"))
        assert [p.name for p in paths] == [f"{t:03d}_0.png" for t in range(30)]
    sky = _gray(hard.root / "truth" / "masks" / "sky" / "000_0.png") > 0
    assert 0.03 < sky.mean() < 0.4 and not sky[-40:].any()  # sky above the street, none on the road
    marker = json.loads((hard.root / layout.MARKER).read_text(encoding="utf-8"))
    assert marker["sky_masks_shipped"] is False and marker["lidar"]["beams"] == 64


def test_untracked_movers_have_no_instance_and_no_dynamic_mask(hard: Scene, content: Content) -> None:
    untracked = [m for m in content.movers if m.moving and not m.tracked]
    assert {m.class_name for m in untracked} == {"Vehicle", "Pedestrian"}
    assert sum(m.class_name == "Pedestrian" for m in untracked) >= 2
    info = json.loads((hard.root / "instances" / "instances_info.json").read_text(encoding="utf-8"))
    ids = {v["id"] for v in info.values()}
    assert ids == {f"{SPEC.folder}_{m.id}" for m in content.movers if m.tracked}
    assert not any(m.id in i for m in untracked for i in ids)
    assert {t.source_id for t in hard.tracks} == ids
    # each untracked mover shows in the movers truth mask, outside the dynamic mask (which holds the
    # tracked movers' rectangles only), in most frames
    shift = _to_street(hard)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)
    for m in untracked:
        seen = 0
        for f in hard.frames:
            corners = (signs * m.size / 2) @ m.poses[f.index, :3, :3].T + m.poses[f.index, :3, 3] - shift
            uv, z = f.camera.project(corners)
            if np.any(z < 1):
                continue
            (u0, v0), (u1, v1) = np.clip(np.floor(uv.min(0)), 0, None).astype(int), np.ceil(uv.max(0)).astype(int)
            movers = _gray(hard.root / "truth" / "masks" / "movers" / f"{f.index:03d}_0.png")[v0:v1, u0:u1] > 0
            assert f.dynamic_mask_path is not None
            dynamic = _gray(f.dynamic_mask_path)[v0:v1, u0:u1] > 0
            seen += int((movers & ~dynamic).sum() >= 3)
        assert seen >= 20, (m.id, seen)


def test_lidar_sees_every_mover_with_its_flow(hard: Scene, content: Content) -> None:
    """Tracked or not, every moving object has returns in the sweeps, with its speed in the flow
    columns and its Waymo flow class."""
    for m in (m for m in content.movers if m.moving):
        hits = 0
        for k in range(0, 30, 3):
            raw = np.fromfile(hard.root / "lidar" / f"{k:03d}.bin", np.float32).reshape(-1, 14).astype(np.float64)
            ego = content.ego[k]
            world = raw[:, 3:6] @ ego[:3, :3].T + ego[:3, 3]
            local = (world - m.poses[k, :3, 3]) @ m.poses[k, :3, :3]
            # in the box and clear of the ground it stands on (the returns have 2 cm of range noise)
            inside = np.all(np.abs(local) <= m.size / 2, axis=1) & (local[:, 2] > 0.1 - m.size[2] / 2)
            if inside.any():
                speed = np.linalg.norm(raw[inside, 6:9], axis=1)
                np.testing.assert_allclose(speed, np.linalg.norm(m.velocity[k]), rtol=1e-4)
                assert np.all(raw[inside, 9] == (2 if m.class_name == "Pedestrian" else 1))
                hits += 1
        assert hits >= 5, m.id


def test_buildings_reach_above_the_top_lidar_beam(hard: Scene, content: Content) -> None:
    """Non-sky pixels above the horizon that no lidar return projects near: the upper floors of the
    blocks, above the 64-beam sensor's +15 degrees."""
    lidar = SPEC.profile.lidar
    shift = _to_street(hard)
    for k in (0, 15, 29):
        f = hard.frames[k]
        sky = _gray(hard.root / "truth" / "masks" / "sky" / f"{k:03d}_0.png") > 0
        rays = _pixel_rays(hard, k)
        above = rays[..., 2] > 0.02
        sweep = hard.lidar(f)
        assert sweep is not None
        uv, z = f.camera.project(sweep.points)
        ok = (z > 0.5) & (uv[:, 0] >= 0) & (uv[:, 0] < 480) & (uv[:, 1] >= 0) & (uv[:, 1] < 270)
        reached = np.zeros((270, 480), np.uint8)
        reached[np.floor(uv[ok, 1]).astype(int), np.floor(uv[ok, 0]).astype(int)] = 1
        near_return = cv2.dilate(reached, np.ones((7, 7), np.uint8)) > 0
        unreached = ~sky & above & ~near_return
        assert unreached.mean() > 0.03, f"frame {k}: {unreached.mean():.1%}"
        # those pixels show surfaces that the top beam passes below
        eye = f.camera.center + shift
        t = _first_shape_hit(content, k, eye, rays)
        points = eye + np.where(np.isfinite(t), t, 0.0)[..., None] * rays
        sensor = content.ego[k][:3, :3] @ np.array(lidar.mount_m) + content.ego[k][:3, 3]
        offset = points - sensor
        elevation = np.degrees(np.arctan2(offset[..., 2], np.linalg.norm(offset[..., :2], axis=-1)))
        beyond = unreached & np.isfinite(t) & (elevation > lidar.elevation_deg[1] + 0.5)
        assert beyond.sum() > 0.5 * unreached.sum(), f"frame {k}"


def _road_pixels(scene: Scene, content: Content, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bare asphalt pixels of frame k within 30 m, nothing in front of them: (mask [H, W], lateral
    offset d [H, W] (m), distance [H, W] (m)). Lane markings, dark patches and puddles are left out
    (another albedo class, or another material under rain)."""
    rays = _pixel_rays(scene, k)
    eye = scene.frames[k].camera.center + _to_street(scene)
    with np.errstate(divide="ignore"):
        t = np.where(rays[..., 2] < -1e-6, -eye[2] / rays[..., 2], np.inf)
    p = eye + np.where(np.isfinite(t), t, 0.0)[..., None] * rays
    s, d = p[..., 0], p[..., 1]  # the street is straight: street x, y are s, d
    ok = (t < 30.0) & (np.abs(d) < layout.ROAD_HALF_M - 0.3) & (np.abs(d) > 0.35)
    ok &= np.abs(np.abs(d) - layout.LANE_M) > 0.35
    for q in content.road_patches:
        ok &= ~((np.abs(s - q["s"]) < q["half_length"] + 0.5) & (np.abs(d - q["d"]) < q["half_width"] + 0.5))
    for ps, pd, hl, hw in content.puddles:
        ok &= ((s - ps) / (hl + 0.5)) ** 2 + ((d - pd) / (hw + 0.5)) ** 2 > 1.0
    ok[ok] = _first_shape_hit(content, k, eye, rays[ok], reach=30.0) > t[ok]  # nothing in front
    return ok, d, t


def test_shadow_truth_is_physical(hard: Scene, content: Content) -> None:
    """Asphalt in the clear frames' cast shadow is darker than sunlit asphalt by the sky light's share
    of the sunlit light, sky / (sky + sun sin(elevation)) per channel in linear light; the weather
    truths, lit by an overcast sky, show no step at the same pixels.

    Pixels are compared within bins of the same lateral offset (0.5 m) and distance (3 m), pooled
    over every second frame: the road's material (snow's tyre tracks) varies across the street and
    rain's reflection and fog with the distance, not with the shadow. Both masks are eroded by 4 px
    (edges blend neighbouring Gaussians and the sun's penumbra). Tolerance: 8 % on the clear ratio
    (the asphalt's albedo noise, 0.025 of 0.27, and the remaining blend), 10 % from 1 under the
    weathers.
    """
    sun = SPEC.profile.sun
    assert sun is not None
    sky, direct = np.array(sun.sky_rgb), np.array(sun.sun_rgb)
    expected = sky / (sky + direct * math.sin(math.radians(sun.elevation_deg)))
    groups: dict[str, dict[tuple[int, int, bool], list[np.ndarray]]] = {w: defaultdict(list) for w in
                                                                         ("clear", "rain", "snow", "fog")}
    kernel = np.ones((9, 9), np.uint8)
    for k in range(0, 30, 2):
        ok, d, t = _road_pixels(hard, content, k)
        shadow = _gray(hard.root / "truth" / "masks" / "shadow" / f"{k:03d}_0.png") > 0
        classes = {True: cv2.erode(shadow.astype(np.uint8), kernel) > 0,
                   False: cv2.erode((~shadow).astype(np.uint8), kernel) > 0}
        frame = hard.frames[k]
        images = {"clear": _linear(frame.image_path),
                  **{w: _linear(hard.references[w][k]) for w in ("rain", "snow", "fog")}}
        for in_shadow, where in classes.items():
            sel = ok & where
            keys = np.stack([np.floor(d[sel] / 0.5), np.floor(t[sel] / 3.0)], 1).astype(int)
            for key in np.unique(keys, axis=0):
                rows = np.all(keys == key, axis=1)
                for w, img in images.items():
                    groups[w][(int(key[0]), int(key[1]), in_shadow)].append(img[sel][rows])
    ratios = {}
    for w, g in groups.items():
        per_bin = []
        for (a, b, in_shadow), values in g.items():
            if not in_shadow or (a, b, False) not in g:
                continue
            dark, lit = np.concatenate(values), np.concatenate(g[(a, b, False)])
            if len(dark) >= 10 and len(lit) >= 10:
                per_bin.append(np.median(dark, 0) / np.median(lit, 0))
        assert len(per_bin) >= 8, w
        ratios[w] = np.median(np.array(per_bin), 0)
    np.testing.assert_allclose(ratios["clear"], expected, rtol=0.08)
    assert np.all(ratios["clear"] < 0.5)  # a real step: sunlit asphalt is over twice as bright
    for w in ("rain", "snow", "fog"):
        np.testing.assert_allclose(ratios[w], 1.0, atol=0.1, err_msg=w)


def test_moving_shadows_move(content: Content) -> None:
    """The untracked lead car's shadow falls on the road where its sun ray meets the ground, and
    moves on with the car."""
    from wcbench.scenes.synth.shadows import ShadowCaster

    caster = ShadowCaster(content)
    assert SPEC.profile.sun is not None
    s = SPEC.profile.sun.direction()
    lead = next(m for m in content.movers if m.id == "car_lead_untracked")
    road = content.static.means[:, 2] < 0.01
    vis = {k: caster.visibility(k)[: len(content.static)] for k in (0, 29)}
    for k, other in ((0, 29), (29, 0)):
        center = lead.poses[k, :3, 3]
        ground = center - s * (center[2] / s[2])  # where the sun ray through the car's centre meets z = 0
        nearest = np.argmin(np.where(road, np.linalg.norm(content.static.means - ground, axis=1), np.inf))
        assert vis[k][nearest] == 0.0 and vis[other][nearest] == 1.0, k


def test_generation_is_deterministic(tmp_path: Path) -> None:
    """Two generations of two frames are byte-identical."""
    hashes = []
    for name in ("a", "b"):
        synth.write_synth_scene(tmp_path / name, SPEC, n_frames=2)
        root = tmp_path / name
        hashes.append({str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
                       for p in sorted(root.rglob("*")) if p.is_file()})
    assert len(hashes[0]) > 25 and hashes[0] == hashes[1]
    assert "truth/masks/shadow/001_0.png" in hashes[0] and not any(k.startswith("sky_masks") for k in hashes[0])


def test_materials_read_the_shared_appearance_tables(hard: Scene) -> None:
    tables = load_presets()["appearance"]
    m = physical_materials()
    assert (m["snow"]["facing_from"], m["snow"]["facing_full"]) == (tables["snow"]["facing_from"],
                                                                    tables["snow"]["facing_full"])
    assert m["snow"]["snow_albedo"] == [tables["snow"]["snow_albedo"]] * 3
    assert m["rain"]["fresnel_f0"] == tables["rain"]["fresnel_f0"]
    assert m["rain"]["wetness_vertical"] == tables["rain"]["wetness_vertical"]
    # v1 keeps its own, frozen, numbers (its scenes regenerate byte for byte)
    assert (layout.MATERIALS_V1["snow"]["normal_up_from"], layout.MATERIALS_V1["snow"]["normal_up_full"]) == (0.55, 0.9)
    truth = json.loads((hard.root / "truth" / "weather.json").read_text(encoding="utf-8"))
    assert truth["snow"]["materials"]["facing_full"] == tables["snow"]["facing_full"]
    assert {"road_patches", "white_facade", "mirror_windows"} <= set(truth["materials"])
    assert len(truth["materials"]["road_patches"]) == SPEC.profile.road_patches
    assert truth["clear"]["sun"]["elevation_deg"] == SPEC.profile.sun.elevation_deg  # type: ignore[union-attr]
    assert {w: truth[w]["preset"] for w in ("rain", "snow", "fog")} == {"rain": "heavy", "snow": "heavy",
                                                                        "fog": "moderate"}
    assert truth["snow"]["weather"]["max_particles"] == 30000 and truth["rain"]["seed"] == SPEC.seed


def test_cie_overcast_irradiance() -> None:
    """A vertical plane under the CIE standard overcast sky receives 0.396 of a horizontal one's
    irradiance; one facing down only the ground's reflection."""
    np.testing.assert_allclose(overcast_irradiance(np.array([1.0, 0.0, -1.0]), 0.0), [1.0, 0.396, 0.0], atol=2e-3)
    np.testing.assert_allclose(overcast_irradiance(np.array([-1.0]), 0.2), [0.2], atol=1e-9)


def test_ray_bundle_matches_brute_force() -> None:
    """The culled shadow rays meet exactly the shapes that testing every ray against every shape finds."""
    rng = np.random.default_rng(3)
    axis = np.array([0.3, 0.4, 0.6])
    axis /= np.linalg.norm(axis)
    points = rng.uniform(-20, 20, (4000, 3))
    dirs = axis + rng.normal(0, 0.003, (4000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    centers = rng.uniform(-15, 15, (12, 3))
    angles = rng.uniform(0, 2 * np.pi, 12)
    rotations = np.array([[[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]] for a in angles])
    halves = rng.uniform(0.3, 4.0, (12, 3))
    spheres = np.concatenate([rng.uniform(-15, 15, (5, 3)), rng.uniform(0.5, 3, (5, 1))], 1)
    brute = np.zeros(len(points), bool)
    for c, R, h in zip(centers, rotations, halves):
        brute |= np.isfinite(box_entry((points - c) @ R, dirs @ R, h))
    for s in spheres:
        brute |= np.isfinite(sphere_entry(s[:3] - points, dirs, float(s[3])))
    culled = RayBundle(points, dirs, axis, margin=0.003 * 60 * 3).blocked((centers, rotations, halves), spheres)
    assert 200 < brute.sum() < 3800
    np.testing.assert_array_equal(culled, brute)


def test_box_and_sphere_entry() -> None:
    o = np.array([[-5.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-5.0, 3.0, 0.0]])
    d = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    np.testing.assert_allclose(box_entry(o, d, np.array([1.0, 2.0, 2.0])), [4.0, np.inf, np.inf])
    np.testing.assert_allclose(sphere_entry(np.array([5.0, 0.0, 0.0]), d, 1.0), [4.0, 4.0, 4.0])
    np.testing.assert_allclose(sphere_entry(-o, d, 1.0), [4.0, np.inf, np.inf])  # unit sphere at 0: hit, inside, miss


def test_editing_truth_takes_the_cars_shadow_with_it(hard: Scene) -> None:
    """With a sun the removed or moved car's cast shadow is edited too, and inside the mask: outside
    it every edited frame equals the plain truth within one level (the shadow alone changes the
    road by tens of levels)."""
    assert [t.name for t in hard.edit_truths] == ["remove_5", "translate_5"]
    for truth in hard.edit_truths:
        for k in (0, 14, 28):
            mask = cv2.imread(str(truth.masks[k]), cv2.IMREAD_GRAYSCALE) > 0
            for w in ("clear", "rain"):
                plain = hard.frames[k].image_path if w == "clear" else hard.references[w][k]
                a = cv2.imread(str(plain)).astype(int)
                b = cv2.imread(str(truth.references[w][k])).astype(int)
                assert np.abs(a - b).max(axis=-1)[~mask].max() <= 1, (truth.name, k, w)
                assert mask.any()
