"""Completing a distance map with the ground plane and vertical walls, against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from wcbench.reference_model.scene_graph.completion import (
    FILL_GROUND,
    FILL_KNOWN,
    FILL_SKY,
    FILL_WALL,
    Facades,
    bridge_rings,
    closing_among,
    complete_distance,
    fit_facades,
    ground_height_below,
    smooth_walls,
)
from wcbench.reference_model.scene_graph.footprints import fill_footprints

#: The level camera's optical axis (world +x).
FORWARD = np.array([1.0, 0.0, 0.0])


def _level_camera(h: int = 40, w: int = 60, f: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """Unit world rays of a level camera looking along +x, z up (OpenCV: x right = -y world,
    y down = -z world, z forward = +x world), and each ray's camera z."""
    xs = (np.arange(w) + 0.5 - w / 2) / f
    ys = (np.arange(h) + 0.5 - h / 2) / f
    cam = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None], np.ones((h, w))), -1)
    norm = np.linalg.norm(cam, axis=-1)
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera -> world
    return (cam / norm[..., None]) @ R.T, 1.0 / norm


def test_ground_pixels_meet_the_plane_and_walls_keep_the_camera_depth_of_their_base():
    rays, z_per_m = _level_camera()
    h, w = z_per_m.shape
    up, center = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.6])
    known = np.zeros((h, w), bool)
    distance = np.zeros((h, w))
    # a facade 12 m ahead seen in rows 18-24 of columns 10-19 (camera depth 12 m)
    known[18:25, 10:20] = True
    distance[18:25, 10:20] = 12.0 / z_per_m[18:25, 10:20]
    sky = np.zeros((h, w), bool)
    sky[:3, 40:] = True
    out, kind, source = complete_distance(distance, known, sky, rays, center, up, 0.0, forward=FORWARD)
    below = rays[..., 2] < -1e-3
    ground = below & ~known
    np.testing.assert_allclose(out[ground], 1.6 / -rays[ground][:, 2], rtol=1e-12)
    assert np.all(kind[ground] == FILL_GROUND) and np.all(kind[known] == FILL_KNOWN)
    # above the facade: the same camera depth (a vertical plane seen by a level camera)
    wall = kind == FILL_WALL
    assert wall[:18, 10:20].all()
    np.testing.assert_allclose((out * z_per_m)[:18, 10:20], 12.0, rtol=1e-9)
    assert np.all(source[:18, 10:20] == 18)
    # above the horizon where only the ground lies below: a wall where the ground meets the horizon
    # (the first row below it, row 20, is 1.6 m x 30 px / 0.5 px = 96 m deep)
    assert np.all(kind[3:20, 40:] == FILL_WALL)
    np.testing.assert_allclose((out * z_per_m)[3:20, 40:], 96.0, rtol=1e-9)
    assert np.all(kind[sky] == FILL_SKY) and np.all(np.isinf(out[sky]))


def test_a_gap_in_a_canopy_rises_from_the_nearest_known_pixel_below():
    rays, z_per_m = _level_camera()
    h, w = z_per_m.shape
    known = np.zeros((h, w), bool)
    distance = np.full((h, w), np.inf)
    known[2:4, 5] = True  # sparse returns high in a tree, 20 m away
    distance[2:4, 5] = 20.0 / z_per_m[2:4, 5]
    known[15:17, 5] = True  # its lower canopy, 6 m away
    distance[15:17, 5] = 6.0 / z_per_m[15:17, 5]
    # the column's own rule (no horizontal closing: alone in its row, a 1 px column is a thin dip)
    out, kind, _ = complete_distance(distance, known, np.zeros((h, w), bool), rays, np.array([0.0, 0, 1.6]),
                                     np.array([0.0, 0, 1.0]), 0.0, forward=FORWARD, thin_fraction=0.0)
    np.testing.assert_allclose((out * z_per_m)[4:15, 5], 6.0, rtol=1e-9)  # from row 15, not row 3
    np.testing.assert_allclose((out * z_per_m)[:2, 5], 20.0, rtol=1e-9)
    assert np.all(kind[4:15, 5] == FILL_WALL)


