"""Surface attributes of lidar Gaussians: normals, ground, open sky, wheel paths, noise fields."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("torch")

from wcbench.reference_model.appearance.line_surfels import line_surfels
from wcbench.reference_model.appearance.surfaces import (
    _FOLIAGE_VARIATION,
    _box_parts,
    _road_under,
    build_surfaces,
    in_box,
    kerb_faces,
    lane_paths,
    object_sides,
    open_to_sky,
)
from wcbench.reference_model.appearance.value_noise import value_noise
from wcbench.reference_model.scene_analysis.normals import pca_normals, principal_axes, principal_frames
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.transforms import quat_to_matrix
from wcbench.scenes.scene import ObjectTrack


def test_pca_normals_of_a_tilted_plane(rng):
    n_true = np.array([0.2, -0.3, 0.9])
    n_true /= np.linalg.norm(n_true)
    a = np.cross(n_true, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n_true, a)
    uv = rng.uniform(-5, 5, (2000, 2))
    points = uv[:, :1] * a + uv[:, 1:] * b + 3.0
    normals = pca_normals(points)
    np.testing.assert_allclose(np.abs(normals @ n_true), 1.0, atol=1e-6)


def test_value_noise_is_seeded_bounded_and_smooth(rng):
    xy = rng.uniform(-50, 50, (5000, 2))
    a = value_noise(xy, cell_m=4.0, seed=3)
    assert a.min() >= 0.0 and a.max() <= 1.0 and a.std() > 0.1
    np.testing.assert_array_equal(a, value_noise(xy, cell_m=4.0, seed=3))
    assert np.abs(a - value_noise(xy, cell_m=4.0, seed=4)).mean() > 0.1
    # continuous: 1 cm moves the field by at most the slope bound (1.5 per cell, smoothstep)
    step = np.abs(value_noise(xy + 0.01, cell_m=4.0, seed=3) - a)
    assert step.max() < 1.5 * 2 * 0.01 / 4.0 + 1e-9


def test_surfaces_of_the_demo_street(demo_scene):
    surf = build_surfaces(demo_scene)
    attrs = surf.static_attributes
    normals = attrs[:, :3]
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    ground = attrs[:, 3] > 0.5
    assert 0.2 < ground.mean() < 0.95
    # ground faces up, towards the cameras, more than sideways (the stored normals are averaged over
    # neighbours, so a ground Gaussian beside a curb or a wall leans a little); what faces sideways
    # is a kerb's face, a few in a hundred (kerb_faces)
    up_component = normals[ground] @ surf.up
    assert np.median(up_component) > 0.98 and np.mean(up_component <= 0.2) < 0.05
    # a curb's step is ground too: the normals of road, face and sidewalk blend there into a slope
    # (at 0.8 up, the snow left a bare band along the PandaSet kerbs), a few per cent of the ground
    assert 0.01 < np.mean(up_component < 0.8) < 0.1
    # the ground lies at the ground height, everything else above it or beside
    heights = surf.gaussians.static.means.astype(np.float64) @ surf.up
    np.testing.assert_array_less(heights[ground] - surf.ground_height(surf.gaussians.static.means[ground]), 0.3)
    # openness: off the ground, the mean over the 8 nearest Gaussians of how much of the fall reaches
    # each (1 open, 0.5 under a tree's crown, 0 sheltered); the demo street's trees give halves. The
    # ground reads the field its Gaussians spread over the plane (0 inside a parked box's footprint)
    values = set(np.unique(attrs[~ground, 4] * 16).round(4))
    assert values <= set(range(17)) and attrs[:, 4].mean() > 0.3
    field = surf.open_field(surf.gaussians.static.means[ground])
    assert np.all(np.isclose(attrs[ground, 4], field, atol=1e-6) | (attrs[ground, 4] == 0.0))
    assert np.mean(np.isclose(attrs[ground, 4], field, atol=1e-6)) > 0.9 and 0.0 < field.min() < field.max() <= 1.0
    # wheel paths are near the cameras' path, off the rest of the ground
    assert attrs[ground, 6].max() > 0.9 and np.median(attrs[ground, 6]) < 0.5
    # a frame's attributes turn with the nodes; the static part is the static one
    cloud, frame_attrs = surf.at_frame(3)
    assert len(cloud) == len(frame_attrs) and frame_attrs.shape[1] == 7
    np.testing.assert_array_equal(frame_attrs[:len(attrs)], attrs)


def test_lane_paths_run_half_a_track_beside_the_path(demo_scene):
    up = np.asarray(demo_scene.up, np.float64) / np.linalg.norm(demo_scene.up)
    points = lane_paths(demo_scene, up=up)
    centers = np.stack([f.camera.center for f in demo_scene.frames])
    flat = centers - np.outer(centers @ up, up)
    pts = points - np.outer(points @ up, up)
    # the ego's wheels run 0.8 m to each side of every camera position (10 cm sampling)
    d = np.linalg.norm(flat[:, None, :] - pts[None, :, :], axis=2)
    np.testing.assert_allclose(d.min(axis=1), 0.8, atol=0.06)
    # and the lines reach beyond the observed path (earlier and later traffic of the lane)
    assert np.linalg.norm(pts - flat[0], axis=1).max() > 100.0


def test_snow_reaches_the_ground_beside_a_wall_not_under_a_canopy():
    # a 6 x 4 m ground at 0.1 m, a 5 m wall rising at x = 6 (facing -x) and a 1.5 m deep canopy
    # 3 m up over x < 1.5: vertical snowfall reaches all the ground but what the canopy covers
    g = np.stack(np.meshgrid(np.arange(0.0, 6.0, 0.1), np.arange(0.0, 4.0, 0.1)), -1).reshape(-1, 2)
    ground = np.column_stack([g, np.zeros(len(g))])
    w = np.stack(np.meshgrid(np.arange(0.0, 4.0, 0.1), np.arange(0.0, 5.0, 0.1)), -1).reshape(-1, 2)
    wall = np.column_stack([np.full(len(w), 6.0), w])
    c = np.stack(np.meshgrid(np.arange(0.0, 1.5, 0.1), np.arange(0.0, 4.0, 0.1)), -1).reshape(-1, 2)
    canopy = np.column_stack([c, np.full(len(c), 3.0)])
    points = np.concatenate([ground, wall, canopy])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (len(ground), 1)), np.tile([-1.0, 0.0, 0.0], (len(wall), 1)),
                              np.tile([0.0, 0.0, -1.0], (len(canopy), 1))])
    is_open = open_to_sky(points, normals, up=np.array([0.0, 0.0, 1.0]))[:len(ground)]
    x = ground[:, 0]
    assert is_open[(x > 2.0) & (x < 5.8)].all()  # up to 0.2 m from the wall's foot
    assert not is_open[x < 1.45].any()  # under the canopy


def test_a_trees_crown_lets_half_the_snow_through_a_roof_none():
    # a 6 x 4 m ground at 0.1 m under two shelters: a flat roof 3 m up over x < 1.5 (a sheet) and
    # a crown over x > 4 (returns scattered through 2.5-4.5 m, normals every way, as foliage gives
    # them); which returns are foliage comes from their own neighbourhoods' surface variation
    rng = np.random.default_rng(3)
    g = np.stack(np.meshgrid(np.arange(0.0, 6.0, 0.1), np.arange(0.0, 4.0, 0.1)), -1).reshape(-1, 2)
    ground = np.column_stack([g, np.zeros(len(g))])
    c = np.stack(np.meshgrid(np.arange(0.0, 1.5, 0.1), np.arange(0.0, 4.0, 0.1)), -1).reshape(-1, 2)
    roof = np.column_stack([c, np.full(len(c), 3.0)])
    crown = np.column_stack([rng.uniform(4.0, 6.0, 4000), rng.uniform(0.0, 4.0, 4000), rng.uniform(2.5, 4.5, 4000)])
    points = np.concatenate([ground, roof, crown])
    normals, variation = principal_axes(points)
    porous = variation > _FOLIAGE_VARIATION
    assert not porous[:len(ground) + len(roof)].any() and porous[len(ground) + len(roof):].mean() > 0.9
    up = np.array([0.0, 0.0, 1.0])
    openness = open_to_sky(points, normals, up=up, porous=porous)[:len(ground)]
    x = ground[:, 0]
    assert np.all(openness[x < 1.45] == 0.0)  # under the roof: dry
    assert np.all(openness[(x > 1.8) & (x < 3.6)] == 1.0)  # in the open
    assert np.mean(openness[x > 4.2] == 0.5) > 0.95  # under the crown: half the fall
    # without the foliage told apart, the crown shelters as a roof does (the rule before)
    assert np.mean(open_to_sky(points, normals, up=up)[:len(ground)][x > 4.2] == 0.0) > 0.95
    with pytest.raises(ValueError, match="porous"):
        open_to_sky(points, normals, up=up, porous=porous[:-1])


def test_a_crown_the_semantics_call_foliage_lets_half_the_snow_through_however_flat(demo_scene, monkeypatch):
    # a street tree's crown seen from below is smooth enough to pass the shape rule as a roof: it
    # sheltered the pavement under it from all the snow (dark patches under the trees of PandaSet's
    # side cameras, docs/findings.md). Where the scene ships lidar semantics their foliage is
    # porous too: here every return more than 0.4 m over the ground is called foliage, so nothing
    # shelters a ground Gaussian from all the fall but a parked box's body over it
    from wcbench.reference_model.scene_analysis.analysis import analyse_scene

    analysis = analyse_scene(demo_scene, log=None)
    plain = build_surfaces(demo_scene, analysis=analysis)
    up = np.asarray(plain.up, np.float64)

    def leafy(pts):
        pts = np.asarray(pts, np.float64).reshape(-1, 3)
        return pts @ up - plain.ground_height(pts) > 0.4

    monkeypatch.setattr(analysis.returns, "foliage_at", leafy)
    leaves = build_surfaces(demo_scene, analysis=analysis)
    before, after = plain.static_attributes, leaves.static_attributes
    np.testing.assert_array_equal(after[:, :3], before[:, :3])  # normals as they were
    # the ground too, but for a kerb's face under what is foliage now and structure before
    assert np.all(after[:, 3] >= before[:, 3]) and np.mean(after[:, 3] != before[:, 3]) < 0.01
    # foliage only lets more snow through: off the ground, each return's own share; the ground's field,
    # spread over the plane from its Gaussians, takes a newly ground kerb face's half under a crown
    # nearby (7 Gaussians lowered, by 0.075 at most, when written)
    off = (after[:, 3] == before[:, 3]) & (before[:, 3] < 0.5)
    assert np.all(after[off, 4] >= before[off, 4] - 1e-6)
    assert np.all(after[:, 4] >= before[:, 4] - 0.1) and np.mean(after[:, 4] < before[:, 4] - 1e-6) < 0.001
    ground = before[:, 3] > 0.5
    means = np.asarray(plain.gaussians.static.means, np.float64)
    parked = [(T, size) for t in demo_scene.tracks for T, size in zip(t.object_to_world, t.box_size)]
    _, _, under = _box_parts(means, parked, up=up)
    # the ground a roof-like shelter kept drier than a crown does now gets at least the crown's half
    # (its field spread over the plane), but under a box
    dry = ground & (before[:, 4] < 0.5) & ~under
    assert dry.sum() > 20, dry.sum()
    assert np.all(after[dry, 4] >= 0.5), np.round(after[dry, 4], 2)


def test_people_leave_no_wheel_path(demo_scene):
    up = np.asarray(demo_scene.up, np.float64) / np.linalg.norm(demo_scene.up)
    before = lane_paths(demo_scene, up=up)
    # a pedestrian walking 6 m along a sidewalk 5 m beside the first camera
    n = len(demo_scene.frames)
    poses = np.tile(np.eye(4), (n, 1, 1))
    start = np.asarray(demo_scene.frames[0].camera.center, np.float64)
    side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    poses[:, :3, 3] = start + 5.0 * side + np.linspace(0.0, 6.0, n)[:, None] * np.cross(side, up)
    walker = ObjectTrack(id="p", class_name="pedestrian", frames=np.arange(n), object_to_world=poses,
                         box_size=np.tile([0.6, 0.6, 1.7], (n, 1)))
    after = lane_paths(dataclasses.replace(demo_scene, tracks=[*demo_scene.tracks, walker]), up=up)
    np.testing.assert_array_equal(after, before)
    # a car driving there would leave one
    car = dataclasses.replace(walker, class_name="vehicle")
    assert len(lane_paths(dataclasses.replace(demo_scene, tracks=[*demo_scene.tracks, car]), up=up)) > len(before)


def _parked_car(yaw: float, at: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """A 4.5 x 1.8 x 1.5 m sedan's box (object-to-world, yawed, standing on z = 0 at ``at``) and
    points (world) of its parts at 5 cm: roof, bonnet, doors and side windows, bumpers, and the road
    under and beside it."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = [at[0], at[1], 0.75]
    g = np.arange(-1.0, 1.0, 0.05)
    grid = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    local = {
        "roof": np.column_stack([grid[:, 0] * 0.9, grid[:, 1] * 0.65, np.full(len(grid), 0.72)]),
        "bonnet": np.column_stack([1.7 + grid[:, 0] * 0.5, grid[:, 1] * 0.6, np.full(len(grid), 0.15)]),
        "doors": np.column_stack([grid[:, 0] * 2.0, np.sign(grid[:, 1]) * 0.88, -0.6 + (grid[:, 1] % 0.5) * 2.1]),
        "bumpers": np.column_stack([np.sign(grid[:, 0]) * 2.24, grid[:, 1] * 0.8, -0.5 + (grid[:, 0] % 0.5)]),
        "road": np.column_stack([grid * [4.0, 3.0], np.full(len(grid), -0.75)]),
    }
    return T, np.array([4.5, 1.8, 1.5]), {k: v @ T[:3, :3].T + T[:3, 3] for k, v in local.items()}


