"""A wall pixel the lidar swept across and saw nothing near lies at least as far as the lidar
reaches (:func:`beyond_reach`), against a per-pixel loop of the same rule; and the lidar's reach
read off a scene's returns (:func:`lidar_reach`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wcbench.reference_model.scene_analysis.motion import LidarReturns
from wcbench.reference_model.scene_analysis.reach import LidarReach, lidar_reach
from wcbench.reference_model.scene_analysis.views import AnalysisViews
from wcbench.reference_model.scene_graph.completion import (
    FILL_GROUND,
    FILL_KNOWN,
    FILL_SKY,
    FILL_WALL,
    beyond_reach,
    reach_vote,
)

UP = np.array([0.0, 0.0, 1.0])


def _level_rays(h: int, w: int, f: float) -> np.ndarray:
    """[H, W, 3] unit world rays of a level camera looking along +x, z up."""
    xs = (np.arange(w) + 0.5 - w / 2) / f
    ys = (np.arange(h) + 0.5 - h / 2) / f
    cam = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None], np.ones((h, w))), -1)
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera -> world
    return (cam / np.linalg.norm(cam, axis=-1, keepdims=True)) @ R.T


def _loop_twin(distance, kind, hits, rays, *, range_m, band, r):
    """The rule pixel by pixel, as its docstring says it."""
    h, w = kind.shape
    out = distance.copy()
    lo, hi = (math.sin(math.radians(e)) for e in band)
    for y in range(h):
        for x in range(w):
            s = float(rays[y, x] @ UP)
            near = hits[max(0, y - r):y + r + 1, max(0, x - r):x + r + 1].any()
            swept = hits[y, :x + 1].any() and hits[y, x:].any() and hits[y:, x].any()
            if kind[y, x] == FILL_WALL and lo < s < hi and not near and swept and distance[y, x] < range_m:
                out[y, x] = range_m
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_beyond_reach_matches_the_rule_pixel_by_pixel(seed):
    rng = np.random.default_rng(seed)
    h, w = 30, 48
    rays = _level_rays(h, w, 20.0)
    kinds = [FILL_KNOWN, FILL_GROUND, FILL_WALL, FILL_SKY]
    kind = rng.choice(kinds, size=(h, w), p=[0.2, 0.1, 0.6, 0.1]).astype(np.int8)
    hits = rng.random((h, w)) < 0.04
    distance = rng.uniform(5.0, 150.0, (h, w))
    got = beyond_reach(distance, kind, hits, rays, UP, range_m=80.0, elevation_deg=(-10.0, 25.0), clearance=1 / 48)
    want = _loop_twin(distance, kind, hits, rays, range_m=80.0, band=(-10.0, 25.0), r=1)
    np.testing.assert_array_equal(got, want)
    assert (got != distance).any() and (got == distance).any()  # both branches are exercised


def test_a_building_closing_the_street_beyond_the_returns_is_put_at_the_reach():
    h, w = 40, 64
    rays = _level_rays(h, w, 30.0)
    kind = np.full((h, w), FILL_WALL, np.int8)
    kind[:8] = FILL_SKY
    hits = np.zeros((h, w), bool)
    hits[8:30, :14] = hits[8:30, 50:] = True  # the facades on either side, seen by the lidar
    hits[30:] = True  # the road
    distance = np.full((h, w), 25.0)  # the completion's guess: the car in front, continued upward
    out = beyond_reach(distance, kind, hits, rays, UP, range_m=120.0, elevation_deg=(-20.0, 40.0), clearance=2 / 64)
    assert np.all(out[10:28, 17:47] == 120.0)  # the end of the street, clear of every return
    assert np.all(out[:, :16] == 25.0) and np.all(out[:, 48:] == 25.0)  # within 2 px of the facades' returns
    assert np.all(out[:8] == 25.0)  # the sky rows are not walls
    # above the lidar's highest beam the ray says nothing: the rows whose elevation passes 5 degrees stay
    top = beyond_reach(distance, kind, hits, rays, UP, range_m=120.0, elevation_deg=(-20.0, 5.0), clearance=2 / 64)
    elevation = np.degrees(np.arcsin(rays[:, 32] @ UP))
    assert np.all(top[elevation >= 5.0, 32] == 25.0) and np.all(top[(elevation < 5.0) & (np.arange(h) >= 10)
                                                                     & (np.arange(h) < 28), 32] == 120.0)
    # beside the sweep (no return on one side of the row) nothing is known
    one_side = hits.copy()
    one_side[:30, 50:] = False
    side = beyond_reach(distance, kind, one_side, rays, UP, range_m=120.0, elevation_deg=(-20.0, 40.0),
                        clearance=2 / 64)
    assert np.all(side[:30, 17:] == 25.0)
    # a guess already beyond the reach is kept
    far = beyond_reach(np.full((h, w), 300.0), kind, hits, rays, UP, range_m=120.0, elevation_deg=(-20.0, 40.0))
    assert np.all(far == 300.0)


def test_beyond_reach_refuses_bad_input():
    rays = _level_rays(4, 6, 3.0)
    kind = np.full((4, 6), FILL_WALL, np.int8)
    hits = np.zeros((4, 6), bool)
    with pytest.raises(ValueError, match="range_m > 0"):
        beyond_reach(np.ones((4, 6)), kind, hits, rays, UP, range_m=0.0, elevation_deg=(-5.0, 5.0))
    with pytest.raises(ValueError, match="low < high"):
        beyond_reach(np.ones((4, 6)), kind, hits, rays, UP, range_m=50.0, elevation_deg=(5.0, -5.0))
    with pytest.raises(ValueError, match=r"\[H, W\]"):
        beyond_reach(np.ones((4, 5)), kind, hits, rays, UP, range_m=50.0, elevation_deg=(-5.0, 5.0))


def _views(centers: list[np.ndarray]) -> AnalysisViews:
    poses = []
    for c in centers:
        T = np.eye(4)
        T[:3, 3] = c
        poses.append(T)
    n = len(centers)
    return AnalysisViews(size=(8, 6), images=[np.zeros((6, 8, 3), np.float32)] * n, K=[np.eye(3)] * n,
                         camera_to_world=poses, up=UP, times=np.arange(n, dtype=np.float64))


def _returns(points: dict[int, np.ndarray]) -> LidarReturns:
    flags = {k: np.zeros(len(p), bool) for k, p in points.items()}
    return LidarReturns(points=points, dynamic=flags, tracked=dict(flags), noise=dict(flags))


def test_lidar_reach_reads_the_range_and_the_band_of_far_returns():
    rng = np.random.default_rng(0)
    centers = [np.array([2.0 * k, 0.0, 1.5]) for k in range(5)]
    points = {}
    for k, c in enumerate(centers):
        d = rng.uniform(1.0, 90.0, 4000)
        el = np.radians(rng.uniform(-12.0, 9.0, 4000))
        az = rng.uniform(-np.pi, np.pi, 4000)
        points[k] = c + d[:, None] * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    reach = lidar_reach(_views(centers), _returns(points))
    assert isinstance(reach, LidarReach)
    assert 89.0 < reach.range_m <= 90.0
    lo, hi = reach.elevation_deg
    assert -12.0 < lo < -11.7 and 8.7 < hi < 9.0
    assert reach.facts() == {"range_m": round(reach.range_m, 1), "elevation_deg": [round(lo, 1), round(hi, 1)]}
    # too few returns beyond 20 m to read a band: no reach
    near = {k: c + rng.uniform(-10, 10, (300, 3)) for k, c in enumerate(centers)}
    assert lidar_reach(_views(centers), _returns(near)) is None
    assert lidar_reach(_views(centers), _returns({})) is None
    with pytest.raises(ValueError, match="range_m > 0"):
        LidarReach(range_m=-1.0, elevation_deg=(0.0, 1.0))


def test_given_the_frame_a_surface_the_lidar_saw_in_part_is_not_put_beyond_the_reach():
    """Between a spinning lidar's sparse upper beams the top of a near facade returns nothing; the
    frame shows it as one surface with its lower floors, which returned: it stays. A building that
    looks like nothing the lidar saw is put at the reach."""
    h, w = 270, 480
    rays = _level_rays(h, w, 300.0)
    kind = np.full((h, w), FILL_WALL, np.int8)
    kind[:60] = FILL_SKY
    guide = np.full((h, w, 3), 0.55, np.float32)  # the street's light facades
    guide[70:140, 40:200] = 0.2  # a dark facade on the left ...
    hits = np.zeros((h, w), bool)
    hits[85:140, 40:200] = True  # ... whose floors below its top 15 rows returned
    hits[60:140, :40] = hits[60:140, 440:] = True  # the street's edges
    hits[140:] = True  # the road
    guide[100:136, 260:340] = np.array([0.6, 0.3, 0.2], np.float32)  # a brick building far down the street
    distance = np.full((h, w), 30.0)
    kwargs = dict(range_m=150.0, elevation_deg=(-30.0, 40.0))
    plain = beyond_reach(distance, kind, hits, rays, UP, **kwargs)
    voted = beyond_reach(distance, kind, hits, rays, UP, guide=guide, **kwargs)
    assert np.all(plain[70:80, 50:190] == 150.0)  # without the frame, the facade's top goes far
    assert np.all(voted[70:80, 50:190] == 30.0)  # with it, the facade stays one surface
    assert np.all(voted[104:132, 266:334] == 150.0)  # the brick building goes to the reach
    assert np.all(voted[hits] == 30.0)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_vote_on_the_candidates_surroundings_is_the_whole_frames_at_every_candidate(seed):
    rng = np.random.default_rng(seed)
    h, w = 135, 240
    # a frame of a few flat regions with noise, candidates in a band about the horizon
    guide = np.repeat(np.repeat(rng.random((9, 16, 3)), 15, axis=0), 15, axis=1).astype(np.float32)
    guide += rng.normal(0.0, 0.02, guide.shape).astype(np.float32)
    candidates = np.zeros((h, w), bool)
    candidates[50:80, 60:200] = rng.random((30, 140)) < 0.5
    hits = rng.random((h, w)) < 0.3
    hits[candidates] = False
    fast = reach_vote(candidates, hits, guide, radius=10)
    slow = reach_vote(candidates, hits, guide, radius=10, crop=False)
    np.testing.assert_array_equal(fast[candidates], slow[candidates])
    assert fast[candidates].any() and not fast[candidates].all()  # both verdicts are exercised
    assert not fast[:20].any() and not fast[110:].any()  # outside the grown box: False