def test_a_pole_in_front_of_a_facade_does_not_carry_its_distance_up_the_facade():
    rays, z_per_m = _level_camera(h=40, w=120)
    h, w = z_per_m.shape
    known = np.zeros((h, w), bool)
    distance = np.full((h, w), np.inf)
    known[15:25, 10:110] = True  # a facade 20 m ahead, its top return at row 15
    distance[15:25, 10:110] = 20.0 / z_per_m[15:25, 10:110]
    pole = np.s_[12:25, 50:52]  # a 2 px pole 5 m ahead, its top above the facade's
    known[pole] = True
    distance[pole] = 5.0 / z_per_m[pole]
    sky = np.zeros((h, w), bool)
    args = (sky, rays, np.array([0.0, 0, 1.6]), np.array([0.0, 0, 1.0]), 0.0)
    out, kind, _ = complete_distance(distance, known, *args, forward=FORWARD)  # 1/60 of 120: 2 px each side
    depth = out * z_per_m
    np.testing.assert_allclose(depth[:12, 10:110], 20.0, rtol=1e-9)  # the facade rises above the pole too
    assert np.all(kind[:12, 10:110] == FILL_WALL)
    np.testing.assert_allclose(depth[pole], 5.0, rtol=1e-9)  # what the lidar saw is kept
    # without the closing, the pole's columns carry its 5 m up the facade
    depth = complete_distance(distance, known, *args, forward=FORWARD, thin_fraction=0.0)[0] * z_per_m
    np.testing.assert_allclose(depth[:12, 50:52], 5.0, rtol=1e-9)
    # a wide sign (30 px) is a structure of its own: its distance rises above it
    wide = np.s_[12:25, 40:70]
    known[wide] = True
    distance[wide] = 8.0 / z_per_m[wide]
    depth = complete_distance(distance, known, *args, forward=FORWARD)[0] * z_per_m
    np.testing.assert_allclose(depth[:12, 44:66], 8.0, rtol=1e-9)
    np.testing.assert_allclose(depth[:12, 10:38], 20.0, rtol=1e-9)


@pytest.mark.parametrize("half", [1, 2, 4])
def test_the_closing_among_known_pixels_equals_its_written_out_definition(rng, half):
    h, w = 17, 23
    values = rng.uniform(1.0, 80.0, (h, w))
    mask = rng.random((h, w)) < 0.6

    def window(grid, y, x):
        ys, xs = slice(max(0, y - half), y + half + 1), slice(max(0, x - half), x + half + 1)
        return grid[ys, xs][mask[ys, xs]]

    dilated = np.full((h, w), -np.inf)
    for y, x in zip(*np.nonzero(mask)):
        dilated[y, x] = window(values, y, x).max()
    expected = values.copy()
    for y, x in zip(*np.nonzero(mask)):
        expected[y, x] = window(dilated, y, x).min()
    got = closing_among(values, mask, half)
    np.testing.assert_allclose(got, expected, rtol=1e-6)  # float32 inside
    assert np.array_equal(got[~mask], values[~mask])
    assert np.all(got[mask] >= values[mask] * (1 - 1e-6))  # a closing only fills


def test_ground_height_below_a_camera():
    rng = np.random.default_rng(0)
    ground = np.c_[rng.uniform(-10, 10, (500, 2)), rng.normal(0.0, 0.01, 500)]
    wall = np.c_[rng.uniform(-10, 10, 200), np.full(200, 8.0), rng.uniform(0, 10, 200)]
    points = np.concatenate([ground, wall])
    assert ground_height_below(points, np.array([0.0, 0, 1.7]), np.array([0.0, 0, 1])) == pytest.approx(-0.016,
                                                                                                      abs=0.01)
    # nothing near: a car's camera height below the camera
    assert ground_height_below(points + 100.0, np.array([0.0, 0, 1.7]), np.array([0.0, 0, 1])) == pytest.approx(0.1)


