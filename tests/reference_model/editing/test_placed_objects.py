"""``insert ... at=``: an object set down on the ground, from this scene or carried in from another
trained scene (its clear colours kept, every other weather read by the target's decoders)."""

from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import weather_models as wm  # noqa: E402

from wcbench.reference_model.editing.edits import parse_edit, parse_edits, placement_for  # noqa: E402
from wcbench.reference_model.editing.transfer import (  # noqa: E402
    carried_features,
    ground_axes,
    ground_point,
    placed_objects,
    pose_on_ground,
)
from wcbench.reference_model.model.decoders import color_logits  # noqa: E402
from wcbench.reference_model.model.scene_model import Placement  # noqa: E402

pytestmark = pytest.mark.model

#: The hand-made scene's camera looks along +z with y down: its "up" is -y, and the ground lies 2 m
#: below the camera (y = +2).
UP = np.array([0.0, -1.0, 0.0])


def _flat_ground(x: float, y: float) -> np.ndarray:
    return np.array([x, 2.0, y])


def test_placed_insert_parses_round_trips_and_refuses_what_it_cannot_mean():
    e = parse_edit("insert scene=pandaset_002_back id=5 at=12,-3,90")
    assert (e.scene, e.ids, e.at, e.by) == ("pandaset_002_back", ("5",), (12.0, -3.0, 90.0), None)
    assert parse_edits([e.to_json()]) == [e]
    assert parse_edit("insert id=7 at=1,2,0").scene is None
    for text, match in [("insert scene=b id=5", "needs at="), ("insert id=5 at=1,2,3 by=1,0,0", "exclude"),
                        ("translate id=5 at=1,2,3", "only go with insert"),
                        ("insert class=Car at=1,2,3", "exactly one"), ("insert ids=5,6 at=1,2,3", "exactly one"),
                        ("insert id=5 at=1,2", "three numbers"), ("insert id=5 at=1,x,2", "must be numbers"),
                        ("insert id=5 at=1,2,nan", "finite")]:
        with pytest.raises(ValueError, match=match):
            parse_edit(text)


@pytest.mark.parametrize("yaw", [0.0, 30.0, 90.0, -135.0])
def test_the_pose_stands_the_box_on_the_ground_turned_by_the_yaw_about_up(yaw):
    up = np.array([0.05, -0.1, 1.0])
    up /= np.linalg.norm(up)
    size = np.array([4.0, 2.0, 1.5])

    def ground(x: float, y: float) -> np.ndarray:  # the plane up . p = -1.7 below x, y
        return np.array([x, y, (-1.7 - up[0] * x - up[1] * y) / up[2]])

    pose = pose_on_ground((3.0, -2.0, yaw), up=up, box_size=size, ground=ground)
    R, t = pose[:3, :3], pose[:3, 3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R[:, 2], up, atol=1e-12)  # the box's z is the scene's up
    # the bottom face's centre lies on the plane below (3, -2), the top 1.5 m above it
    bottom = t - R[:, 2] * size[2] / 2
    assert bottom @ up == pytest.approx(-1.7, abs=1e-12)
    np.testing.assert_allclose(bottom[:2], ground(3.0, -2.0)[:2], atol=1e-12)
    # the heading: world x on the ground turned by yaw (counter-clockwise seen from above)
    h0 = np.array([1.0, 0.0, 0.0]) - up[0] * up
    h0 /= np.linalg.norm(h0)
    assert float(np.clip(R[:, 0] @ h0, -1, 1)) == pytest.approx(math.cos(math.radians(yaw)), abs=1e-12)
    assert float(np.cross(h0, R[:, 0]) @ up) == pytest.approx(math.sin(math.radians(yaw)), abs=1e-12)


def test_the_place_is_named_along_the_two_world_axes_nearest_the_ground():
    assert ground_axes(np.array([0.0, 0.0, 1.0])) == (0, 1, 2)
    assert ground_axes(UP) == (0, 2, 1)  # y down: x and z
    # in a y-down scene the place (a, b) is world (a, ground, b) and yaw 0 lies along x
    pose = pose_on_ground((1.0, 7.0, 0.0), up=UP, box_size=np.array([1.6, 1.0, 1.6]), ground=_flat_ground)
    np.testing.assert_allclose(pose[:3, 3], [1.0, 2.0 - 0.8, 7.0])
    np.testing.assert_allclose(pose[:3, :3], np.stack([[1.0, 0, 0], np.cross(UP, [1.0, 0, 0]), UP], 1), atol=1e-12)
    g = ground_point(np.array([[0.0, 1.9, 7.0], [0.5, 2.0, 7.2]]), 0.2, 7.0, up=UP, reference=np.zeros(3))
    np.testing.assert_allclose(g[[0, 2]], [0.2, 7.0])
    assert g[1] == pytest.approx(2.0 - 0.05 * 0.1)  # the 5th percentile of the heights (y down: the lower is 2.0)


