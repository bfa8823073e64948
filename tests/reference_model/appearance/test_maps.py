"""The per-view surface maps' stand-in for a tracked object the lidar samples sparsely: its box
(docs/design.md §7, "Weather appearance")."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

pytest.importorskip("torch")

from wcbench.reference_model.appearance.box_shells import (
    _BOX_SLACK_M,
    _CABIN_SHARE,
    _CUBE,
    _box_motions,
    _boxes_miss_view,
    _clipped_box_outline,
    _replace_tails,
    _slab_interval,
    _spill_region,
    _vertical_steps,
    box_shells,
    moving_pixels,
)
from wcbench.reference_model.appearance.maps import (
    _COVERED,
    FIELDS,
    HIT_FILLED,
    HIT_SEEN,
    HIT_SKY,
    NO_HIT,
    _gaussian_blur,
    _mirrored_cloud,
    _rasterize,
    _rays,
    _reflection_lookup,
    _reflection_lookup_fast,
    facing_view,
    glossy_blur,
    mirror_distance,
    refine,
    screen_reflection,
    surface_maps,
)
from wcbench.reference_model.appearance.open_ground import OpenGround
from wcbench.reference_model.appearance.surfaces import UNDERBODY_M, build_surfaces, in_box
from wcbench.reference_model.model.sky import view_directions
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.weather.particle_geometry import quat_from_axis_to
from wcbench.scenes.scene import Camera

UP = np.array([0.0, 0.0, 1.0])
#: A parked car's box: 4.5 x 1.8 x 1.5 m, its near face 7.75 m ahead of the camera, on the ground.
SIZE = np.array([4.5, 1.8, 1.5])
BOX = np.eye(4)
BOX[:3, 3] = [10.0, 0.0, 0.75]


def _camera(height_m):
    """A camera ``height_m`` above the ground looking along +x (OpenCV axes), 320 x 180, f = 300 px."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    c2w[:3, 3] = [0.0, 0.0, height_m]
    return Camera(K=np.array([[300.0, 0, 160.0], [0, 300.0, 90.0], [0, 0, 1]]), width=320, height=180,
                  camera_to_world=c2w)


def _surfaces(box=BOX, grid=(7, 5, 5), own=None, sweep_behind_m=None):
    """The lidar's few returns of the car: points over its box's surface (the hull covers it);
    ``own`` [M, 3] the movers' returns of frame 0's sweep (none by default: no analysis). With
    ``sweep_behind_m``, frame 0 has no sweep and frame 1's is the nearest, taken when the car stood
    that far back along x (its returns there are ``own`` moved back)."""
    g = np.stack(np.meshgrid(*(np.linspace(-1, 1, n) for n in grid)), -1).reshape(-1, 3)
    shell = g[np.max(np.abs(g), axis=1) == 1.0] * SIZE / 2 + box[:3, 3]
    n = len(shell)
    cloud = GaussianCloud(means=shell.astype(np.float32), quats=np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
                          scales=np.full((n, 3), 0.1, np.float32), opacities=np.ones(n, np.float32),
                          colors=np.zeros((n, 3), np.float32))
    analysis, back = None, box.copy()
    back[0, 3] -= sweep_behind_m or 0.0
    if own is not None:
        sweep = 0 if sweep_behind_m is None else 1
        moved = own - (box[:3, 3] - back[:3, 3])
        analysis = SimpleNamespace(returns=SimpleNamespace(
            nearest_sweep=lambda k: sweep, own_tracked=lambda k: moved if k == sweep else own[:0]))
    return SimpleNamespace(up=UP, boxes_at=lambda k: [(box, SIZE)], at_frame=lambda k: (cloud, None), analysis=analysis,
                           boxes=[(np.array([0, 1]), np.stack([box, back]), np.stack([SIZE, SIZE]))],
                           inside_boxes=lambda k, poses, halves: [shell[in_box((shell - T[:3, 3]) @ T[:3, :3], h)]
                                                                  for T, h in zip(poses, halves)])


@pytest.mark.parametrize("moves", [True, False])
def test_a_surface_on_a_moving_objects_box_is_moving_the_road_under_it_and_a_parked_ones_not(moves):
    camera = _camera(1.6)
    rays, _ = _rays(camera)
    surfaces = SimpleNamespace(up=UP, boxes_at=lambda k, moving_only=False: [(BOX, SIZE)] if moves or not moving_only
                               else [])
    # one surface point at each of four pixels: the car's rear, its roof, the road under its sill
    # (inside the box's slack, below the underbody line) and a wall past it
    points = {"rear": [7.75, 0.0, 0.8], "roof": [9.0, 0.0, 1.5], "under": [7.9, 0.0, 0.1], "wall": [30.0, 0.0, 1.0]}
    distance = np.full(rays.shape[:2], np.inf)
    for p in points.values():
        distance[_pixel(camera, p)] = np.linalg.norm(np.asarray(p) - camera.center)
    moving = moving_pixels(surfaces, 0, camera, rays, distance, np.isfinite(distance))
    for name, p in points.items():
        assert moving[_pixel(camera, p)] == (moves and name in ("rear", "roof")), name
    assert moving.sum() == 2 * moves
    # only the candidates (the box shells' pixels) are asked
    assert not moving_pixels(surfaces, 0, camera, rays, distance, np.zeros(distance.shape, bool)).any()


@pytest.mark.parametrize("seed", range(4))
def test_the_moving_pixels_culled_by_each_boxs_projected_corners_are_every_boxs_test_of_every_pixel(seed):
    rng = np.random.default_rng(seed)
    camera = _camera(1.6)
    rays, _ = _rays(camera)
    boxes = []
    for _ in range(12):  # ahead, beside, straddling the camera and behind it
        T = np.eye(4)
        yaw = rng.uniform(-np.pi, np.pi)
        T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
        T[:3, 3] = [rng.uniform(-8.0, 25.0), rng.uniform(-6.0, 6.0), 0.75]
        boxes.append((T, np.array([rng.uniform(0.8, 5.0), rng.uniform(0.6, 2.2), 1.5])))
    surfaces = SimpleNamespace(up=UP, boxes_at=lambda k, moving_only=False: boxes)
    distance = rng.uniform(1.0, 30.0, rays.shape[:2])
    distance[rng.random(distance.shape) < 0.05] = np.inf
    candidates = rng.random(distance.shape) < 0.7
    fast = moving_pixels(surfaces, 0, camera, rays, distance, candidates)
    # the twin: every box against every candidate pixel's surface point
    points = camera.center + rays * np.where(np.isfinite(distance), distance, 0.0)[..., None]
    twin = np.zeros(distance.shape, bool)
    for T, size in boxes:
        local = (points - T[:3, 3]) @ T[:3, :3]
        twin |= (in_box(local.reshape(-1, 3), size / 2 + _BOX_SLACK_M).reshape(distance.shape)
                 & (local[..., 2] >= -size[2] / 2 + UNDERBODY_M))
    twin &= candidates & np.isfinite(distance)
    assert twin.sum() > 1000
    np.testing.assert_array_equal(fast, twin)


@pytest.mark.model
def test_the_surfaces_know_which_boxes_move(synth_hard):
    surfaces = build_surfaces(synth_hard)
    nodes = {node.track_id for node in surfaces.gaussians.nodes}
    assert nodes and len(nodes) < len(synth_hard.tracks)  # some move, some are parked
    assert surfaces.moving.tolist() == [str(t.id) in nodes for t in synth_hard.tracks]
    for k in range(len(synth_hard)):
        annotated = [str(t.id) for t in synth_hard.tracks if k in set(np.asarray(t.frames).tolist())]
        assert len(surfaces.boxes_at(k)) == len(annotated)
        assert len(surfaces.boxes_at(k, moving_only=True)) == sum(i in nodes for i in annotated)


def _pixel(camera, point):
    uv, _ = camera.project(np.asarray(point, np.float64)[None])
    return int(np.floor(uv[0, 1])), int(np.floor(uv[0, 0]))


def _maps(camera, distance_m=30.0):
    """The lidar's maps where it sees a wall ``distance_m`` away through the sparse car."""
    h, w = camera.height, camera.width
    normal = np.zeros((h, w, 3), np.float32)
    normal[..., 0] = -1.0
    fields = {k: np.zeros((h, w), np.float32) for k in ("ground", "open", "puddle", "track")}
    return np.full((h, w), distance_m, np.float64), normal, fields