def _wall_points(rng: np.random.Generator, normal: np.ndarray, offset: float, along: tuple[float, float],
                 top_m: float, n: int, noise_m: float = 0.02) -> np.ndarray:
    """``n`` returns on the vertical plane ``normal . x = offset`` (z up), between ``along`` (m
    along its horizontal tangent) and heights 0-``top_m``, with Gaussian noise across it."""
    tangent = np.array([-normal[1], normal[0], 0.0])
    s = rng.uniform(*along, n)
    z = rng.uniform(0.0, top_m, n)
    return offset * normal + s[:, None] * tangent + z[:, None] * [0, 0, 1.0] + rng.normal(0, noise_m, (n, 1)) * normal


def test_fitted_facades_are_the_walls_above_a_cars_height_and_not_the_clutter(rng):
    up = np.array([0.0, 0, 1])
    n1, n2 = np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    walls = np.concatenate([_wall_points(rng, n1, 20.0, (-10.0, 5.0), 9.0, 4000),
                            _wall_points(rng, n2, -12.0, (0.0, 15.0), 9.0, 4000)])
    cars = _wall_points(rng, n2, 6.0, (-5.0, 15.0), 2.0, 3000)  # parked cars' sides: below 2.5 m
    clutter = rng.uniform([-5, -10, 0], [15, 10, 9], (1500, 3))  # a tree's leaves: no plane
    leaf_normals = rng.normal(size=(1500, 3))
    leaf_normals /= np.linalg.norm(leaf_normals, axis=1, keepdims=True)
    points = np.concatenate([walls, cars, clutter])
    normals = np.concatenate([np.repeat([n1], 4000, 0), np.repeat([n2], 7000, 0), leaf_normals])
    facades = fit_facades(points, normals, points[:, 2], up)
    assert len(facades) == 2
    # each wall within 5 cm and 1 degree, its extent within the cell size of its returns' span
    for normal, offset, span in ((n1, 20.0, (-10.0, 5.0)), (n2, -12.0, (0.0, 15.0))):
        i = int(np.argmax(np.abs(facades.normal @ normal)))
        sign = np.sign(facades.normal[i] @ normal)
        assert sign * facades.normal[i] @ normal > np.cos(np.radians(1.0))
        assert sign * facades.offset[i] == pytest.approx(offset, abs=0.05)
        lo, hi = sorted(facades.extent[i] * (facades.tangent[i] @ [-normal[1], normal[0], 0]))
        assert lo == pytest.approx(span[0], abs=0.3) and hi == pytest.approx(span[1], abs=0.3)
        top = facades.top[i][np.isfinite(facades.top[i])]  # its highest return per metre: 9 m up
        assert len(top) >= 15 and np.all((top > 8.5) & (top < 9.1))
    with pytest.raises(ValueError, match="heights"):
        fit_facades(points, normals, points[:10, 2], up)