def test_the_ground_point_is_the_lowest_returns_height_below_x_y():
    g = np.random.default_rng(0)
    road = np.c_[g.uniform(-10, 10, (2000, 2)), g.normal(-1.8, 0.01, 2000)]  # z up, road 1.8 m down
    pole = np.c_[np.full((200, 2), 1.0), g.uniform(-1.8, 3.0, 200)]
    p = ground_point(np.concatenate([road, pole]), 1.5, 0.5, up=np.array([0.0, 0.0, 1.0]),
                     reference=np.array([0.0, 0.0, 0.0]))
    np.testing.assert_allclose(p[:2], [1.5, 0.5])
    assert p[2] == pytest.approx(-1.8, abs=0.03)  # the 5th percentile of the road's heights
    # no return near: 1.6 m below the reference camera
    far = ground_point(road, 50.0, 50.0, up=np.array([0.0, 0.0, 1.0]), reference=np.array([0.0, 0.0, 0.2]))
    assert far[2] == pytest.approx(-1.4)


#: The target's clear decoder: the identity shifted in logit.
CLEAR_SHIFT = torch.tensor([0.3, -0.2, 0.1])


def _two_scenes():
    """A source scene with a red car and a target whose car is blue, whose rain decoder darkens
    (identity shifted by -1 in logit) and whose clear decoder is not the identity."""
    source = wm.make_model(("clear", "rain"))
    target = wm.make_model(("clear", "rain"))
    with torch.no_grad():
        target.rigid[0].gaussians.features[:, :3] = color_logits(torch.tensor([[0.1, 0.2, 0.8]]).expand(64, 3))
        target.decoders.b2[1] -= 1.0
        target.decoders.b2[0] += CLEAR_SHIFT  # a clear decoder off the identity
    return source, target


def test_carried_features_give_the_objects_clear_colours_and_the_targets_rain():
    source, target = _two_scenes()
    car = source.rigid[0]
    with torch.no_grad():
        colors = source.decoders(car.gaussians.features, ["clear"])
    heights = torch.full((len(car.gaussians),), 0.5)
    feats, facts = carried_features(colors, heights, target, class_name="Car")
    with torch.no_grad():
        out = target.decoders(feats, ["clear", "rain"])
    # the exemplars (the target's blue car) are far off; the refinement brings the clear colour
    # within 0.01 of the object's own
    assert "64 Gaussians of the target's 1 vehicle object" in facts["exemplars"]
    assert facts["clear_error_exemplars"] > 0.1
    assert facts["clear_error"] < 0.01
    torch.testing.assert_close(out[:, :3], colors, atol=0.03, rtol=0)
    # the rain is the target's reading: its darker decoder, not the source's (the source's rain is
    # its clear: identity decoders)
    with torch.no_grad():
        # identity decoders: clear = sigmoid(f + CLEAR_SHIFT), rain = sigmoid(f - 1)
        expected = torch.sigmoid(torch.logit(out[:, :3].clamp(1e-4, 1 - 1e-4)) - CLEAR_SHIFT - 1.0)
        source_rain = source.decoders(car.gaussians.features, ["rain"])
    assert float((out[:, 3:] - source_rain).abs().mean()) > 0.05
    assert float((out[:, 3:] - expected).abs().mean()) < 0.05