def test_a_box_stands_for_a_sparse_car_only_where_the_ray_passes_through_its_body():
    camera = _camera(1.6)
    rays, _ = _rays(camera)
    distance, normal, fields = _maps(camera)
    changed = box_shells(_surfaces(), 0, camera, rays, camera.center, distance, normal, fields,
                          np.zeros(distance.shape, bool))
    # through the lower body: the box's near face, 7.75 m away, vertical (it takes no snow)
    body = _pixel(camera, [7.75, 0.0, 0.4])
    assert changed[body] and distance[body] == pytest.approx(7.75 / rays[body][0], rel=1e-6)
    np.testing.assert_allclose(normal[body], [-1.0, 0.0, 0.0], atol=1e-6)
    # just under the box's top and above the glasshouse all the way through (the air the box holds
    # over the roof's curve): the wall behind stays, and no roof is invented there
    air = _pixel(camera, [7.75, 0.0, 1.47])
    assert not changed[air] and distance[air] == 30.0
    # no pixel of the box takes a face that faces up unless its ray passes through the body
    assert np.all(normal[changed] @ UP.astype(np.float32) < 0.3)


def test_a_ray_through_the_glass_takes_the_glasshouses_face_not_the_boxs_top():
    # a camera 2.2 m up, the car 2.75 m ahead: the ray enters its box through the top (1.5 m) just
    # behind the front face, and the glasshouse (from the middle 0.6 of the length: 3.65 m) through
    # its front under its roof (1.35 m); the lidar saw through the glass. The windscreen stands
    # upright there (the box's top drew a band of snow across a windscreen)
    camera = _camera(2.2)
    rays, _ = _rays(camera)
    distance, normal, fields = _maps(camera)
    box = BOX.copy()
    box[0, 3] = 5.0
    pixel = _pixel(camera, [3.65, 0.0, 1.30])
    ray = rays[pixel]
    assert 2.2 + ray[2] * (2.75 / ray[0]) > 1.5  # it enters through the box's top
    changed = box_shells(_surfaces(box), 0, camera, rays, camera.center, distance, normal, fields,
                         np.zeros(distance.shape, bool))
    assert changed[pixel] and distance[pixel] == pytest.approx(3.65 / ray[0], rel=1e-9)
    np.testing.assert_allclose(normal[pixel], [-1.0, 0.0, 0.0], atol=1e-6)


def test_the_road_just_before_and_under_a_cars_sills_stays_road():
    camera = _camera(1.6)
    rays, _ = _rays(camera)
    distance, normal, fields = _maps(camera)
    # a ray that passes the box's near face 0.14 m above the road, under the sills, and meets the
    # road under the car 8.5 m away: what the lidar saw there (the road) stays
    pixel = _pixel(camera, [7.75, 0.0, 0.14])
    distance[pixel] = 1.6 / -rays[pixel][2]
    normal[pixel], fields["ground"][pixel] = UP, 1.0
    changed = box_shells(_surfaces(), 0, camera, rays, camera.center, distance, normal, fields,
                          np.zeros(distance.shape, bool))
    assert not changed[pixel] and fields["ground"][pixel] == 1.0
    np.testing.assert_allclose(normal[pixel], UP, atol=1e-6)


def test_a_cars_gaussians_tails_beside_its_silhouette_and_their_blend_past_them_take_what_lies_beside_it():
    camera = _camera(1.6)
    rays, _ = _rays(camera)
    distance, normal, fields = _maps(camera)
    # the lidar's maps put the car's roof (facing up) 0.1 m beside its box's side, about 4 px from
    # the hull of its returns: the tails of its Gaussians over the wall behind; one pixel farther
    # out, their compositing with the wall: off the car (12 m away), its normal half up
    pixel = _pixel(camera, [7.75, 1.0, 1.0])
    distance[pixel] = float(np.linalg.norm(np.array([7.75, 1.0, 1.0 - 1.6])))
    normal[pixel], fields["open"][pixel] = UP, 1.0
    blend = (pixel[0], pixel[1] - 1)
    distance[blend] = 12.0
    normal[blend] = np.array([-1.0, 0.0, 1.0]) / np.sqrt(2.0)
    box_shells(_surfaces(), 0, camera, rays, camera.center, distance, normal, fields, np.zeros(distance.shape, bool))
    assert fields["open"][pixel] == 0.0
    for p in (pixel, blend):
        assert distance[p] == 30.0
        np.testing.assert_allclose(normal[p], [-1.0, 0.0, 0.0], atol=1e-6)
    # a pixel of the wall beside it keeps the wall (its surface is nowhere near the car)
    far = _pixel(camera, [7.75, 3.0, 1.0])
    assert distance[far] == 30.0


@pytest.mark.parametrize("mover", [True, False])
def test_below_the_underbody_line_a_surface_beside_a_movers_footprint_is_tails_one_under_it_stays(mover):
    # a mover's node gathers every sweep's returns in its box's frame, spread past the car by the
    # boxes' jitter: its lowest Gaussians, facing down, reach 0.15 m beside the box below the line
    # (0.3 m) where the road under a car shows, over the road beside it (a dark wedge in the snow);
    # a surface under the car's sill, inside its footprint, is the car's or the road under it. A
    # parked car's Gaussians are its static returns: beside its box there, its tyres stay
    camera = _camera(1.6)
    rays, _ = _rays(camera)
    distance, normal, fields = _maps(camera)
    pixels = {}
    for name, point in (("beside", [7.75, 1.05, 0.2]), ("under", [7.9, 0.0, 0.12])):
        pixel = pixels[name] = _pixel(camera, point)
        distance[pixel] = float(np.linalg.norm(np.array(point) - camera.center))
        normal[pixel], fields["open"][pixel] = [0.0, 0.0, -1.0], 1.0
    surfaces = _surfaces(own=_narrower_car(0.9) if mover else None)
    box_shells(surfaces, 0, camera, rays, camera.center, distance, normal, fields, np.zeros(distance.shape, bool))
    beside, under = pixels["beside"], pixels["under"]
    if mover:
        assert distance[beside] == 30.0 and fields["open"][beside] == 0.0
        np.testing.assert_allclose(normal[beside], [-1.0, 0.0, 0.0], atol=1e-6)
    else:
        assert distance[beside] < 10.0 and fields["open"][beside] == 1.0
    assert distance[under] < 10.0 and fields["open"][under] == 1.0
    np.testing.assert_allclose(normal[under], [0.0, 0.0, -1.0], atol=1e-6)


def _narrower_car(half_width):
    """Returns over the near face and the top of a car ``half_width`` wide (m) inside BOX's box."""
    y, z = np.meshgrid(np.linspace(-half_width, half_width, 13), np.linspace(0.35, 1.5, 12))
    face = np.stack([np.full(y.size, 7.75), y.ravel(), z.ravel()], 1)
    x, y = np.meshgrid(np.linspace(7.75, 12.25, 10), np.linspace(-half_width, half_width, 13))
    top = np.stack([x.ravel(), y.ravel(), np.full(x.size, 1.5)], 1)
    return np.concatenate([face, top])


@pytest.mark.parametrize("own_returns, sweep_behind_m", [(300, None), (300, 2.0), (15, None)])
def test_a_movers_silhouette_is_its_frames_own_returns_where_they_sampled_it(own_returns, sweep_behind_m):
    # the mover's Gaussians fill its box (the boxes' jitter spread them 0.3 m past the car on each
    # side); the frame's own sweep saw the car 1.4 m wide: a pixel of the maps on the box's side
    # past those returns is the Gaussians' tails and takes the wall behind. A frame without a sweep
    # takes the nearest one's, carried with the box (the car 2 m back then). With too few returns
    # (fewer than 20), the hull of the Gaussians stands, and the pixel is the car's side.
    camera = _camera(1.6)
    rays, _ = _rays(camera)
    distance, normal, fields = _maps(camera)
    own = _narrower_car(0.7)
    own = own[np.random.default_rng(0).permutation(len(own))[:own_returns]]
    pixel = _pixel(camera, [7.75, 0.85, 1.0])
    distance[pixel] = float(np.linalg.norm(np.array([7.75, 0.85, 1.0 - 1.6])))
    normal[pixel], fields["open"][pixel] = UP, 1.0
    box_shells(_surfaces(own=own, sweep_behind_m=sweep_behind_m), 0, camera, rays, camera.center, distance, normal,
               fields, np.zeros(distance.shape, bool))
    if own_returns >= 20:
        assert distance[pixel] == 30.0 and fields["open"][pixel] == 0.0
        # the car the frame's returns saw keeps its face
        inner = _pixel(camera, [7.75, 0.4, 0.8])
        assert distance[inner] == pytest.approx(7.75 / rays[inner][0], rel=1e-6)
    else:
        assert distance[pixel] < 10.0 and fields["open"][pixel] == 1.0