def _pitched_camera(h: int, w: int, f: float, pitch_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit world rays of the level camera of :func:`_level_camera` pitched up by ``pitch_deg``,
    and its optical axis."""
    rays, _ = _level_camera(h, w, f)
    a = np.radians(pitch_deg)
    R = np.array([[np.cos(a), 0.0, -np.sin(a)], [0.0, 1.0, 0.0], [np.sin(a), 0.0, np.cos(a)]])
    return rays @ R.T, R @ FORWARD


def test_an_oblique_facade_above_the_lidar_is_completed_on_its_plane_behind_a_wide_sign(rng):
    h, w = 60, 90
    rays, forward = _pitched_camera(h, w, 45.0, 6.0)
    center, up = np.array([0.0, 0.0, 1.6]), np.array([0.0, 0.0, 1.0])
    # a wall at 35 degrees to the view, 20 m ahead on the axis; the lidar reaches 4 m up it
    normal = np.array([np.cos(np.radians(35.0)), np.sin(np.radians(35.0)), 0.0])
    offset = 20.0 * normal[0]
    with np.errstate(divide="ignore"):
        t_wall = (offset - normal @ center) / (rays @ normal)
    height = center[2] + t_wall * rays[..., 2]
    on_wall = (t_wall > 0) & (height > 0.0)
    known = on_wall & (height < 4.0)
    distance = np.where(known, t_wall, np.inf)
    # a sign before the wall, 30 px wide (wider than the closing's window), at the top of the lidar's reach
    top = np.argmax(known, axis=0)  # each column's highest return
    sign = np.zeros((h, w), bool)
    for x in range(30, 60):
        sign[top[x]:top[x] + 6, x] = True
    distance[sign] = 0.85 * t_wall[sign]  # hung 15 % before the wall
    above = on_wall & ~known
    assert above[:10].all() and sign[:, 30:60].any(axis=0).all()
    returns = _wall_points(rng, normal, offset, (-150.0, 150.0), 4.0, 20000)  # farther than the view reaches
    facades = fit_facades(returns, np.repeat([normal], len(returns), 0), returns[:, 2], up)
    assert len(facades) == 1
    args = (known, np.zeros((h, w), bool), rays, center, up, 0.0)
    out, kind, _ = complete_distance(distance, *args, forward=forward, facades=facades)
    assert np.all(kind[above] == FILL_WALL)
    # the analytic ray-plane distance, within 1 % (the plane fitted to 2 cm noisy returns)
    np.testing.assert_allclose(out[above], t_wall[above], rtol=0.01)
    np.testing.assert_allclose(out[known], distance[known], rtol=1e-12)  # what the lidar saw is kept
    # the closing alone carries the sign's distance up its columns (and, pitched, is off the plane)
    closed, _, _ = complete_distance(distance, *args, forward=forward)
    assert np.all(np.abs(closed[:10, 40:50] / t_wall[:10, 40:50] - 1.0) > 0.1)
    # a tree's canopy at 40 % of the wall's distance is a thing of its own: its top keeps the closing
    tree = distance.copy()
    tree[sign] = 0.4 * t_wall[sign]
    by_plane = complete_distance(tree, *args, forward=forward, facades=facades)[0]
    alone = complete_distance(tree, *args, forward=forward)[0]
    assert np.array_equal(by_plane[:10, 40:50], alone[:10, 40:50])
    np.testing.assert_allclose(by_plane[:10, :20], t_wall[:10, :20], rtol=0.01)
    # no facade: the closing is the fallback, to the bit
    assert np.array_equal(complete_distance(distance, *args, forward=forward, facades=Facades.none(up))[0], closed)
    # a low facade nearer than what the pixel rises from, its top (0.5 m) under the rays: the
    # surface is seen over it and does not stand on it (the closing); a tall one (8 m) hides it:
    # what the lidar saw through it came through a window, and the wall above is that facade's
    def low_wall(top_m: float) -> Facades:
        return Facades(normal=np.array([[1.0, 0, 0]]), offset=np.array([5.0]), tangent=np.array([[0.0, 1, 0]]),
                       extent=np.array([[-50.0, 50.0]]), top=np.full((1, 101), top_m), up=up)

    assert np.array_equal(complete_distance(distance, *args, forward=forward, facades=low_wall(0.5))[0], closed)
    tall = complete_distance(distance, *args, forward=forward, facades=low_wall(8.0))[0]
    np.testing.assert_allclose(tall[above], 5.0 / (rays[above] @ [1.0, 0, 0]), rtol=1e-9)


def test_a_far_return_seen_over_a_sign_the_lidar_looked_over_is_not_taken_through_it():
    # a sign 30 m ahead (the plane x = 30), 4 m tall by its returns; the camera at the origin
    up = np.array([0.0, 0.0, 1.0])
    sign = Facades(normal=np.array([[1.0, 0, 0]]), offset=np.array([30.0]), tangent=np.array([[0.0, 1, 0]]),
                   extent=np.array([[-5.0, 5.0]]), top=np.full((1, 11), 4.0), up=up)

    def through(over_m: float, **kw: float) -> int:
        """The facade a return 73 m away stands on, seen along a ray ``over_m`` over the sign's top."""
        ray = np.array([[30.0, 0.0, 4.0 + over_m]])
        ray /= np.linalg.norm(ray)
        reach = 73.0 * np.hypot(ray[0, 0], ray[0, 1])
        return int(sign.first_behind(np.zeros(3), ray, np.array([reach]), **kw)[0])

    # without the field's top, 0.5 m + 5 % of 30 m over the top is still "through a window"
    assert through(1.3) == 0 and through(2.1) == -1
    # the lidar's field reaches 9.8 degrees: the sign's top (7.6 degrees) lies more than a beam's
    # step (1 degree) under it, so the lidar looked over the sign and it ends there; past 0.5 m and
    # a beam's step at 30 m (0.52 m) the return is seen over it, not through it
    assert through(1.3, ceiling_deg=9.8) == -1
    assert through(0.9, ceiling_deg=9.8) == 0
    # a field cut at 8 degrees leaves the sign's top unknown: its unseen part keeps the share
    assert through(1.3, ceiling_deg=8.0) == 0


def test_a_ray_that_does_not_meet_a_rising_street_is_a_wall_as_far_as_the_level_plane_not_sky():
    rays, z_per_m = _level_camera()
    h, w = z_per_m.shape
    center, up = np.array([0.0, 0.0, 1.6]), np.array([0.0, 0.0, 1.0])

    def rising(points: np.ndarray) -> np.ndarray:  # level to 45 m ahead, then a terrace 3 m up
        return np.where(points[:, 0] > 45.0, 3.0, 0.0)

    known = np.zeros((h, w), bool)
    distance = np.full((h, w), np.inf)
    known[30:, 28:32] = True  # a car 6 m ahead below (a wall must not rise from it)
    distance[30:, 28:32] = 6.0 / z_per_m[30:, 28:32]
    out, kind, source = complete_distance(distance, known, np.zeros((h, w), bool), rays, center, up, 0.0,
                                          forward=FORWARD, ground_at=rising, thin_fraction=0.0)
    # row 20 looks 1/60 below the horizon: 0.85 m up at 45 m, under the terrace beyond (the steps
    # from the level plane's 96 m land on the terrace and back): a wall at the level plane's 96 m
    assert np.all(kind[20] == FILL_WALL) and np.all(source[20] == -1)
    np.testing.assert_allclose((out * z_per_m)[20], 96.0, rtol=1e-9)
    # rows 0-19 above the horizon rise from it, at its camera depth
    assert np.all(kind[:20] == FILL_WALL) and np.all(source[:20] == 20)
    np.testing.assert_allclose((out * z_per_m)[:20], 96.0, rtol=1e-9)
    assert np.all(kind[21] == FILL_GROUND)  # 1/20 below: meets the street at 32 m
    np.testing.assert_allclose(out[21], 1.6 / -rays[21, :, 2], rtol=1e-9)
    assert np.all(np.isfinite(out))


#: The road's colour around the boxes of the footprint tests (RGB in [0, 1]).
ROAD = np.array([0.30, 0.32, 0.36])


def _road(slope: float = 0.0, step: float = 0.2) -> np.ndarray:
    """Road points on z = slope x over 16 m x 16 m (world, m; z up)."""
    x, y = np.meshgrid(np.arange(-8, 8, step), np.arange(-8, 8, step))
    return np.stack([x.ravel(), y.ravel(), slope * x.ravel()], 1)


def _box(center: tuple[float, float, float], yaw: float) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = center
    return T


def _in_footprint(points: np.ndarray, T: np.ndarray, half: np.ndarray, grow: float = 0.0) -> np.ndarray:
    local = (points - T[:3, 3]) @ T[:3, :3]
    return np.all(np.abs(local[:, :2]) <= half[:2] + grow, axis=1)


def test_the_ground_no_return_saw_under_a_parked_box_is_tiled_with_the_roads_colour():
    size = np.array([4.0, 2.0, 1.5])
    T = _box((1.0, 0.5, 0.75 + 0.05 * 1.0), 0.4)  # standing on a road rising 5 cm per metre
    road = _road(slope=0.05)
    seen = ~_in_footprint(road, T, size / 2, grow=0.2)  # the box and its margin hid the rest
    colors = np.tile(ROAD, (int(seen.sum()), 1))
    fill = fill_footprints(road[seen], colors, [(T, size)], np.array([0.0, 0.0, 1.0]))
    assert len(fill) > 100
    # every point of the footprint is within reach of a tile or of the road seen beside it; the
    # tiles lie on the road's plane, flat along up, road-coloured and opaque
    inner = road[_in_footprint(road, T, size / 2)]
    both = np.concatenate([fill.means[:, :2], road[seen][:, :2]])
    d = np.linalg.norm(inner[:, None, :2] - both[None, :, :2], axis=2).min(1)
    assert d.max() < 0.25 and 0.25 ** 2 * _in_footprint(fill.means, T, size / 2).sum() > 0.8 * 8.0
    np.testing.assert_allclose(fill.means[:, 2], 0.05 * fill.means[:, 0], atol=0.02)
    normal = np.stack([np.eye(3)[2]] * len(fill))
    from wcbench.reference_model.transforms import quat_to_matrix
    axes = np.stack([quat_to_matrix(q) for q in fill.quats.astype(np.float64)])
    thin = axes[np.arange(len(fill)), :, np.argmin(fill.scales, axis=1)]
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", thin, normal)), 1.0, atol=1e-3)
    assert fill.scales.min() <= 0.02 + 1e-6 and np.all(fill.opacities >= 0.9)
    np.testing.assert_allclose(fill.colors, np.tile(ROAD, (len(fill), 1)), atol=1e-3)


def test_a_tile_takes_the_colour_of_the_road_nearest_it_and_seen_ground_is_not_tiled_again():
    size = np.array([4.0, 2.0, 1.5])
    T = _box((0.0, 0.0, 0.75), 0.0)
    road = _road()
    colors = np.where(road[:, :1] < 0, 0.2, 0.6) * np.ones((1, 3))  # a dark left half, a pale right one
    seen = ~_in_footprint(road, T, size / 2, grow=0.2)
    fill = fill_footprints(road[seen], colors[seen], [(T, size)], np.array([0.0, 0.0, 1.0]))
    left, right = fill.means[:, 0] < -1.0, fill.means[:, 0] > 1.0
    assert np.all(fill.colors[left] < 0.3) and np.all(fill.colors[right] > 0.5)
    # a mover's box over road the lidar saw (other sweeps): nothing to fill; and no ground, no tile
    assert len(fill_footprints(road, colors, [(T, size)], np.array([0.0, 0.0, 1.0]))) == 0
    assert len(fill_footprints(road[:0], colors[:0], [(T, size)], np.array([0.0, 0.0, 1.0]))) == 0
    with pytest.raises(ValueError, match="colors"):
        fill_footprints(road, colors[:5], [(T, size)], np.array([0.0, 0.0, 1.0]))


def _band(h: int = 40, w: int = 80) -> tuple[np.ndarray, np.ndarray]:
    """A wall band (rows 5-24) whose column guesses alternate 40 m / 80 m every 6 columns, over a
    row of returns (25-29) and the ground (30-39), under the sky (0-4): distances and kinds."""
    kind = np.full((h, w), FILL_WALL, np.int8)
    kind[:5] = FILL_SKY
    kind[25:30] = FILL_KNOWN
    kind[30:] = FILL_GROUND
    distance = np.where((np.arange(w) // 6) % 2 == 0, 40.0, 80.0)[None, :].repeat(h, 0)
    distance[:5] = np.inf
    distance[25:30] = 60.0
    distance[30:] = 20.0
    return distance, kind


def test_a_band_of_one_colour_gets_one_distance_not_a_block_per_column():
    distance, kind = _band()
    guide = np.full((*kind.shape, 3), 0.2, np.float32)
    guide[:5] = (0.7, 0.75, 0.8)  # the sky
    guide[30:] = 0.35  # the road
    out = smooth_walls(distance, kind, guide, radius=12)
    wall = kind == FILL_WALL
    # the columns' jumps (40 <-> 80 m) are gone inside the band, and nothing leaves their range
    inner = out[8:22, 14:66]
    assert np.abs(np.diff(np.log(inner), axis=1)).max() < 0.05
    assert np.abs(np.diff(np.log(distance[8:22, 14:66]), axis=1)).max() > 0.6  # as it was
    assert out[wall].min() >= 20.0 - 1e-9 and out[wall].max() <= 80.0 + 1e-9
    # returns, ground and sky keep theirs
    np.testing.assert_array_equal(out[~wall], distance[~wall])


def test_a_wall_is_not_smoothed_across_an_edge_of_the_frame():
    distance, kind = _band()
    distance[5:25, :40], distance[5:25, 40:] = 30.0, 90.0  # two facades meeting at column 40
    guide = np.full((*kind.shape, 3), 0.15, np.float32)
    guide[:5], guide[25:30], guide[30:] = (0.7, 0.75, 0.8), (0.6, 0.2, 0.2), (0.3, 0.35, 0.4)  # sky, shops, road
    guide[5:25, 40:] = (0.8, 0.75, 0.6)  # a dark and a pale facade
    out = smooth_walls(distance, kind, guide, radius=12)
    np.testing.assert_allclose(out[5:16, :37], 30.0, rtol=0.03)
    np.testing.assert_allclose(out[5:16, 43:], 90.0, rtol=0.03)
    # where four colours meet within a window (the facades' corner with the shops' row) the
    # filter's local linear model of the colours holds less well
    np.testing.assert_allclose(out[16:25, :37], 30.0, rtol=0.15)
    np.testing.assert_allclose(out[16:25, 43:], 90.0, rtol=0.15)
    # without the frame's edge the two would mix across the seam
    flat = guide.copy()
    flat[5:25] = 0.15
    mixed = smooth_walls(distance, kind, flat, radius=12)
    assert mixed[15, 38] > 40.0 and mixed[15, 42] < 80.0


def test_a_thin_return_before_a_facade_of_its_colour_lends_the_walls_nothing_a_wide_one_does():
    # a facade's walls at 50 m (rows 5-24) over its returns (25-29), a pole of the facade's colour at
    # 10 m (columns 38-41, every row below the sky), and a paler near building at 11 m (columns
    # 0-19) whose walls continue it
    h, w = 40, 80
    kind = np.full((h, w), FILL_WALL, np.int8)
    kind[:5], kind[25:30], kind[30:] = FILL_SKY, FILL_KNOWN, FILL_GROUND
    distance = np.full((h, w), 50.0)
    distance[:5], distance[30:] = np.inf, 20.0
    kind[5:30, 38:42], distance[5:30, 38:42] = FILL_KNOWN, 10.0
    distance[5:30, :20] = 11.0
    guide = np.full((h, w, 3), 0.2, np.float32)
    guide[:5], guide[30:] = (0.7, 0.75, 0.8), 0.35
    guide[5:30, :20] = (0.75, 0.7, 0.55)
    out = smooth_walls(distance, kind, guide, radius=12)
    wall = kind == FILL_WALL
    # beside the pole the facade keeps its 50 m (the pole, 4 px wide, is a dip the closing fills)
    np.testing.assert_allclose(out[5:25, 30:38][wall[5:25, 30:38]], 50.0, rtol=0.01)
    np.testing.assert_allclose(out[5:25, 42:50][wall[5:25, 42:50]], 50.0, rtol=0.01)
    # the near building's walls keep its 11 m: wider than the window, its returns are a surface
    np.testing.assert_allclose(out[5:25, :8], 11.0, rtol=0.01)
    np.testing.assert_array_equal(out[~wall], distance[~wall])


def test_complete_distance_smooths_its_walls_only_when_given_the_frame():
    rays, z_per_m = _level_camera()
    h, w = z_per_m.shape
    up, center = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.6])
    known = np.zeros((h, w), bool)
    distance = np.zeros((h, w))
    known[18:20, :] = True  # a row of returns at 12 m and 24 m, alternating every 5 columns
    depth = np.where((np.arange(w) // 5) % 2 == 0, 12.0, 24.0)[None, :]
    distance[18:20] = depth / z_per_m[18:20]
    sky = np.zeros((h, w), bool)
    sky[:2] = True
    opts = {"forward": FORWARD, "thin_fraction": 0.0}  # each column continues its own return
    plain, kind, _ = complete_distance(distance, known, sky, rays, center, up, 0.0, **opts)
    guide = np.full((h, w, 3), 0.3, np.float32)
    guided, kind2, _ = complete_distance(distance, known, sky, rays, center, up, 0.0, guide=guide,
                                         guide_radius=0.3, **opts)  # a 12 px window on 40 rows
    np.testing.assert_array_equal(kind, kind2)
    wall = kind == FILL_WALL
    assert np.abs(np.diff(np.log(plain[5:15, 10:50]), axis=1)).max() > 0.6
    assert np.abs(np.diff(np.log(guided[5:15, 10:50]), axis=1)).max() < 0.1
    np.testing.assert_array_equal(guided[~wall], plain[~wall])
    with pytest.raises(ValueError, match="radius >= 1"):
        smooth_walls(plain, kind, guide[:10], radius=3)


def test_a_pixel_between_two_returns_of_one_surface_takes_their_interpolated_inverse_depth():
    h, w = 30, 4
    depth = np.full((h, w), np.inf)
    sky = np.zeros((h, w), bool)
    depth[5, :], depth[11, :] = 80.0, 84.0  # two rings of one far facade, 6 rows apart
    depth[11, 1] = 40.0  # column 1: the lower return is a nearer thing
    sky[8, 2] = True  # column 2: sky between them
    depth[11, 3], depth[20, 3] = np.inf, 81.0  # column 3: 15 rows apart
    rr, cc = np.array([7, 7, 7, 7, 9]), np.array([0, 1, 2, 3, 0])
    out = bridge_rings(depth, sky, rr, cc, max_gap=12, agree=0.05)
    # a plane's inverse depth is affine in the row: 2 of 6 rows from 80 m toward 84 m
    assert out[0] == pytest.approx(1.0 / ((4 / 6) / 80.0 + (2 / 6) / 84.0), rel=1e-12)
    assert out[4] == pytest.approx(1.0 / ((2 / 6) / 80.0 + (4 / 6) / 84.0), rel=1e-12)
    assert np.all(np.isinf(out[1:4]))  # disagreeing, across the sky, too far apart
    assert np.isfinite(bridge_rings(depth, sky, rr[3:4], cc[3:4], max_gap=14, agree=0.05)[0])


def test_the_rows_between_a_far_facades_rings_stay_on_it_and_out_of_the_smoothing():
    rays, z_per_m = _level_camera()
    h, w = z_per_m.shape
    up, center = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.6])
    known = np.zeros((h, w), bool)
    depth = np.full((h, w), np.inf)
    for row in (6, 10, 14):  # a far facade's rings, 80 m ahead
        known[row], depth[row] = True, 80.0
    known[15:20], depth[15:20] = True, 20.0  # a near low building below it, in the same colour
    distance = np.where(known, depth / z_per_m, 0.0)
    sky = np.zeros((h, w), bool)
    sky[:3] = True
    guide = np.full((h, w, 3), 0.3, np.float32)
    opts = {"forward": FORWARD, "guide": guide, "guide_radius": 0.3}
    # rings 4 rows apart on 40 rows (at 270 rows the default bridges up to 12)
    out, kind, _ = complete_distance(distance, known, sky, rays, center, up, 0.0, ring_gap=0.1, **opts)
    between = np.zeros((h, w), bool)
    between[[7, 8, 9, 11, 12, 13]] = True
    assert np.all(kind[between] == FILL_WALL)
    np.testing.assert_allclose((out * z_per_m)[between], 80.0, rtol=1e-9)
    # without the bridge the frame's smoothing pulls them toward the near building's 20 m
    old, _, _ = complete_distance(distance, known, sky, rays, center, up, 0.0, ring_gap=0.0, **opts)
    assert (old * z_per_m)[between].min() < 60.0