@pytest.mark.parametrize("neighbours", [1, 5])
def test_exemplars_are_the_mean_of_the_nearest_and_come_from_every_node_when_the_class_is_rare(neighbours):
    source, target = _two_scenes()
    car = source.rigid[0]
    with torch.no_grad():
        colors = source.decoders(car.gaussians.features, ["clear"])
    with pytest.MonkeyPatch.context() as mp:
        import wcbench.reference_model.editing.transfer as transfer

        mp.setattr(transfer, "MIN_POOL", 100)
        feats, facts = carried_features(colors, torch.full((64,), 0.5), target, class_name="vehicle", steps=0,
                                        neighbours=neighbours)
    assert "every node of the target (it has 64 of class vehicle, fewer than 100)" in facts["exemplars"]
    # the twin: every pool Gaussian's distance in clear colour, sorted (no refinement: steps=0)
    with torch.no_grad():
        pool = torch.cat([p.features for p in target.nodes().values()])
        pool_colors = target.decoders(pool, ["clear"])
    d = torch.cdist(colors.double(), pool_colors.double())
    nearest = torch.argsort(d, dim=1, stable=True)[:, :neighbours]
    torch.testing.assert_close(feats, pool[nearest].mean(1), atol=1e-6, rtol=0)
    # the nearest in colour to a red car are the wall's reddest Gaussians, not the blue car's
    car_feats = target.rigid[0].gaussians.features.detach()
    assert not any(bool((car_feats == f).all(1).any()) for f in pool[nearest[:, 0]])


def _render_mask(model, placement, frame=1):
    hidden = Placement(hidden={"background"} | placement.hidden, offsets=placement.offsets, copies=placement.copies)
    with torch.no_grad():
        out = model.render(frame, wm.WORLD_TO_CAMERA, wm.K, wm.WIDTH, wm.HEIGHT, ("clear", "rain"),
                           sky_grid=wm.sky_grid(model), depth=True, placement=hidden)
    return out


def test_a_car_carried_in_stands_where_it_was_put_in_every_frame_and_edits_after_it_reach_it():
    source, target = _two_scenes()
    edits = parse_edits(["remove class=Car", "insert scene=src id=5 at=1.5,7,0"])
    objects, keys, facts = placed_objects(edits, target, n_frames=wm.N_FRAMES, up=UP, ground=_flat_ground,
                                          sources={"src": source})
    assert keys == {1: "rigid:src/5#1"} and facts[0]["carried"] and facts[0]["clear_error"] < 0.01
    model = target.with_objects(objects)
    place = placement_for(edits, model.objects(), placed=keys)
    assert place.hidden == {"rigid:5"}  # the remove came first: the carried car stays
    for frame in range(wm.N_FRAMES):
        out = _render_mask(model, place, frame)
        ys, xs = np.nonzero(out.alpha.numpy() > 0.5)
        # box centre at x = 1.5, 1.6 m above... the ground is at y = +2 (up is -y): centre y = 2 - 0.8,
        # 7 m ahead
        assert xs.mean() == pytest.approx(wm.WIDTH / 2 + wm.FOCAL * 1.5 / 7.0, abs=1.0)
        assert ys.mean() == pytest.approx(wm.HEIGHT / 2 + wm.FOCAL * 1.2 / 7.0, abs=1.0)
        rgb = out.images.numpy()[ys, xs]
        assert rgb[:, 0].mean() > 0.6 and rgb[:, 2].mean() < 0.3  # red, as in its own scene
        assert rgb[:, 3].mean() < rgb[:, 0].mean() - 0.1  # the target's darker rain
    # an edit after the insertion selects it too
    after = parse_edits(["insert scene=src id=5 at=1.5,7,0", "remove class=Car"])
    objects2, keys2, _ = placed_objects(after, target, n_frames=wm.N_FRAMES, up=UP, ground=_flat_ground,
                                        sources={"src": source})
    place2 = placement_for(after, target.with_objects(objects2).objects(), placed=keys2)
    assert place2.hidden == {"rigid:5", "rigid:src/5#0"}


def test_a_copy_of_this_scenes_car_keeps_its_features_and_errors_name_what_is_missing():
    model = wm.make_model(("clear", "rain"))
    edits = parse_edits("insert id=5 at=-1,8,45")
    objects, keys, facts = placed_objects(edits, model, n_frames=wm.N_FRAMES, up=UP, ground=_flat_ground)
    assert keys == {0: "rigid:5#0"} and facts[0]["carried"] is False
    assert torch.equal(objects[0].gaussians.features, model.rigid[0].gaussians.features)
    with pytest.raises(ValueError, match="not an object node"):
        placed_objects(parse_edits("insert id=9 at=0,5,0"), model, n_frames=3, up=UP, ground=_flat_ground)
    with pytest.raises(ValueError, match="no trained model of scene 'b'"):
        placed_objects(parse_edits("insert scene=b id=5 at=0,5,0"), model, n_frames=3, up=UP, ground=_flat_ground)
    with pytest.raises(ValueError, match="was not made"):
        placement_for(edits, model.objects())
    with pytest.raises(ValueError, match="already"):
        model.with_objects(objects).with_objects(objects)