def test_a_lidar_surface_on_a_car_keeps_its_own_normal_not_the_roof_the_ray_enters():
    camera = _camera(1.8)
    rays, _ = _rays(camera)
    distance, normal, fields = _maps(camera)
    # the ray enters the box through its top (the camera is above the car) and meets a side
    # window the lidar sampled, 0.2 m inside the box: a surface facing sideways
    pixel = _pixel(camera, [10.0, 0.0, 1.5])
    ray = rays[pixel]
    entry = (1.5 - 1.8) / ray[2]
    distance[pixel] = entry + 0.2
    normal[pixel] = [0.0, -0.94, 0.34]
    changed = box_shells(_surfaces(), 0, camera, rays, camera.center, distance, normal, fields,
                          np.zeros(distance.shape, bool))
    assert changed[pixel] and fields["open"][pixel] == 1.0 and fields["ground"][pixel] == 0.0
    np.testing.assert_allclose(normal[pixel], [0.0, -0.94, 0.34], atol=1e-6)
    assert distance[pixel] == pytest.approx(entry + 0.2)


def _spilled_roof(camera, top_row, frame_top_row):
    """Maps of the wall 30 m away behind the car, the car's near face drawn from row ``top_row`` (its
    Gaussians' reach, inside the hull of its returns) and a frame showing the wall (dark) down to
    ``frame_top_row`` and the car (white) below; column 160, the car's middle."""
    rays, _ = _rays(camera)
    distance, normal, fields = _maps(camera)
    face = slice(top_row, _pixel(camera, [7.75, 0.0, 0.4])[0])
    distance[face, 140:181] = 7.75 / rays[face, 140:181, 0]
    normal[face, 140:181] = UP
    fields["open"][face, 140:181] = 1.0
    image = np.full((camera.height, camera.width, 3), 0.2, np.float32)
    image[frame_top_row:] = 0.9
    return rays, distance, normal, fields, image


def test_the_band_a_cars_gaussians_draw_over_its_top_takes_what_the_frame_shows_behind_it():
    # the returns' hull reaches the far edge of the roof (row 92); the frame shows the car's top at
    # row 97 and the wall above it: rows 92-95 are the roof's Gaussians over the wall
    camera = _camera(1.6)
    assert _pixel(camera, [12.25, 0.0, 1.5])[0] == 92
    rays, distance, normal, fields, image = _spilled_roof(camera, 92, 97)
    box_shells(_surfaces(), 0, camera, rays, camera.center, distance, normal, fields, np.zeros(distance.shape, bool),
               image=image)
    assert np.all(distance[92:96, 150:171] == 30.0) and np.all(fields["open"][92:96, 150:171] == 0.0)
    np.testing.assert_allclose(normal[92:96, 150:171], np.broadcast_to([-1.0, 0.0, 0.0], (4, 21, 3)), atol=1e-6)
    # the car the frame shows keeps its surface
    assert np.all(distance[98:110, 150:171] < 9.0) and np.all(fields["open"][98:110, 150:171] == 1.0)


@pytest.mark.parametrize("frame_top_row", [92, 180])
def test_a_cars_top_is_kept_where_the_frame_shows_it_or_shows_no_edge_below_it(frame_top_row):
    # the frame's edge at the maps' top (the car is where they put it), or none within reach below
    # it (a car as dark as what lies behind it): the maps stay as the shells leave them
    camera = _camera(1.6)
    rays, distance, normal, fields, image = _spilled_roof(camera, 92, frame_top_row)
    without = [a.copy() for a in (distance, normal, fields["open"])]
    box_shells(_surfaces(), 0, camera, rays, camera.center, *without[:2], {**fields, "open": without[2]},
               np.zeros(distance.shape, bool))
    box_shells(_surfaces(), 0, camera, rays, camera.center, distance, normal, fields, np.zeros(distance.shape, bool),
               image=image)
    np.testing.assert_array_equal(distance, without[0])
    np.testing.assert_array_equal(fields["open"], without[2])


def _spilled_sides(camera, frame_columns):
    """Maps of the wall 30 m away behind the car, the car's near face drawn over the columns of the
    hull of its returns (125-195), and a frame showing the car (white) over ``frame_columns`` and the
    wall (dark) beside it."""
    rays, _ = _rays(camera)
    distance, normal, fields = _maps(camera)
    rows = slice(_pixel(camera, [7.75, 0.0, 1.5])[0] + 1, _pixel(camera, [7.75, 0.0, 0.4])[0])
    distance[rows, 126:195] = 7.75 / rays[rows, 126:195, 0]
    normal[rows, 126:195] = UP
    fields["open"][rows, 126:195] = 1.0
    image = np.full((camera.height, camera.width, 3), 0.2, np.float32)
    image[:, frame_columns] = 0.9
    return rays, distance, normal, fields, image, rows


def test_the_bands_a_cars_gaussians_draw_beside_its_sides_take_what_the_frame_shows_there():
    # the maps put the car's face over columns 126-194 (its surfels' reach, inside the hull of its
    # returns); the frame shows the car over 131-189 and the wall beside it: the bands on either
    # side are the wall's, the car the frame shows keeps its face
    camera = _camera(1.6)
    assert _pixel(camera, [7.75, 0.9, 1.0])[1] <= 126 and _pixel(camera, [7.75, -0.9, 1.0])[1] >= 194
    rays, distance, normal, fields, image, rows = _spilled_sides(camera, slice(131, 190))
    box_shells(_surfaces(), 0, camera, rays, camera.center, distance, normal, fields, np.zeros(distance.shape, bool),
               image=image)
    middle = slice(rows.start + 3, rows.stop - 3)
    for band in (slice(126, 131), slice(190, 195)):
        assert np.all(distance[middle, band] == 30.0) and np.all(fields["open"][middle, band] == 0.0)
    assert np.all(distance[middle, 133:188] < 9.0) and np.all(fields["open"][middle, 133:188] == 1.0)


@pytest.mark.parametrize("run", [3, 10])
def test_a_short_run_of_rows_without_a_band_between_two_with_one_takes_theirs_a_longer_run_keeps_its_own(run):
    # the frame shows the car out to the hull's left edge (column 126) on ``run`` rows and over
    # 131-189 elsewhere: on 3 rows (under the 2 x 2 rows the closing spans at 180 rows) the row's own
    # search stopped short, and the band of the rows on either side runs on over it (a taillight's
    # step inside the car); 10 rows are the frame's own outline (a mirror), and keep the car's face
    camera = _camera(1.6)
    rays, distance, normal, fields, image, rows = _spilled_sides(camera, slice(131, 190))
    assert rows.start < 100 and rows.stop > 130  # every row read below lies on the car's face
    image[110:110 + run, 126:131] = 0.9
    box_shells(_surfaces(), 0, camera, rays, camera.center, distance, normal, fields, np.zeros(distance.shape, bool),
               image=image)
    assert np.all(distance[100:106, 126:131] == 30.0) and np.all(distance[124:130, 126:131] == 30.0)
    if run == 3:
        assert np.all(distance[110:113, 126:131] == 30.0) and np.all(fields["open"][110:113, 126:131] == 0.0)
    else:
        inner = slice(111, 110 + run - 1)
        assert np.all(distance[inner, 126:131] < 9.0) and np.all(fields["open"][inner, 126:131] == 1.0)


def test_a_cars_sides_are_kept_where_the_frame_shows_them_there():
    camera = _camera(1.6)
    rays, distance, normal, fields, image, rows = _spilled_sides(camera, slice(126, 195))
    without = [a.copy() for a in (distance, normal, fields["open"])]
    box_shells(_surfaces(), 0, camera, rays, camera.center, *without[:2], {**fields, "open": without[2]},
               np.zeros(distance.shape, bool))
    box_shells(_surfaces(), 0, camera, rays, camera.center, distance, normal, fields, np.zeros(distance.shape, bool),
               image=image)
    np.testing.assert_array_equal(distance[rows], without[0][rows])
    np.testing.assert_array_equal(fields["open"][rows], without[2][rows])


