"""Completing a distance map with the ground plane and vertical walls, against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from wcbench.reference_model.scene_graph.completion import (
    FILL_GROUND,
    FILL_KNOWN,
    FILL_SKY,
    FILL_WALL,
    closing_among,
    complete_distance,
    ground_height_below,
)

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


def test_a_ray_that_misses_a_rising_ground_is_a_wall_not_a_pixel_with_nothing_below():
    # A street rising 2 % ahead: the row just below the horizon (descending 1.7 %) never meets it.
    # Above it, where only ground lies below, the wall rises from the first row that does meet the
    # ground (old behaviour: from the missing row, infinitely far, shown as sky).
    rays, z_per_m = _level_camera()
    h, w = z_per_m.shape
    up, center = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.6])
    sky = np.zeros((h, w), bool)
    sky[:3] = True
    known = np.zeros((h, w), bool)
    out, kind, source = complete_distance(np.zeros((h, w)), known, sky, rays, center, up, 0.0, forward=FORWARD,
                                          ground_at=lambda p: 0.02 * p[:, 0], thin_fraction=0.0)
    assert np.all(kind[20] == FILL_WALL) and np.all(source[20] == 21)
    assert np.all(np.isfinite(out[21:])) and np.all(kind[21:] == FILL_GROUND)
    assert not np.any((kind == FILL_SKY) & ~sky)
    # the wall keeps the camera depth of the ground pixel it rises from (thin_fraction=0: its own column)
    np.testing.assert_allclose((out * z_per_m)[3:21], np.broadcast_to((out * z_per_m)[21], (18, w)), rtol=1e-9)