@pytest.mark.parametrize("yaw", [0.0, 0.7])
def test_a_boxed_objects_sides_are_found_not_its_top_nor_the_road(yaw):
    T, size, parts = _parked_car(yaw, np.array([5.0, -2.0]))
    up = np.array([0.0, 0.0, 1.0])
    points = np.concatenate(list(parts.values()))
    side = object_sides(points, [(T, size)], up=up)
    start = 0
    for name, pts in parts.items():
        got = side[start:start + len(pts)]
        start += len(pts)
        if name in ("doors", "bumpers"):
            assert got.all(), name
        else:
            assert not got.any(), name



def test_the_road_a_moving_cars_box_takes_in_is_told_from_its_body(rng):
    # a node's returns in its box frame (z up, 4.5 x 1.8 x 1.5 m): the road it stands on (a patch
    # at the bottom, as the box's margin takes it in), its doors and wheels down to the road, its roof
    size = np.array([[4.5, 1.8, 1.5]])
    bottom = -0.75
    road = np.stack([rng.uniform(-2.6, 2.6, 300), rng.uniform(-1.1, 1.1, 300), bottom + rng.normal(0, 0.02, 300)], 1)
    door = np.stack([rng.uniform(-2.2, 2.2, 300), np.full(300, 0.9), rng.uniform(bottom + 0.05, 0.2, 300)], 1)
    roof = np.stack([rng.uniform(-1.0, 1.0, 200), rng.uniform(-0.7, 0.7, 200), np.full(200, 0.75)], 1)
    got = _road_under(np.concatenate([road, door, roof]), size)
    # the road, but where its nearest returns mix with the door's foot (a tilted normal)
    assert got[:300][np.abs(road[:, 1] - 0.9) > 0.3].all()
    door_got, foot = got[300:600], door[:, 2] < bottom + 0.3
    assert not door_got[~foot].any() and not got[600:].any()  # above the band: the body, the roof
    # a door's foot faces sideways; where its few returns' nearest are the road's, one in ten tilts
    assert door_got[foot].mean() < 0.15