def _beside_camera():
    """A camera 1.8 m up and a parked car's box beside it, its rear half behind the image plane."""
    camera = _camera(1.8)
    box = np.eye(4)
    box[:3, 3] = [1.5, -2.0, 0.75]
    return camera, box


def test_a_car_beside_the_camera_seen_by_enough_returns_gets_its_hulls_shell():
    camera, box = _beside_camera()
    rays, _ = _rays(camera)
    surfaces = _surfaces(box, (13, 7, 7))
    cloud, _ = surfaces.at_frame(0)
    assert np.count_nonzero(cloud.means[:, 0] > 0.1) >= 100  # camera depth is world x here
    distance, normal, fields = _maps(camera)
    changed = box_shells(surfaces, 0, camera, rays, camera.center, distance, normal, fields,
                          np.zeros(distance.shape, bool))
    pixel = _pixel(camera, [2.5, -1.15, 1.2])  # the near side, the ray then through the glasshouse
    assert changed[pixel] and distance[pixel] < 30.0


def test_a_car_in_the_lidars_blind_zone_is_its_box_only_where_the_lidar_saw_nothing():
    # the lidar's blind zone leaves a few returns of a car beside the camera in front of it: their
    # hull would be a sliver of the car, so the box (cut at the near plane) outlines it, and stands
    # for it only where the lidar saw no surface off the car through it
    camera, box = _beside_camera()
    rays, _ = _rays(camera)
    surfaces = _surfaces(box, (4, 3, 3))
    cloud, _ = surfaces.at_frame(0)
    assert 3 <= np.count_nonzero(cloud.means[:, 0] > 0.1) < 100
    distance, normal, fields = _maps(camera)
    side = _pixel(camera, [2.5, -1.1, 1.2])  # the near side, the ray then through the glasshouse
    wall = _pixel(camera, [2.5, -1.1, 1.45])  # the same side near the roof, where the lidar saw the wall
    assert wall[0] < side[0]
    distance[side[0] - 10:] = np.inf  # the rows the lidar did not reach
    fields["ground"][:] = 1.0
    changed = box_shells(surfaces, 0, camera, rays, camera.center, distance, normal, fields,
                          np.zeros(distance.shape, bool))
    assert changed[side] and fields["ground"][side] == 0.0
    ray = rays[side]
    entry = (-2.0 + 0.9 * _CABIN_SHARE[1]) / ray[1]  # the glasshouse's near side, 0.9 of the box's width
    assert distance[side] == pytest.approx(entry, rel=1e-6)
    # the face stands for the car upright, facing the camera: no snow settles on it
    assert normal[side] @ UP == pytest.approx(0.0, abs=1e-6) and normal[side] @ ray < 0.0
    np.testing.assert_allclose(np.linalg.norm(normal[changed], axis=1), 1.0, atol=1e-5)
    assert np.all(np.abs(normal[changed] @ UP.astype(np.float32)) < 1e-5)
    assert not changed[wall] and distance[wall] == 30.0
    # nothing the lidar saw beyond the box is taken
    assert not np.any(changed & np.isfinite(distance) & (distance >= 30.0))


def test_the_outline_of_a_box_cut_at_the_near_plane_is_the_hull_of_its_points_in_front():
    # the slow twin: points filling the box, those more than 0.1 m in front of the camera projected;
    # their hull, inside a window of the image, against the hull of the outline's vertices
    rng = np.random.default_rng(5)
    camera, box = _beside_camera()
    w2c, K = np.asarray(camera.world_to_camera, np.float64), np.asarray(camera.K, np.float64)
    window = np.float32([[-320, -180], [640, -180], [640, 360], [-320, 360]])
    for yaw in (0.0, 0.4, -1.1):
        T = box.copy()
        T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
        corners = (_CUBE * SIZE / 2) @ T[:3, :3].T + T[:3, 3]
        assert np.any(corners[:, 0] <= 0.1) and np.any(corners[:, 0] > 0.1)  # it straddles the plane
        outline = _clipped_box_outline(corners, w2c, K)
        local = rng.uniform(-1, 1, (400_000, 3))
        local[np.arange(len(local)), rng.integers(0, 3, len(local))] = rng.choice([-1.0, 1.0], len(local))  # faces
        cam = (local * SIZE / 2 @ T[:3, :3].T + T[:3, 3]) @ w2c[:3, :3].T + w2c[:3, 3]
        cam = cam[cam[:, 2] > 0.1]
        uv = np.stack([K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2], K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]], 1)
        areas = []
        for points in (outline, uv):
            hull = cv2.convexHull(np.clip(points, -1e5, 1e5).astype(np.float32))
            area, _ = cv2.intersectConvexConvex(hull, window)
            areas.append(area)
        assert areas[1] > 1000.0 and areas[1] <= areas[0] * (1 + 1e-6)
        assert areas[1] == pytest.approx(areas[0], rel=0.01)


def _old_box_skip(T, half, w2c, K, width, height, rng):
    """The per-point skip of a box (the slow twin): points filling the box (its corners among them)
    in front of the camera by over 0.1 m, fewer than 3, or all past one edge of the image."""
    local = np.concatenate([rng.uniform(-1, 1, (4000, 3)), np.array(np.meshgrid(*[[-1.0, 1.0]] * 3)).reshape(3, -1).T])
    cam = (local * half @ T[:3, :3].T + T[:3, 3]) @ w2c[:3, :3].T + w2c[:3, 3]
    cam = cam[cam[:, 2] > 0.1]
    if len(cam) < 3:
        return True
    u, v = K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2], K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]
    return bool(u.max() < 0 or u.min() >= width or v.max() < 0 or v.min() >= height)


def test_a_box_is_skipped_by_its_corners_only_where_no_point_of_it_could_be_drawn():
    # the corner test stands for the per-point test of every point of the box: it may keep a box
    # whose points all miss (a box straddling the camera's plane), never skip one that shows
    rng = np.random.default_rng(3)
    camera = _camera(1.6)
    w2c, K = np.asarray(camera.world_to_camera, np.float64), np.asarray(camera.K, np.float64)
    poses, halves = np.tile(np.eye(4), (300, 1, 1)), rng.uniform(0.3, 3.0, (300, 3))
    for T in poses:
        yaw = rng.uniform(0, 2 * np.pi)
        T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
        T[:3, 3] = [rng.uniform(-40, 40), rng.uniform(-40, 40), rng.uniform(0, 2)]
    poses[:3, :3, 3] = [[0.0, 0.0, 1.6], [0.05, 0.0, 1.55], [-0.5, 0.2, 1.6]]  # around the camera itself
    fast = _boxes_miss_view(poses, halves, w2c, K, camera.width, camera.height)  # every box at once
    slow = np.array([_old_box_skip(T, half, w2c, K, camera.width, camera.height, rng)
                     for T, half in zip(poses, halves)])
    assert not np.any(fast & ~slow), f"boxes at {poses[fast & ~slow][:, :3, 3]} that show were skipped"
    # most boxes around a camera with a 56-degree view miss it, and the corners tell nearly all
    assert fast.sum() > 150 and (fast == slow).sum() > 280


def test_a_frames_rays_turned_from_the_cameras_are_its_view_directions():
    # the slow twin: view_directions of the pose, normalised after the turn; equal to float32 rounding
    camera = _camera(1.6)
    for yaw in (0.0, 0.7, -2.9):
        c2w = np.array(camera.camera_to_world, np.float64)
        turn = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        c2w[:3, :3] = turn @ c2w[:3, :3]
        view = replace(camera, camera_to_world=c2w)
        rays, z_per_m = _rays(view)
        slow = view_directions(c2w, camera.K, camera.width, camera.height).astype(np.float64)
        np.testing.assert_allclose(rays, slow, rtol=0, atol=1.2e-7)
        np.testing.assert_allclose(z_per_m, slow @ c2w[:3, 2], rtol=0, atol=2e-7)
        np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=2e-7)


