"""Ghost returns (smoke, exhaust, spray, a reflection's ghost) are no surface: no frame shows one,
while a pedestrian, dynamic too, is what its frame shows (motion.py, docs/design.md §7)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

# The scene analysis needs the model extra (torch, PyMaxflow); the torch-free envs skip it.
pytest.importorskip("torch")

from wcbench.reference_model.scene_analysis.analysis import solid_masks
from wcbench.reference_model.scene_analysis.motion import classify_returns, transient_classes
from wcbench.reference_model.scene_analysis.views import AnalysisViews, pixel_indices

W, H, F = 160, 90, 6
K = np.array([[80.0, 0.0, 80.0], [0.0, 80.0, 45.0], [0.0, 0.0, 1.0]])
CLASSES = {1: "Building", 2: "Reflection", 3: "Pedestrian", 4: "Exhaust"}


def _grid(x0: float, x1: float, y0: float, y1: float, z: float, step: float = 0.1) -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], 1)


def _scene() -> tuple[SimpleNamespace, AnalysisViews, dict[str, np.ndarray]]:
    """A camera still at the origin looking along +z (y down) at a wall 20 m away, a pedestrian at
    8 m, a reflection's ghost at 30 m above the wall's top (in open sky) and a puff of exhaust at 6 m,
    in every sweep."""
    wall = _grid(-6.0, 6.0, -1.0, 2.0, 20.0, 0.2)
    person = _grid(1.0, 1.5, 0.2, 1.9, 8.0)
    ghost = _grid(-3.0, -2.0, -9.0, -8.0, 30.0)
    puff = _grid(-1.5, -1.0, 1.0, 1.5, 6.0)
    points = np.concatenate([wall, person, ghost, puff])
    labels = np.concatenate([np.full(len(wall), 1), np.full(len(person), 3), np.full(len(ghost), 2),
                             np.full(len(puff), 4)]).astype(np.uint8)
    sweep = SimpleNamespace(points=points, labels=labels)
    scene = SimpleNamespace(frames=list(range(F)), lidar=lambda f: sweep, tracks=[], class_names=CLASSES)
    img = np.full((H, W, 3), 0.5, np.float32)
    views = AnalysisViews(size=(W, H), images=[img] * F, K=[K] * F, camera_to_world=[np.eye(4)] * F,
                          up=np.array([0.0, -1.0, 0.0]), times=np.arange(F) * 0.1)
    parts = {"wall": wall, "person": person, "ghost": ghost, "puff": puff}
    return scene, views, parts


def test_people_are_transient_but_not_ghosts():
    every = transient_classes(CLASSES)
    ghosts = transient_classes(CLASSES, people=False)
    assert every[[2, 3, 4]].all() and not every[1]
    assert ghosts[[2, 4]].all() and not ghosts[[1, 3]].any()


def test_ghost_returns_are_in_no_frame_and_no_solid_pixel_while_a_pedestrian_is():
    scene, views, parts = _scene()
    returns = classify_returns(scene, views)
    n = {name: len(p) for name, p in parts.items()}
    start = np.cumsum([0, *n.values()])
    span = {name: slice(a, b) for name, a, b in zip(n, start[:-1], start[1:])}
    for k in range(F):
        assert returns.ghost[k][span["ghost"]].all() and returns.ghost[k][span["puff"]].all()
        assert not returns.ghost[k][span["wall"]].any() and not returns.ghost[k][span["person"]].any()
        assert returns.dynamic[k][span["person"]].all() and not returns.dynamic[k][span["wall"]].any()
    assert returns.facts["ghost"] == F * (n["ghost"] + n["puff"])
    shown = returns.frame_points(2)
    for name, present in (("wall", True), ("person", True), ("ghost", False), ("puff", False)):
        found = np.isin(parts[name].view([("", float)] * 3), shown.view([("", float)] * 3)).ravel()
        assert found.all() if present else not found.any(), name
    solid, _ = solid_masks(views, returns)
    for name, present in (("person", True), ("ghost", False)):
        u, v, _, ok = pixel_indices(parts[name], views.world_to_camera(2), K, (W, H))
        assert ok.any()
        hit = solid[2][v[ok], u[ok]]
        assert hit.all() if present else not hit.any(), name