def test_a_parked_cars_sills_shelter_only_the_ground_under_it():
    # the road beside a parked car's doors: its sills and bumpers face down within 0.5 m sideways
    # and shelter it by the any-return rule (dark holes in the snow beside the parked cars of the
    # side cameras); vertical snowfall reaches it when the car shelters only its own footprint
    T, size, parts = _parked_car(0.0, np.array([0.0, 0.0]))
    # an SUV's doors curve under from 0.55 to 0.7 m: there their returns face down
    sills = parts["doors"][(parts["doors"][:, 2] > 0.55) & (parts["doors"][:, 2] < 0.7)]
    # its bumpers' returns outline the body at the box's ends (the ground it shelters, below)
    bumpers = parts["bumpers"][parts["bumpers"][:, 2] > 0.4]
    car = np.concatenate([parts["roof"], sills, bumpers])
    car_normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (len(parts["roof"]), 1)),
                                  np.tile([0.0, 0.0, -1.0], (len(sills), 1)),
                                  np.tile([1.0, 0.0, 0.0], (len(bumpers), 1))])
    g = np.stack(np.meshgrid(np.arange(-2.0, 2.0, 0.1), np.arange(-1.6, 1.6, 0.1)), -1).reshape(-1, 2)
    road = np.column_stack([g, np.zeros(len(g))])
    points = np.concatenate([road, car])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (len(road), 1)), car_normals])
    up = np.array([0.0, 0.0, 1.0])
    beside = (np.abs(road[:, 1]) > 1.0) & (np.abs(road[:, 1]) < 1.35) & (np.abs(road[:, 0]) < 1.8)
    assert not open_to_sky(points, normals, up=up)[:len(road)][beside].all()  # the old rule
    # build_surfaces' rule: the car's body shelters nothing beside it, its footprint is sheltered
    _, body, under = _box_parts(points, [(T, size)], up=up)
    np.testing.assert_array_equal(body, np.arange(len(points)) >= len(road))
    is_open = (open_to_sky(points, normals, up=up, shelters=~body) * ~under)[:len(road)]
    assert np.all(is_open[beside] == 1.0)
    assert not is_open[(np.abs(road[:, 0]) < 2.2) & (np.abs(road[:, 1]) < 0.85)].any()
    with pytest.raises(ValueError, match="shelters"):
        open_to_sky(points, normals, up=up, shelters=body[:-1])