def _old_mirrored_cloud(surfaces, index, ground_height):
    """The mirrored cloud with every surfel turned per frame (the slow twin of the cached one)."""
    cloud, attrs = surfaces.at_frame(index)
    up = surfaces.up
    keep = attrs[:, 3] < 0.5
    means = cloud.means[keep].astype(np.float64)
    h = means @ up - ground_height
    above = h > 0.05
    normals = attrs[keep][above, :3].astype(np.float64)
    return GaussianCloud(means=means[above] - 2.0 * np.outer(h[above], up),
                         quats=quat_from_axis_to(normals - 2.0 * np.outer(normals @ up, up)).astype(np.float32),
                         scales=cloud.scales[keep][above], opacities=cloud.opacities[keep][above],
                         colors=cloud.colors[keep][above])


def test_the_mirrored_cloud_with_its_static_orientations_made_once_is_the_per_frame_one(demo_scene, monkeypatch):
    surfaces = build_surfaces(demo_scene)
    static, static_attrs = surfaces.at_frame(0)
    assert len(static) == len(surfaces.gaussians.static)
    # a frame's moving surfels after the static ones (as at_frame appends them): tilted normals,
    # a third of them ground, some under the mirror
    rng = np.random.default_rng(5)
    n = 500
    attrs = np.zeros((n, static_attrs.shape[1]), np.float32)
    attrs[:, :3] = rng.normal(size=(n, 3))
    attrs[:, :3] /= np.linalg.norm(attrs[:, :3], axis=1, keepdims=True)
    attrs[:, 3] = rng.uniform(size=n) < 1 / 3
    means = np.asarray(static.means)[rng.integers(0, len(static), n)] + rng.normal(0, 1.0, (n, 3)).astype(np.float32)
    movers = GaussianCloud(means=means.astype(np.float32), quats=np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
                           scales=np.full((n, 3), 0.05, np.float32), opacities=np.full(n, 0.9, np.float32),
                           colors=rng.uniform(size=(n, 3)).astype(np.float32))
    frame = (GaussianCloud.concatenate([static, movers]), np.concatenate([static_attrs, attrs]))
    monkeypatch.setattr(surfaces, "at_frame", lambda k: frame)
    keep = static_attrs[:, 3] < 0.5
    up = np.asarray(surfaces.up, np.float64)
    for height in (0.0, 0.4, -0.2):
        fast, slow = _mirrored_cloud(surfaces, 3, height), _old_mirrored_cloud(surfaces, 3, height)
        assert len(slow) > len(static) // 10
        assert len(fast) == len(slow)
        # the cached static rows come sorted by height (a slice above the plane): the slow twin's
        # static rows put in that order (a stable sort), its moving rows as they are
        h = np.asarray(static.means, np.float64)[keep] @ up
        n_static = int(np.sum(h - height > 0.05))
        order = np.concatenate([np.argsort(h[h - height > 0.05], kind="stable"), np.arange(n_static, len(slow))])
        for name in ("quats", "scales", "opacities", "colors"):
            np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name)[order], err_msg=name)
        # mirrored about the plane through the origin, then shifted by twice the plane's height: the
        # same centres up to float32 rounding (1e-5 m at the scene's 100 m)
        np.testing.assert_allclose(fast.means, slow.means[order], rtol=0, atol=1e-5)


def test_a_hull_filled_in_its_spill_region_is_the_hull_filled_on_the_whole_frame():
    # the slow twin: the polygon filled on a frame of its own; hulls inside, across the edges and
    # corners, wholly outside, and degenerate (a point, a segment)
    rng = np.random.default_rng(11)
    h, w = 90, 160
    for trial in range(300):
        n = int(rng.integers(1, 12))
        spread = rng.uniform(0.5, 120)
        pts = rng.normal([rng.uniform(-60, 220), rng.uniform(-40, 130)], spread, (n, 2))
        hull = cv2.convexHull(np.round(pts).astype(np.int32))
        frame = np.zeros((h, w), np.uint8)
        cv2.fillConvexPoly(frame, hull, 1)
        region = _spill_region(hull, h, w)
        if region is None:
            assert not frame.any(), f"trial {trial}: {hull.reshape(-1, 2).tolist()}"
            continue
        x0, y0, x1, y1 = region
        part = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.fillConvexPoly(part, hull - np.array([x0, y0], np.int32), 1)
        drawn = np.zeros_like(frame)
        drawn[y0:y1, x0:x1] = part
        assert np.array_equal(drawn, frame), f"trial {trial}: {hull.reshape(-1, 2).tolist()}"


def _random_street(rng, n_boxes):
    """A camera, parked and turned boxes around it with returns over their surfaces, and lidar maps
    that see through some of them, stop on others and miss the rest (inf)."""
    camera = _camera(1.7)
    rays, _ = _rays(camera)
    boxes, clouds = [], []
    for _ in range(n_boxes):
        size = rng.uniform([3.5, 1.6, 1.3], [5.0, 2.0, 1.9])
        yaw = rng.uniform(-np.pi, np.pi)
        pose = np.eye(4)
        pose[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
        pose[:3, 3] = [rng.uniform(4.0, 30.0), rng.uniform(-8.0, 8.0), size[2] / 2]
        g = rng.uniform(-1.0, 1.0, (400, 3))
        g[np.arange(400), rng.integers(0, 3, 400)] = rng.choice([-1.0, 1.0], 400)  # on a face
        clouds.append((g * size / 2) @ pose[:3, :3].T + pose[:3, 3])
        boxes.append((pose, size))
    pts = np.concatenate(clouds)
    cloud = GaussianCloud(means=pts.astype(np.float32), quats=np.tile(np.float32([1, 0, 0, 0]), (len(pts), 1)),
                          scales=np.full((len(pts), 3), 0.1, np.float32), opacities=np.ones(len(pts), np.float32),
                          colors=np.zeros((len(pts), 3), np.float32))
    surfaces = SimpleNamespace(up=UP, boxes_at=lambda k: boxes, at_frame=lambda k: (cloud, None), analysis=None,
                               inside_boxes=lambda k, poses, halves: [pts[in_box((pts - T[:3, 3]) @ T[:3, :3], h)]
                                                                      for T, h in zip(poses, halves)])
    h, w = camera.height, camera.width
    distance = rng.uniform(2.0, 40.0, (h, w))
    distance[rng.random((h, w)) < 0.1] = np.inf
    normal = rng.normal(size=(h, w, 3)).astype(np.float32)
    fields = {k: rng.random((h, w)).astype(np.float32) for k in ("ground", "open", "puddle", "track")}
    sky = rng.random((h, w)) < 0.05
    return surfaces, camera, rays, distance, normal, fields, sky


@pytest.mark.parametrize("seed", range(6))
def test_the_shell_kernel_is_its_numpy_reference(seed):
    # the fast twin against the slow one on streets of several overlapping boxes (each box reads the
    # distances the boxes before it wrote): the same pixels changed, tails and all, and with a frame
    # (blocks of colour) the same bands over the boxes' tops; the same values to float64 rounding
    # (BLAS may fuse the reference's 3 x 3 products)
    pytest.importorskip("numba")
    rng = np.random.default_rng(seed)
    surfaces, camera, rays, distance, normal, fields, sky = _random_street(rng, 12)
    image = cv2.resize(rng.random((18, 32, 3)).astype(np.float32), (camera.width, camera.height),
                       interpolation=cv2.INTER_NEAREST) if seed % 2 else None
    out = {}
    for fast in (True, False):
        d, n, f = distance.copy(), normal.copy(), {k: v.copy() for k, v in fields.items()}
        changed = box_shells(surfaces, 0, camera, rays, camera.center, d, n, f, sky, image=image, fast=fast)
        out[fast] = (changed, d, n, f)
    (c1, d1, n1, f1), (c0, d0, n0, f0) = out[True], out[False]
    assert c0.sum() > 500 and (d0 != distance).sum() > 500  # shells and tails were drawn
    if image is not None:  # and bands, which the maps without a frame keep
        d, n, f = distance.copy(), normal.copy(), {k: v.copy() for k, v in fields.items()}
        box_shells(surfaces, 0, camera, rays, camera.center, d, n, f, sky)
        assert (d != d0).sum() > 20
    np.testing.assert_array_equal(c1, c0)
    np.testing.assert_array_equal(np.isfinite(d1), np.isfinite(d0))
    np.testing.assert_allclose(d1, d0, rtol=1e-12, atol=0)
    np.testing.assert_allclose(n1, n0, rtol=0, atol=1e-6)
    for k in f0:
        np.testing.assert_array_equal(f1[k], f0[k])


def test_the_frames_steps_and_the_mirrored_sides_from_one_transpose_are_the_direct_ones_to_the_bit():
    # the slow twins: each step the root of np.sum over the colour axis of the blurred frame's squared
    # differences, and the mirrored side's steps those of the frame mirrored, then transposed
    # (_side_bands reverses the transposed frame's rows and steps instead); frames of random noise,
    # of blocks and with an odd size
    rng = np.random.default_rng(11)
    for h, w in ((270, 480), (37, 61)):
        for frame in (rng.random((h, w, 3), np.float32),
                      cv2.resize(rng.random((5, 9, 3)).astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)):
            blurred = cv2.GaussianBlur(frame, (3, 3), 0.8)
            slow = np.zeros((h, w), np.float32)
            slow[1:] = np.sqrt(np.sum(np.square(blurred[1:] - blurred[:-1]), axis=-1))
            np.testing.assert_array_equal(_vertical_steps(frame), slow)
            turned = np.ascontiguousarray(frame.transpose(1, 0, 2))
            steps = _vertical_steps(turned)
            mirrored = _vertical_steps(np.ascontiguousarray(frame[:, ::-1].transpose(1, 0, 2)))
            np.testing.assert_array_equal(np.concatenate([steps[:1], steps[:0:-1]]), mirrored)
            np.testing.assert_array_equal(np.ascontiguousarray(turned[::-1]),
                                          np.ascontiguousarray(frame[:, ::-1].transpose(1, 0, 2)))


def test_the_slab_interval_and_the_box_test_by_columns_are_the_row_reductions():
    # the slow twins: np.nanmax / np.nanmin over each row's three slabs, np.all over its three
    # axes; rays parallel to a slab (a zero component: inf or NaN parameters) and origins on a
    # slab's plane included. Equal to the bit (a max, a min and comparisons round nothing)
    rng = np.random.default_rng(5)
    half = np.array([2.2, 0.9, 0.75])
    for origin in (rng.normal(0.0, 4.0, 3), np.array([2.2, 0.0, -5.0]), np.array([0.0, 0.9, 0.75])):
        dirs = rng.normal(size=(4000, 3))
        dirs[rng.uniform(size=dirs.shape) < 0.15] = 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - origin) / dirs, (half - origin) / dirs
            slow_in = np.nanmax(np.minimum(t1, t2), axis=1)
            slow_out = np.nanmin(np.maximum(t1, t2), axis=1)
            fast_in, fast_out = _slab_interval(origin, dirs, -half, half)
        np.testing.assert_array_equal(fast_in, slow_in)
        np.testing.assert_array_equal(fast_out, slow_out)
    points = rng.uniform(-3.0, 3.0, (4000, 3))
    points[:10] = half  # on the box's corner: inside
    np.testing.assert_array_equal(in_box(points, half), np.all(np.abs(points) <= half, axis=1))


