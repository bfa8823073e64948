"""What the harder truth's wet ground mirrors (wcbench.scenes.synth.mirrors; docs/design.md §3): the
street its reflected view ray meets, the sky only where it meets nothing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wcbench.scenes.synth.content import Boxes
from wcbench.scenes.synth.light import linear_to_srgb, srgb_to_linear
from wcbench.scenes.synth.mirrors import RAY_OFFSET_M, mirror_hits, mirrored_colors, reflected_rays

EYE = np.array([0.0, 0.0, 1.6])
RED, GREY, SKY = np.array([0.8, 0.1, 0.1]), np.array([0.3, 0.3, 0.32]), np.array([0.6, 0.62, 0.66])
UP = np.array([0.0, 0.0, 1.0])


def _box(center: list[float], half: list[float], yaw: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    R = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    return np.array(center, float), R, np.array(half, float)


def _boxes(*items: tuple[np.ndarray, np.ndarray, np.ndarray]) -> Boxes:
    return Boxes.of([(c, R, h, 0.3, 0, -1) for c, R, h in items])


def _street() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Boxes]:
    """A grey wet road (z = 0, 0.25 m grid) before a red box 20 m ahead, 6 m wide and 4 m tall, whose
    front face is covered by red Gaussians; returns means, normals, mirrors, colours and the box."""
    x, y = np.meshgrid(np.arange(2.0, 18.0, 0.25), np.arange(-10.0, 10.0, 0.25))
    road = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    fy, fz = np.meshgrid(np.arange(-3.0, 3.01, 0.2), np.arange(0.0, 4.01, 0.2))
    face = np.stack([np.full(fy.size, 19.0), fy.ravel(), fz.ravel()], 1)
    means = np.concatenate([road, face])
    normals = np.concatenate([np.tile(UP, (len(road), 1)), np.tile([-1.0, 0.0, 0.0], (len(face), 1))])
    mirrors = np.arange(len(means)) < len(road)
    colors = np.concatenate([np.tile(GREY, (len(road), 1)), np.tile(RED, (len(face), 1))])
    return means, normals, mirrors, colors, _boxes(_box([20.0, 0.0, 2.0], [1.0, 3.0, 2.0]))


def _index(means: np.ndarray, point: list[float]) -> int:
    return int(np.argmin(np.linalg.norm(means - np.array(point), axis=1)))


def test_the_wet_road_mirrors_the_box_before_it_and_the_sky_beside_it() -> None:
    means, normals, mirrors, colors, box = _street()
    out, hit = mirrored_colors(means, normals, EYE, mirrors, colors, SKY, box, np.zeros((0, 4)))
    ahead, beside = _index(means, [10.0, 0.0, 0.0]), _index(means, [10.0, 8.0, 0.0])
    # 10 m ahead the reflected ray rises 1.6 m in 10 m: 1.44 m up at the box's front, 9 m on
    assert hit[ahead] and not hit[beside]
    np.testing.assert_allclose(out[ahead], RED, atol=1e-9)
    np.testing.assert_allclose(out[beside], SKY, atol=1e-9)
    # what does not mirror keeps the sky it was given (its Fresnel term is 0 anyway)
    assert not hit[~mirrors].any()
    np.testing.assert_allclose(out[~mirrors], np.tile(SKY, ((~mirrors).sum(), 1)))
    # near the camera the reflected ray rises steeply, over the box's 4 m: sky
    near = _index(means, [2.0, 0.0, 0.0])
    assert not hit[near]


def test_the_reflected_path_is_hazed_in_linear_light() -> None:
    means, normals, mirrors, colors, box = _street()
    beta, haze = 0.05, np.array([0.7, 0.7, 0.72])
    out, hit = mirrored_colors(means, normals, EYE, mirrors, colors, SKY, box, np.zeros((0, 4)), beta=beta, haze=haze)
    i = _index(means, [10.0, 0.0, 0.0])
    assert hit[i]
    r = reflected_rays(means[i:i + 1], normals[i:i + 1], EYE)[0]
    t = (19.0 - (means[i, 0] + RAY_OFFSET_M * r[0])) / r[0]  # to the box's front face at x = 19
    kept = math.exp(-beta * t)
    np.testing.assert_allclose(out[i], linear_to_srgb(srgb_to_linear(RED) * kept + srgb_to_linear(haze) * (1 - kept)),
                               atol=1e-9)
    with pytest.raises(ValueError, match="haze"):
        mirrored_colors(means, normals, EYE, mirrors, colors, SKY, box, np.zeros((0, 4)), beta=beta)
    with pytest.raises(ValueError, match="mirrors"):
        mirrored_colors(means, normals, EYE, mirrors[:-1], colors, SKY, box, np.zeros((0, 4)))


def test_a_wet_side_seen_from_above_mirrors_the_ground() -> None:
    # a car's wet side 5 m ahead, facing the camera, seen from 1.6 m up at 0.5 m: the ray reflected
    # back toward the camera falls and meets the road (its colour: the nearest road Gaussian's)
    means = np.array([[5.0, 0.0, 0.5], [4.0, 0.0, 0.0], [3.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    normals = np.array([[-1.0, 0.0, 0.0], *[[0.0, 0.0, 1.0]] * 4])
    colors = np.array([RED, GREY, GREY * 0.5, GREY * 0.2, GREY * 0.1])
    out, hit = mirrored_colors(means, normals, EYE, np.array([True, False, False, False, False]), colors, SKY,
                               _boxes(), np.zeros((0, 4)))
    # the reflected ray leaves (5, 0, 0.5) back along -x, falling 1.1 m in 5 m: the road at x = 2.73
    assert hit[0]
    np.testing.assert_allclose(out[0], GREY * 0.5, atol=1e-9)
    out, hit = mirrored_colors(means, normals, EYE, np.array([True, False, False, False, False]), colors, SKY,
                               _boxes(), np.zeros((0, 4)), ground_z=None)
    assert not hit[0]


def _slow_hit(o: np.ndarray, d: np.ndarray, boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
              spheres: np.ndarray, ground_z: float) -> tuple[float, int]:
    """The first entry of one ray and the box it is (-1: another shape or none): each box clipped face
    pair by face pair (Cyrus-Beck), each sphere by its quadratic, the ground plane; a ray starting
    inside a shape does not meet it."""
    best, which = math.inf, -1
    for m, (c, R, h) in enumerate(boxes):
        lo_o, lo_d = R.T @ (o - c), R.T @ d
        t_in, t_out = -math.inf, math.inf
        for axis in range(3):
            if abs(lo_d[axis]) < 1e-15:
                if abs(lo_o[axis]) > h[axis]:
                    t_in, t_out = math.inf, -math.inf
                continue
            a, b = (-h[axis] - lo_o[axis]) / lo_d[axis], (h[axis] - lo_o[axis]) / lo_d[axis]
            t_in, t_out = max(t_in, min(a, b)), min(t_out, max(a, b))
        if t_in <= t_out and 0 < t_in < best:
            best, which = t_in, m
    for s in spheres:
        oc = o - s[:3]
        b, c2 = float(d @ oc), float(oc @ oc) - s[3] ** 2
        disc = b * b - c2
        if disc >= 0 and 0 < -b - math.sqrt(disc) < best:
            best, which = -b - math.sqrt(disc), -1
    if d[2] < 0 and 0 < (ground_z - o[2]) / d[2] < best:
        best, which = (ground_z - o[2]) / d[2], -1
    return best, which


def test_mirror_hits_match_every_ray_against_every_shape_one_at_a_time() -> None:
    rng = np.random.default_rng(7)
    shapes = [_box(list(rng.uniform([-20, -20, 0], [20, 20, 6])), list(rng.uniform(0.3, 4.0, 3)),
                   float(rng.uniform(0, 2 * math.pi))) for _ in range(8)]
    spheres = np.concatenate([rng.uniform([-20, -20, 3], [20, 20, 9], (4, 3)), rng.uniform(1.0, 4.0, (4, 1))], 1)
    origins = rng.uniform([-25, -25, 0.0], [25, 25, 8.0], (400, 3))
    dirs = rng.normal(size=(400, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    fast, box = mirror_hits(origins, dirs, _boxes(*shapes), spheres, ground_z=0.0)
    slow = [_slow_hit(o, d, shapes, spheres, 0.0) for o, d in zip(origins, dirs)]
    t = np.array([a for a, _ in slow])
    assert 100 < np.isfinite(fast).sum() < 400 and (box >= 0).sum() > 15
    np.testing.assert_array_equal(np.isfinite(fast), np.isfinite(t))
    np.testing.assert_allclose(fast[np.isfinite(fast)], t[np.isfinite(t)], rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(box, [b for _, b in slow])