def test_a_parked_cars_rounded_corners_leave_its_boxs_corners_open():
    # a 4.5 x 1.8 m box round a car whose plan has corners rounded by 0.5 m: the road in the box's
    # corners, beside the bumpers, is under no body (a bare lobe at the corner in the snow on the
    # PandaSet right camera); the road under the body is sheltered
    T, size, _ = _parked_car(0.0, np.array([0.0, 0.0]))
    half, radius = size[:2] / 2, 0.5
    t = np.linspace(0.0, 2 * np.pi, 400, endpoint=False)
    # the rounded rectangle's outline (each side's straight run, the quarter circles at the corners)
    core = half - radius
    ring = np.column_stack([np.clip(np.cos(t) * 10, -1, 1) * core[0] + radius * np.cos(t),
                            np.clip(np.sin(t) * 10, -1, 1) * core[1] + radius * np.sin(t)])
    body = np.concatenate([np.column_stack([ring, np.full(len(ring), z)]) for z in (0.5, 0.9, 1.3)])
    g = np.stack(np.meshgrid(np.arange(-2.2, 2.25, 0.05), np.arange(-0.85, 0.9, 0.05)), -1).reshape(-1, 2)
    road = np.column_stack([g, np.zeros(len(g))])
    up = np.array([0.0, 0.0, 1.0])
    _, _, under = _box_parts(np.concatenate([road, body]), [(T, size)], up=up)
    under = under[:len(road)]
    inward = half - np.abs(g)  # from the box's sides
    corner = np.hypot(np.maximum(radius - inward[:, 0], 0), np.maximum(radius - inward[:, 1], 0))
    assert not under[corner > radius + 0.06].any()  # past the rounded body (its outline's chords)
    assert under[corner < radius - 0.06].all()
    # a car the lidar barely saw (a dozen returns on it) shelters its whole footprint
    few = body[:: len(body) // 12][:12]
    _, _, under_few = _box_parts(np.concatenate([road, few]), [(T, size)], up=up)
    assert under_few[:len(road)].all()


def _frames_with_movers(surfaces, rng, n, spread_m, monkeypatch):
    """Frames 0 and 7 of ``surfaces`` with ``n`` movers each after the static Gaussians (as at_frame
    appends them), scattered by ``spread_m`` around static ones; at_frame patched to give them.
    Returns (the static cloud, {frame: (cloud, attributes)})."""
    static, static_attrs = surfaces.at_frame(0)
    frames = {}
    for index in (0, 7):
        means = (np.asarray(static.means)[rng.integers(0, len(static), n)]
                 + rng.normal(0, spread_m, (n, 3))).astype(np.float32)
        movers = GaussianCloud(means=means, quats=np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
                               scales=np.full((n, 3), 0.05, np.float32), opacities=np.full(n, 0.9, np.float32),
                               colors=np.zeros((n, 3), np.float32))
        frames[index] = (GaussianCloud.concatenate([static, movers]),
                         np.concatenate([static_attrs, np.zeros((n, static_attrs.shape[1]), np.float32)]))
    monkeypatch.setattr(surfaces, "at_frame", lambda k: frames[k])
    return static, frames


def test_the_batched_neighbour_search_finds_what_a_brute_force_one_does(demo_scene, monkeypatch):
    # the slow twin: distances to every Gaussian of the frame, static and moving alike
    surfaces = build_surfaces(demo_scene)
    rng = np.random.default_rng(4)
    static, frames = _frames_with_movers(surfaces, rng, 400, 1.5, monkeypatch)
    balls = {}
    for index in (0, 7, 0, 7):  # each frame's balls asked again (the kept ones), frames in turn
        means = np.asarray(frames[index][0].means, np.float64)
        if index not in balls:
            balls[index] = (means[rng.integers(0, len(means), 6)] + rng.normal(0, 2.0, (6, 3)),
                            rng.uniform(0.5, 6.0, 6))
        centers, radii = balls[index]
        found = surfaces.near(index, centers, radii)
        assert len(found) == 6
        for c, r, idx in zip(centers, radii, found):
            slow = np.flatnonzero(np.linalg.norm(means - c, axis=1) <= r)
            np.testing.assert_array_equal(np.sort(idx), slow)
        assert any(np.any(i >= len(static)) for i in found), "a ball holds movers"
    assert surfaces.near(0, np.zeros((0, 3)), np.zeros(0)) == []


def test_the_points_inside_boxes_kept_for_a_parked_car_are_those_a_brute_force_search_finds(demo_scene, monkeypatch):
    # the slow twin: every Gaussian of the frame tested against the box; the same boxes asked for at
    # two frames with other movers (a parked car's static points kept, the movers tested again)
    surfaces = build_surfaces(demo_scene)
    rng = np.random.default_rng(6)
    static, frames = _frames_with_movers(surfaces, rng, 600, 1.0, monkeypatch)
    poses = np.tile(np.eye(4), (8, 1, 1))
    for T in poses:
        yaw = rng.uniform(0, 2 * np.pi)
        T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
        T[:3, 3] = np.asarray(static.means)[rng.integers(0, len(static))]
    halves = rng.uniform(0.5, 3.0, (8, 3))
    for index in (0, 7, 0):
        means = np.asarray(frames[index][0].means, np.float64)
        found = surfaces.inside_boxes(index, poses, halves)
        for T, half, pts in zip(poses, halves, found):
            slow = means[in_box((means - T[:3, 3]) @ T[:3, :3], half)]
            np.testing.assert_array_equal(pts, slow)
        assert any(np.any(np.isin(p[:, 0], means[len(static):, 0])) for p in found), "a box holds movers"
    assert surfaces.inside_boxes(0, np.zeros((0, 4, 4)), np.zeros((0, 3))) == []


def test_principal_frames_are_the_neighbourhoods_covariance_and_principal_axes_read_them(rng):
    points = rng.normal(size=(300, 3)) * [2.0, 0.5, 0.05]
    values, axes = principal_frames(points, k=300)
    cov = np.cov(points.T, bias=True)  # every point's neighbourhood is the whole cloud
    np.testing.assert_allclose(values[0], np.linalg.eigvalsh(cov), rtol=1e-9)
    np.testing.assert_allclose(axes[0] @ np.diag(values[0]) @ axes[0].T, cov, atol=1e-12)
    normals, variation = principal_axes(points, k=300)
    np.testing.assert_array_equal(normals, axes[:, :, 0])
    np.testing.assert_allclose(variation, values[:, 0] / values.sum(axis=1), rtol=1e-12)


def _covariances(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    rot = np.stack([quat_to_matrix(q.astype(np.float64)) for q in quats])
    return np.einsum("nij,nj,nkj->nik", rot, scales.astype(np.float64) ** 2, rot)


def test_a_wire_is_a_thin_line_and_a_lidar_ring_on_a_wall_stays_a_disc(rng):
    direction = np.array([0.6, 0.8, 0.0])
    t = np.arange(-60, 61) * 0.05
    wire = np.array([3.0, -2.0, 8.0]) + t[:, None] * direction + rng.normal(scale=0.01, size=(len(t), 3))
    # one ring across a wall with the next ring 0.5 m above it: 16 neighbours lie on the ring alone
    ring = np.stack([t, np.full_like(t, 20.0), np.full_like(t, 1.0)], 1)
    wall = np.concatenate([ring, ring + np.array([0.0, 0.0, 0.5])])
    for points, is_wire in ((wire, True), (wall, False)):
        spread, frames = principal_frames(points)
        normals = frames[:, :, 0]
        width = np.full(len(points), 0.2, np.float32)
        quats, across = line_surfels(normals, spread, frames[:, :, 2], width, points)
        scales = np.stack([width, across, 0.25 * width], 1)
        cov = _covariances(quats, scales)
        rot = np.stack([quat_to_matrix(q.astype(np.float64)) for q in quats])
        np.testing.assert_allclose(np.abs(np.einsum("nij,nj->ni", rot, [[0, 0, 1.0]] * len(points))),
                                   np.abs(normals), atol=1e-5)  # the surfel's third axis is its normal
        inner = slice(10, len(t) - 10)
        if is_wire:
            # along the wire as wide as before, across it as the returns spread (0.01 m noise)
            np.testing.assert_allclose(direction @ cov[inner] @ direction, 0.04, rtol=5e-3)
            assert np.all(across[inner] < 0.03) and np.all(across[inner] > 0.003)
        else:
            np.testing.assert_array_equal(across, width)


def test_a_crown_reaching_into_a_parked_cars_box_is_not_in_it(demo_scene, monkeypatch):
    # a street tree's crown hangs into a parked car's box: the box's hull was drawn from its leaves
    # too, and spread the car's shell over the sidewalk between crown and bonnet (a bare patch in
    # the snow, docs/findings.md). The analysis' semantics say which static Gaussians are foliage
    # (here: those above 1 m); the box keeps the rest, and its movers all
    surfaces = build_surfaces(demo_scene)
    rng = np.random.default_rng(7)
    static, _ = _frames_with_movers(surfaces, rng, 300, 1.0, monkeypatch)
    means = np.asarray(static.means, np.float64)
    up = np.asarray(surfaces.up, np.float64)

    def leafy(pts):
        return np.asarray(pts, np.float64).reshape(-1, 3) @ up > float(np.median(means @ up))

    pose = np.eye(4)
    pose[:3, 3] = means[np.argmin(np.abs(means @ up - np.median(means @ up)))]
    half = np.array([[3.0, 3.0, 3.0]])
    plain = surfaces.inside_boxes(0, pose[None], half)[0]
    assert leafy(plain).any() and (~leafy(plain)).any()
    monkeypatch.setattr(surfaces, "analysis", SimpleNamespace(returns=SimpleNamespace(foliage_at=leafy)))
    monkeypatch.setattr(surfaces, "_inside_memo", {})
    kept = surfaces.inside_boxes(0, pose[None], half)[0]
    n_static = int(np.isin(plain[:, 0], means[:, 0]).sum())
    static_kept = kept[:int(np.isin(kept[:, 0], means[:, 0]).sum())]
    assert not leafy(static_kept).any()
    np.testing.assert_array_equal(static_kept, plain[:n_static][~leafy(plain[:n_static])])
    assert len(plain) > n_static
    np.testing.assert_array_equal(kept[len(static_kept):], plain[n_static:])  # the movers all stay


def test_a_kerbs_face_is_ground_and_a_walls_foot_is_not_whatever_hangs_over_them():
    # returns along x: a kerb's face at y = 0 (0-0.15 m over the road, facing the road), the
    # sidewalk's top behind it, and 10 m further a wall's face rising 3 m; a street tree's lowest
    # branches hang 1.8 m over the kerb's second half (foliage: not solid)
    x = np.arange(0.0, 6.0, 0.1)
    kerb = np.stack([x, np.zeros_like(x), np.full_like(x, 0.08)], 1)
    top = np.stack([x, np.full_like(x, 0.5), np.full_like(x, 0.15)], 1)
    wall = np.concatenate([np.stack([x + 10.0, np.zeros_like(x), np.full_like(x, z)], 1) for z in (0.1, 0.6, 1.2, 2.5)])
    branches = np.stack([x[30:], np.full(30, 0.1), np.full(30, 1.8)], 1)
    points = np.concatenate([kerb, top, wall, branches])
    up_component = np.concatenate([np.zeros(len(kerb)), np.ones(len(top)), np.zeros(len(wall)), -np.ones(30)])
    solid = np.concatenate([np.ones(len(points) - 30, bool), np.zeros(30, bool)])
    got = kerb_faces(points[:, :2], points[:, 2], up_component, solid)
    n_kerb, n_top = len(kerb), len(top)
    assert got[:n_kerb].all()  # the face, under the branches too
    assert not got[n_kerb:n_kerb + n_top].any()  # the sidewalk's top is ground by its normal, not here
    wall_low = np.arange(n_kerb + n_top, n_kerb + n_top + len(x))
    assert not got[wall_low].any() and not got[n_kerb + n_top + len(x):].any()  # a wall's foot, the wall
    # branches counted as structure take the face under them from the ground
    under = kerb_faces(points[:, :2], points[:, 2], up_component, np.ones(len(points), bool))
    assert under[:27].all() and not under[30:n_kerb].any()  # (those within 0.3 m of the first branch too)
    # the k-d tree's answer is the brute-force one, on scattered returns
    rng = np.random.default_rng(0)
    pts = rng.uniform([0, 0, -0.1], [4, 4, 2.5], (400, 3))
    ups, solid = rng.uniform(-1, 1, 400), rng.random(400) > 0.2
    low = (pts[:, 2] < 0.3) & (np.abs(ups) <= 0.3)
    tall = (pts[:, 2] >= 0.3) & (pts[:, 2] < 2.0) & solid
    gaps = np.linalg.norm(pts[:, None, :2] - pts[None, tall, :2], axis=-1)
    expected = low & ~(gaps <= 0.3).any(axis=1)
    np.testing.assert_array_equal(kerb_faces(pts[:, :2], pts[:, 2], ups, solid), expected)