def _bilinear_slow(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The slow twin of OpenCV's INTER_LINEAR resize of a 2D float image to ``size`` (W, H), pixel
    by pixel: centres aligned (x_src = (x + 0.5) w / W - 0.5), the edge pixels repeated."""
    h, w = image.shape
    out = np.zeros((size[1], size[0]), np.float64)
    for y in range(size[1]):
        sy = min(max((y + 0.5) * h / size[1] - 0.5, 0.0), h - 1.0)
        y0 = int(np.floor(sy))
        y1, fy = min(y0 + 1, h - 1), sy - y0
        for x in range(size[0]):
            sx = min(max((x + 0.5) * w / size[0] - 0.5, 0.0), w - 1.0)
            x0 = int(np.floor(sx))
            x1, fx = min(x0 + 1, w - 1), sx - x0
            out[y, x] = ((1 - fy) * ((1 - fx) * image[y0, x0] + fx * image[y0, x1])
                         + fy * ((1 - fx) * image[y1, x0] + fx * image[y1, x1]))
    return out


def test_the_mirrors_distance_from_one_dummy_channel_is_the_coloured_render_resized_by_its_cover(demo_scene):
    # the slow twin: the mirrored surfaces rendered with their colours, as the reflection's image
    # was (the compositing weights and the depth do not depend on the channels), resized up by a
    # normalised convolution written out pixel by pixel: each pixel's covered neighbours' distances
    # weighted by their bilinear weights, covered where those weights hold at least one half
    surfaces = build_surfaces(demo_scene)
    cam = demo_scene.frames[4].camera
    height = float(surfaces.ground_height(np.asarray(cam.center, np.float64)[None])[0])
    fast = mirror_distance(surfaces, 4, cam, height)
    w, h = int(cam.width), int(cam.height)
    half = replace(cam, K=np.diag([0.5, 0.5, 1.0]) @ np.asarray(cam.K, np.float64), width=w // 2, height=h // 2)
    half = replace(half, K=np.diag([half.width / (0.5 * w), half.height / (0.5 * h), 1.0]) @ half.K)
    sub = _mirrored_cloud(surfaces, 4, height)
    _, alpha, depth = _rasterize(sub, np.asarray(sub.colors, np.float32), half)
    _, z_per_m = _rays(half)
    covered = alpha > _COVERED
    distance = np.where(covered, depth / np.maximum(z_per_m, 1e-9), 0.0)
    weight = _bilinear_slow(covered.astype(np.float64), (w, h))
    slow = np.where(weight >= 0.5, _bilinear_slow(distance, (w, h)) / np.maximum(weight, 1e-6), np.inf)
    assert np.isfinite(fast).mean() > 0.2 and np.isinf(fast).any()
    decided = np.abs(weight - 0.5) > 1e-5  # a weight of one half to the rounding: either side holds
    np.testing.assert_array_equal(np.isfinite(fast)[decided], np.isfinite(slow)[decided])
    both = np.isfinite(fast) & np.isfinite(slow)
    np.testing.assert_allclose(fast[both], slow[both], rtol=1e-5)
    # no distance between two covered ones' that none of them has: the sentinel's mixing is gone
    near, far = float(distance[covered].min()), float(distance[covered].max())
    assert np.all((fast[np.isfinite(fast)] >= near * (1 - 1e-5)) & (fast[np.isfinite(fast)] <= far * (1 + 1e-5)))


@pytest.mark.parametrize("sigma", [0.7, 1.5, 6.0, 6.1875, 12.0, 24.0])
def test_a_band_of_rows_of_a_blur_is_those_rows_of_the_whole_images_blur_to_the_bit(sigma):
    # the slow twin: _gaussian_blur of the whole image, sliced; bands at the top and bottom edges, in
    # the middle, of one row and of every row, on a random image of four channels
    rng = np.random.default_rng(3)
    image = rng.uniform(size=(270, 480, 4)).astype(np.float32)
    whole = _gaussian_blur(image, sigma)
    for band in (slice(0, 40), slice(130, 270), slice(100, 180), slice(150, 151), slice(0, 270)):
        np.testing.assert_array_equal(_gaussian_blur(image, sigma, rows=band), whole[band])


@pytest.mark.parametrize("sigma", [4.0, 12.0, 18.0, 24.0, 40.0])
def test_a_wide_blur_on_a_quarter_size_image_is_the_full_size_blur(sigma):
    # the slow twin: OpenCV's blur at full size. A normalised convolution's inputs: a sparse weight
    # (a reflection seen at scattered places) and colours on it
    rng = np.random.default_rng(7)
    h, w = 270, 480
    weight = (cv2.GaussianBlur(rng.uniform(size=(h, w)).astype(np.float32), (0, 0), 6) > 0.5).astype(np.float32)
    colour = cv2.GaussianBlur(rng.uniform(size=(h, w, 3)).astype(np.float32), (0, 0), 3)
    stacked = np.dstack([colour * weight[..., None], weight])
    fast, slow = _gaussian_blur(stacked, sigma), cv2.GaussianBlur(stacked, (0, 0), sigma)
    assert fast.shape == slow.shape and fast.dtype == np.float32
    if sigma <= 12.0:
        np.testing.assert_array_equal(fast, slow)
        return
    # away from the frame's edges (the border rules differ), within 1 % of the range; the normalised
    # colour (what the fill uses) likewise where the weight is not vanishing
    inner = (slice(int(2 * sigma), h - int(2 * sigma)), slice(int(2 * sigma), w - int(2 * sigma)))
    assert np.abs(fast - slow)[inner].max() < 0.01
    ok = slow[..., 3][inner] > 0.05
    ratio_fast = fast[..., :3][inner][ok] / fast[..., 3][inner][ok, None]
    ratio_slow = slow[..., :3][inner][ok] / slow[..., 3][inner][ok, None]
    assert np.abs(ratio_fast - ratio_slow).max() < 0.01


def test_the_tails_take_a_source_pixel_as_near_as_the_brute_force_nearest(rng):
    # the labelled distance transform (a 5x5 mask, not exact Euclidean) against every source pixel
    # tried for every tail pixel: the pixel it picks lies at most 2 % plus half a pixel farther
    h, w = 60, 80
    source = rng.random((h, w)) < 0.05
    tails = ~source & (rng.random((h, w)) < 0.3)
    rows, cols = np.mgrid[0:h, 0:w]
    distance = (rows * w + cols).astype(np.float64)  # a pixel's own index: which source it took
    normal = np.zeros((h, w, 3), np.float32)
    fields = {"ground": np.zeros((h, w), np.float32)}
    _replace_tails(tails, source, distance, normal, fields)
    sr, sc = np.nonzero(source)
    for r, c in zip(*np.nonzero(tails)):
        taken = np.divmod(int(distance[r, c]), w)
        assert source[taken]
        best = np.sqrt(((sr - r) ** 2 + (sc - c) ** 2).min())
        assert np.hypot(taken[0] - r, taken[1] - c) <= 1.02 * best + 0.5
    untouched = ~tails
    assert np.array_equal(distance[untouched], (rows * w + cols)[untouched])


@pytest.mark.parametrize("fields", [(), ("ground", "open", "track"), ("puddle",), FIELDS])
def test_maps_of_some_fields_are_the_maps_of_all_to_the_bit_the_others_nan(demo_scene, fields):
    # the slow twin: every attribute composited; the fewer channels change no sum of the others
    surfaces = build_surfaces(demo_scene)
    cam = demo_scene.frames[4].camera
    sky = np.zeros((int(cam.height), int(cam.width)), bool)
    sky[:10] = True
    full = surface_maps(surfaces, 4, cam, sky)
    part = surface_maps(surfaces, 4, cam, sky, fields=fields)
    assert full.fields == FIELDS and part.fields == tuple(f for f in FIELDS if f in fields)
    for name in ("normal", "distance", "sky", "sky_alpha", "covered", "rays"):
        np.testing.assert_array_equal(getattr(part, name), getattr(full, name), err_msg=name)
    assert part.ground_height == full.ground_height
    for name in FIELDS:
        if name in fields:
            np.testing.assert_array_equal(getattr(part, name), getattr(full, name), err_msg=name)
            assert np.isfinite(getattr(part, name)).all()
        else:
            assert np.isnan(getattr(part, name)).all(), name
    # the demo street's maps hold ground and open ground somewhere: the comparison is not of zeros
    assert full.ground.max() > 0.5 and full.open.max() > 0.5


def test_a_turnable_surfel_is_turned_toward_the_view_that_sees_it_and_no_other():
    center = np.array([0.0, 0.0, 1.5])
    # the top of a crown 20 m ahead, 6 m up, its normal turned down toward a camera below it; a
    # wall facing the camera; a ground surfel tipped 20 degrees away from a ray that grazes it (not
    # turnable), and the crown's surfel again, not turnable (foliage)
    means = np.array([[20.0, 0.0, 6.0], [15.0, 0.0, 2.0], [25.0, 0.0, 0.0], [20.0, 0.0, 6.0]])
    normals = np.array([[0.6, 0.0, -0.8], [-1.0, 0.0, 0.0], [np.sin(np.radians(20)), 0.0, np.cos(np.radians(20))],
                        [0.6, 0.0, -0.8]])
    turned = facing_view(means, normals, np.array([True, True, False, False]), center)
    np.testing.assert_allclose(turned, [[-0.6, 0.0, 0.8], normals[1], normals[2], normals[3]], atol=1e-7)
    assert turned.dtype == np.float32


def test_the_maps_are_the_same_whichever_way_the_turnable_surfels_were_turned(demo_scene, monkeypatch):
    # the slow twin of facing_view in the maps: every turnable surfel reversed changes no pixel
    surfaces = build_surfaces(demo_scene)
    assert surfaces.view_turned is not None and surfaces.view_turned.mean() > 0.1
    cam = demo_scene.frames[4].camera
    sky = np.zeros((int(cam.height), int(cam.width)), bool)
    sky[:10] = True
    maps = surface_maps(surfaces, 4, cam, sky)
    at_frame = surfaces.at_frame

    def reversed_normals(index):
        cloud, attrs = at_frame(index)
        attrs = attrs.copy()
        attrs[:len(surfaces.view_turned)][surfaces.view_turned, :3] *= -1.0
        return cloud, attrs

    monkeypatch.setattr(surfaces, "at_frame", reversed_normals)
    turned = surface_maps(surfaces, 4, cam, sky)
    np.testing.assert_array_equal(turned.normal, maps.normal)
    assert not np.array_equal(reversed_normals(4)[1], at_frame(4)[1])


def test_the_ground_the_lidar_missed_reads_the_grounds_openness_field(demo_scene, monkeypatch):
    # the road below the lidar's lowest beam and a trunk's shadow on the pavement are filled with
    # the ground plane: their openness is the field the ground Gaussians spread (under a crown, its
    # half), not the open sky that striped the snow under a street tree (docs/findings.md)
    surfaces = build_surfaces(demo_scene)
    assert surfaces.open_ground is not None
    cam = demo_scene.frames[4].camera
    sky = np.zeros((int(cam.height), int(cam.width)), bool)
    sky[:10] = True
    plain = surface_maps(surfaces, 4, cam, sky)
    filled = ~plain.covered & ~plain.sky & (plain.ground == 1.0)
    assert filled.sum() > 100, filled.sum()
    sheltered = OpenGround(origin=np.array([-2e4, -2e4]), cell_m=1e4, field=np.full((4, 4), 0.3, np.float32))
    monkeypatch.setattr(surfaces, "open_ground", sheltered)
    under = surface_maps(surfaces, 4, cam, sky)
    np.testing.assert_allclose(under.open[filled], 0.3, atol=1e-6)
    np.testing.assert_array_equal(under.open[~filled], plain.open[~filled])  # the lidar's own ground as it was


def test_maps_refuse_a_field_they_do_not_know(demo_scene):
    surfaces = build_surfaces(demo_scene)
    cam = demo_scene.frames[0].camera
    with pytest.raises(ValueError, match="wetness"):
        surface_maps(surfaces, 0, cam, np.zeros((int(cam.height), int(cam.width)), bool), fields=("wetness",))


def _pitched_camera(degrees):
    """:func:`_camera` 1.7 m up, pitched down by ``degrees``: the frame spans 16.7 degrees above and
    below its axis, so the sky's reflection of the steeper road leaves the frame."""
    s, c = np.sin(np.radians(degrees)), np.cos(np.radians(degrees))
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[0.0, -s, c], [-1.0, 0.0, 0.0], [0.0, -c, -s]])
    c2w[:3, 3] = [0.0, 0.0, 1.7]
    return replace(_camera(1.7), camera_to_world=c2w)


