"""Foliage by the scene's semantics: a crown reaching into a parked car's box is not the car
(motion.py's :meth:`LidarReturns.foliage_at`, read by the surfaces' box search)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

# The scene analysis needs the model extra (torch, PyMaxflow); the torch-free envs skip it.
pytest.importorskip("torch")

from wcbench.reference_model.scene_analysis.motion import (
    LidarReturns,
    classify_returns,
    foliage_classes,
)
from wcbench.reference_model.scene_analysis.views import AnalysisViews

W, H, F = 160, 90, 4
K = np.array([[80.0, 0.0, 80.0], [0.0, 80.0, 45.0], [0.0, 0.0, 1.0]])


def _scene(classes, rng):
    """A camera still at the origin looking along +z at a wall 20 m away (class 1) and a crown of
    scattered returns 10 m away (class 2), the same sweep every frame."""
    xs, ys = np.meshgrid(np.arange(-6.0, 6.0, 0.2), np.arange(-1.0, 2.0, 0.2))
    wall = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 20.0)], 1)
    crown = rng.uniform([-1.0, -3.0, 9.0], [1.0, -1.0, 11.0], (1500, 3))
    labels = np.concatenate([np.full(len(wall), 1), np.full(len(crown), 2)]).astype(np.uint8)
    sweep = SimpleNamespace(points=np.concatenate([wall, crown]), labels=labels)
    scene = SimpleNamespace(frames=list(range(F)), lidar=lambda f: sweep, tracks=[], class_names=classes)
    views = AnalysisViews(size=(W, H), images=[np.full((H, W, 3), 0.5, np.float32)] * F, K=[K] * F,
                          camera_to_world=[np.eye(4)] * F, up=np.array([0.0, -1.0, 0.0]), times=np.arange(F) * 0.1)
    return scene, views, wall, crown


def test_foliage_classes_are_read_by_name():
    lookup = foliage_classes({5: "Vegetation", 13: "Car", 41: "Building", 7: " TREES ", 300: "vegetation"})
    assert lookup[[5, 7]].all() and not lookup[[13, 41]].any() and lookup.sum() == 2


def test_a_point_among_foliage_returns_is_foliage_one_on_the_wall_or_alone_is_not(rng):
    scene, views, wall, crown = _scene({1: "Building", 2: "Vegetation"}, rng)
    returns = classify_returns(scene, views)
    assert all(returns.foliage[k][len(wall):].all() and not returns.foliage[k][:len(wall)].any() for k in range(F))
    beside_wall = wall[:50] + np.array([0.05, 0.0, 0.0])
    out = returns.foliage_at(np.concatenate([crown[:50], beside_wall, [[0.0, 5.0, 15.0]]]))
    assert out[:50].all() and not out[50:].any()
    assert returns.foliage_at(np.zeros((0, 3))).shape == (0,)


def test_foliage_at_is_the_vote_of_the_nearest_static_returns_within_reach(rng):
    # the slow twin: every static return's distance, the 8 nearest within 0.2 m, a strict majority;
    # a noise return (not static) gives no vote
    n = 4000
    points = {0: rng.uniform(-1.0, 1.0, (n, 3)), 3: rng.uniform(-1.0, 1.0, (n, 3))}
    leafy = {k: rng.random(n) < 0.5 for k in points}
    noise = {k: rng.random(n) < 0.1 for k in points}
    none = {k: np.zeros(n, bool) for k in points}
    returns = LidarReturns(points=points, dynamic=none, tracked=none, noise=noise, foliage=leafy)
    static = np.concatenate([points[k][~noise[k]] for k in (0, 3)])
    flags = np.concatenate([leafy[k][~noise[k]] for k in (0, 3)])
    queries = rng.uniform(-1.1, 1.1, (300, 3))
    fast = returns.foliage_at(queries)
    for q, got in zip(queries, fast):
        d = np.linalg.norm(static - q, axis=1)
        near = np.argsort(d)[:8]
        near = near[d[near] <= 0.2]
        assert got == (flags[near].sum() * 2 > len(near)), q
    assert fast.any() and (~fast).any()


def test_a_scene_without_foliage_in_its_semantics_has_none(rng):
    scene, views, _, crown = _scene({1: "Building", 2: "Car"}, rng)
    returns = classify_returns(scene, views)
    assert returns.foliage == {} and not returns.foliage_at(crown).any()
    scene.lidar = lambda f: SimpleNamespace(points=np.concatenate([crown]), labels=None)
    assert classify_returns(scene, views).foliage == {}