def _reflecting_street(rng, camera):
    """Maps of a view over a ground plane near z = 0: the camera's distances (some sky, inf) and the
    reflected paths' lengths, past the plane's point (a surface met), short of it, or none (inf)."""
    rays, _ = _rays(camera)
    h, w = camera.height, camera.width
    distance = rng.uniform(2.0, 60.0, (h, w))
    distance[rng.random((h, w)) < 0.1] = np.inf
    mirror = rng.uniform(1.0, 80.0, (h, w)).astype(np.float32)
    mirror[rng.random((h, w)) < 0.2] = np.inf
    maps = SimpleNamespace(rays=rays.astype(np.float32), distance=distance.astype(np.float32),
                           ground_height=float(rng.uniform(-0.2, 0.2)))
    return maps, mirror


@pytest.mark.parametrize("seed", range(3))
def test_the_reflection_lookup_kernel_is_its_numpy_reference(seed):
    # the fast twin against the slow one, pixel by pixel: the same state everywhere (each of the
    # four drawn), the same looked-up positions to float32 rounding, and screen_reflection's
    # image and known pixels the same whichever looked them up
    pytest.importorskip("numba")
    from wcbench.reference_model._numba_backend import load_numba_kernels

    rng = np.random.default_rng(seed)
    camera = _pitched_camera(10.0)
    maps, mirror = _reflecting_street(rng, camera)
    x0, y0, s0 = _reflection_lookup(camera, maps, mirror, UP)
    x1, y1, s1 = _reflection_lookup_fast(load_numba_kernels("appearance.reflection_kernels"), camera, maps,
                                         mirror, UP)
    for state in (NO_HIT, HIT_SEEN, HIT_SKY, HIT_FILLED):
        assert (s0 == state).sum() > 100, state
    np.testing.assert_array_equal(s1, s0)
    np.testing.assert_allclose(x1, x0, rtol=0, atol=1e-4)
    np.testing.assert_allclose(y1, y0, rtol=0, atol=1e-4)
    source = rng.random((camera.height, camera.width, 3)).astype(np.float32)
    sky = np.broadcast_to(np.float32([0.7, 0.75, 0.8]), source.shape)
    (a, seen_a), (b, seen_b) = (screen_reflection(source, camera, maps, mirror, up=UP, sky=sky, fast=fast)
                                for fast in (True, False))
    np.testing.assert_array_equal(seen_a, seen_b)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-5)


def test_the_reflection_falls_back_to_the_numpy_reference_when_its_kernel_cannot_be_imported(monkeypatch):
    # a broken numba must cost speed, not the editor: screen_reflection's fast path looks up with
    # the reference, to the bit, and the failure is remembered
    from wcbench.reference_model import _numba_backend

    rng = np.random.default_rng(0)
    camera = _pitched_camera(10.0)
    maps, mirror = _reflecting_street(rng, camera)
    source = rng.random((camera.height, camera.width, 3)).astype(np.float32)
    expected = screen_reflection(source, camera, maps, mirror, up=UP, fast=False)
    monkeypatch.setattr(_numba_backend, "_loaded", {})
    monkeypatch.setattr(_numba_backend, "_failed", {})
    monkeypatch.setitem(sys.modules, "wcbench.reference_model.appearance.reflection_kernels", None)
    got = screen_reflection(source, camera, maps, mirror, up=UP, fast=True)
    np.testing.assert_array_equal(got[0], expected[0])
    np.testing.assert_array_equal(got[1], expected[1])
    assert "halted" in str(_numba_backend.numba_error("appearance.reflection_kernels"))


def test_the_editor_imports_without_numba():
    # numba hidden in a fresh interpreter: the editor's modules import (every kernel is loaded
    # lazily), and the reflection kernel reports why it did not load
    code = (
        "import sys; sys.modules['numba'] = None\n"
        "import wcbench.reference_model.appearance.editor\n"
        "from wcbench.reference_model._numba_backend import load_numba_kernels, numba_error\n"
        "assert load_numba_kernels('appearance.reflection_kernels') is None\n"
        "print(numba_error('appearance.reflection_kernels'))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "numba" in done.stdout


def test_a_reflected_ray_that_meets_no_surface_sees_the_sky_and_one_that_meets_a_hidden_one_is_filled():
    # the reference's states by their definitions: above the horizon no hit; a reflected ray
    # toward the sky (inf) that leaves the frame takes the sky; one meeting a surface the camera's
    # own map hides (the camera sees 1 m everywhere) is filled
    camera = _pitched_camera(10.0)
    rays, _ = _rays(camera)
    h, w = camera.height, camera.width
    maps = SimpleNamespace(rays=rays.astype(np.float32), distance=np.full((h, w), 1.0, np.float32),
                           ground_height=0.0)
    _, _, state = _reflection_lookup(camera, maps, np.full((h, w), np.inf, np.float32), UP)
    below = rays @ UP < -1e-3
    assert np.all(state[~below] == NO_HIT)
    # steeper than the frame's top (6.7 degrees up): the mirrored ray looks up past it
    near_road = below & (rays @ UP < -np.sin(np.radians(8.0)))
    assert near_road.sum() > 100 and np.all(state[near_road] == HIT_SKY)
    _, _, state = _reflection_lookup(camera, maps, np.full((h, w), 50.0, np.float32), UP)
    far_enough = below & (1.7 / np.maximum(-(rays @ UP), 1e-9) < 40.0)  # the plane's point short of 50 m
    assert far_enough.sum() > 100 and np.all(state[far_enough] == HIT_FILLED)


def test_a_map_refined_on_a_sharp_edge_of_the_frame_keeps_its_values():
    # a car's dark side against the bright road: a ground map that is an affine map of the two
    # colours comes back within the filter's regularisation, at any eps up to the snow's 1e-2
    guide = np.empty((24, 24, 3), np.float32)
    guide[:] = [0.6, 0.6, 0.62]
    guide[:, 10:] = [0.12, 0.12, 0.14]
    ground = np.where(np.arange(24) < 10, 1.0, 0.0)[None].repeat(24, 0).astype(np.float32)
    for eps in (1e-3, 1e-2):
        np.testing.assert_allclose(refine(ground, guide, radius=2, eps=eps), ground, atol=0.05)


def test_a_stack_of_maps_is_refined_as_each_alone():
    rng = np.random.default_rng(0)
    guide = rng.random((60, 90, 3)).astype(np.float32)
    a, b = rng.random((60, 90)).astype(np.float32), (rng.random((60, 90)) > 0.5).astype(np.float32)
    both = refine(np.dstack([a, b]), guide, radius=2)
    assert both.shape == (60, 90, 2) and both.dtype == np.float32
    np.testing.assert_array_equal(both[..., 0], refine(a, guide, radius=2))
    np.testing.assert_array_equal(both[..., 1], refine(b, guide, radius=2))


def test_the_glossy_blur_keeps_a_uniform_reflection_and_leaves_what_no_ground_is_near():
    # a normalised convolution: a uniform reflection over the ground stays uniform, and rows far
    # above the ground (beyond the longest blur) keep the sharp image to the bit
    camera = _camera(1.7)
    rays, _ = _rays(camera)
    h, w = camera.height, camera.width
    rng = np.random.default_rng(1)
    weight = np.zeros((h, w), np.float32)
    weight[h // 2 + 10:] = 1.0
    image = rng.random((h, w, 3)).astype(np.float32)
    image[h // 2 + 10:] = [0.2, 0.4, 0.6]
    out = glossy_blur(image, weight, rays.astype(np.float32), up=UP, sigma_px=2.0)
    np.testing.assert_allclose(out[h // 2 + 10:], image[h // 2 + 10:], rtol=0, atol=1e-5)
    # the longest blur (8 times 2 px on rows averaged 8 at a time) reaches 4 of its sigmas and a
    # coarse row above the ground's first row (100): 72 rows, so rows 0-27 never see the ground
    np.testing.assert_array_equal(out[:h // 2 + 10 - 72], image[:h // 2 + 10 - 72])


def test_a_boxs_motion_between_frames_carries_its_pose_at_one_to_its_pose_at_the_other():
    rng = np.random.default_rng(3)
    poses = []
    for yaw, x in ((0.0, 10.0), (0.2, 11.0), (0.5, 12.5)):
        T = np.eye(4)
        T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
        T[:3, 3] = [x, rng.uniform(-2, 2), 0.75]
        poses.append(T)
    moving = (np.array([0, 1, 2]), np.stack(poses), np.tile(SIZE, (3, 1)))
    late = (np.array([2]), np.stack(poses[2:]), SIZE[None])  # annotated at frame 2 only
    motions = _box_motions([moving, late], 2, 0)
    assert len(motions) == 2 and motions[1] is None
    local = rng.uniform(-1, 1, (5, 3)) * SIZE / 2  # points on the object, in its box's frame
    at0 = local @ poses[0][:3, :3].T + poses[0][:3, 3]
    at2 = local @ poses[2][:3, :3].T + poses[2][:3, 3]
    np.testing.assert_allclose(at0 @ motions[0][:3, :3].T + motions[0][:3, 3], at2, atol=1e-12)
    assert len(_box_motions([moving, late], 1, 0)) == 1  # frame 1 shows the moving box only
