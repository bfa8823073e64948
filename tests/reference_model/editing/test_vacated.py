"""What a removed object leaves: the background it hid from every camera, refilled from the background
seen around it, and the ground laid where nothing was learned (docs/design.md §7, "What a removal
leaves, filled when it is made")."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from parked_car import CAMERAS, CAR_AT, CAR_SIZE, HEIGHT, RED, ROAD, UP, WIDTH, K, params, parked_car, scene  # noqa: E402

from wcbench.reference_model.editing.vacated import (  # noqa: E402
    fill_from_surroundings,
    hidden_by_objects,
    inside_boxes,
    object_boxes,
    object_cover,
    vacated_background,
)
from wcbench.reference_model.model.objects import RigidObject  # noqa: E402
from wcbench.reference_model.model.scene_model import BACKGROUND, Placement, WeatherCityModel  # noqa: E402
from wcbench.reference_model.raster.rasterizer import rasterize_image  # noqa: E402

pytestmark = pytest.mark.model


def _background(model: WeatherCityModel, camera: tuple) -> tuple[np.ndarray, np.ndarray]:
    """(clear colours [H, W, 3], alpha [H, W]) of the background alone."""
    _, w2c, K_, w, h = camera
    with torch.no_grad():
        g = model.frame_gaussians(camera[0], Placement(hidden={"rigid:7"}))
        colors = model.decoders(model.background.features, ["clear"])
        out = rasterize_image(g.means, g.quats, g.scales, g.opacities, colors, w2c, K_, w, h)
    return out.color.numpy(), out.alpha.numpy()


def test_a_point_behind_the_car_in_most_views_is_hidden_one_beside_or_before_it_is_not():
    car = parked_car()
    covers = [object_cover([car], f, w2c, K_, w, h) for f, w2c, K_, w, h in CAMERAS]
    views = [(w2c, K_, w, h) for _, w2c, K_, w, h in CAMERAS]
    points = np.array([[13.0, 0.0, 0.05], [13.0, 5.0, 0.0], [6.0, 0.0, 0.0], [60.0, 40.0, 0.0]])
    hidden = hidden_by_objects(points, views, covers, covers)
    np.testing.assert_array_equal(hidden, [True, False, False, False])  # behind, beside, before, out of view
    # a camera off to the side, past the car, sees the point behind it: not hidden any more
    side = np.eye(4)
    side[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # looking along +y
    side[:3, 3] = [13.0, -8.0, 1.6]
    extra = (3, np.linalg.inv(side), K, WIDTH, HEIGHT)
    car3 = RigidObject(car.gaussians, track_id="7", class_name="Car", frames=np.arange(4),
                       object_to_world=np.tile(object_boxes([car])[0][0], (4, 1, 1)), box_size=CAR_SIZE, n_frames=4)
    cover3 = object_cover([car3], 3, extra[1], K, WIDTH, HEIGHT)
    args = ([*views, extra[1:]], [*covers, cover3], [*covers, cover3])
    # by default a point is hidden while most views saw it through an object: one side view of four
    # does not free it; asked for every view (share 1), it does
    assert hidden_by_objects(points, *args)[0]
    assert not hidden_by_objects(points, *args, share=1.0)[0]
    with pytest.raises(ValueError, match="per camera"):
        hidden_by_objects(points, views, covers[:2], covers)


def test_a_hidden_row_takes_the_shepard_mean_of_its_nearest_seen_rows_heights_stretched():
    # the slow twin: every distance computed, the nearest taken by a full sort
    g = np.random.default_rng(3)
    means = g.uniform(-5, 5, (400, 3))
    features = g.normal(size=(400, 6)).astype(np.float32)
    hidden = g.random(400) < 0.3
    for k, stretch in ((1, 1.0), (5, 1.0), (8, 4.0)):
        fast = fill_from_surroundings(features, means, hidden, neighbours=k, up=UP, vertical_weight=stretch)
        scaled = means * np.array([1.0, 1.0, stretch])
        seen = np.flatnonzero(~hidden)
        for i in np.flatnonzero(hidden):
            d = np.linalg.norm(scaled[seen] - scaled[i], axis=1)
            near = np.argsort(d, kind="stable")[:k]
            w = 1.0 / np.maximum(d[near], 1e-3) ** 2
            np.testing.assert_allclose(fast[i], (w @ features[seen][near]) / w.sum(), rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(fast[~hidden], features[~hidden])
    with pytest.raises(ValueError, match="neighbours"):
        fill_from_surroundings(features, means, hidden, neighbours=0)
    with pytest.raises(ValueError, match="hidden"):
        fill_from_surroundings(features, means, hidden[:-1])


def test_removing_the_car_leaves_road_where_it_stood_not_its_red_nor_the_sky():
    model, stained = scene()
    filled, facts = vacated_background(model, ["rigid:7"], CAMERAS, up=UP)
    assert facts["hidden_gaussians"] >= int(stained.sum()) and facts["ground_tiles"] > 0
    # the red strip the car's pixels trained: road now
    with torch.no_grad():
        strip = filled.decoders(filled.background.features[: len(stained)][torch.from_numpy(stained)], ["clear"])
    np.testing.assert_allclose(strip.numpy(), np.tile(ROAD, (int(stained.sum()), 1)), atol=0.02)
    for camera in CAMERAS:
        silhouette = np.isfinite(object_cover([model.objects()["rigid:7"]], camera[0], *camera[1:]))
        _, alpha_before = _background(model, camera)
        after, alpha_after = _background(filled, camera)
        below = silhouette.copy()
        below[: HEIGHT // 2 + 1] = False  # under the horizon (the camera looks level)
        assert (alpha_before[below] < 0.5).mean() > 0.1  # the hole the removed car leaves
        assert alpha_after[below].min() > 0.5
        colour = after[below] / alpha_after[below, None]
        assert np.abs(colour - ROAD).max() < 0.05, "road, not the car's red, where it stood"
    # the nodes, decoders and sky are shared; nothing vacated gives the model itself
    assert filled.objects()["rigid:7"] is model.objects()["rigid:7"] and filled.decoders is model.decoders
    assert filled.nodes()[BACKGROUND] is not model.background
    assert vacated_background(model, [], CAMERAS, up=UP)[0] is model
    with pytest.raises(ValueError, match="not objects"):
        vacated_background(model, ["rigid:99"], CAMERAS, up=UP)


def test_a_box_grown_by_its_margin_takes_what_stands_in_it_and_leaves_the_ground():
    # the slow twin: a yawed box's eight faces tested one by one
    pose = np.eye(4)
    yaw = 0.6
    pose[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
    pose[:3, 3] = [3.0, -2.0, 0.75]
    size = np.array([4.5, 1.8, 1.5])
    points = np.random.default_rng(5).uniform([-1.0, -6.0, -0.3], [7.0, 2.0, 2.2], (4000, 3))
    got = inside_boxes(points, [(pose, size)], up=UP, margin_m=0.3, floor_m=0.2)
    local = (points - pose[:3, 3]) @ pose[:3, :3]
    slow = np.ones(len(points), bool)
    for axis in range(3):
        slow &= (local[:, axis] >= -size[axis] / 2 - 0.3) & (local[:, axis] <= size[axis] / 2 + 0.3)
    slow &= points[:, 2] >= 0.0 + 0.2  # the box's bottom face lies on z = 0
    np.testing.assert_array_equal(got, slow)
    assert 100 < got.sum() < len(points) - 100
    assert not inside_boxes(points, [], up=UP).any()
    with pytest.raises(ValueError, match="at least 0"):
        inside_boxes(points, [(pose, size)], up=UP, margin_m=-0.1)


def test_the_colour_a_removed_car_left_before_its_box_is_refilled_though_no_view_saw_it_through_the_car():
    model, _ = scene()
    # a red Gaussian 0.15 m before the car's front at its bumper's height (what it painted there,
    # trained on its pixels), nearer than the car to every camera, so no view sees it through the car
    bumper = np.array([[CAR_AT[0] - CAR_SIZE[0] / 2 - 0.15, 0.0, 0.6]])
    extra = params(bumper, RED[None], 0.1)
    bg = model.background
    with_bumper = model.with_background(type(bg)(*(torch.cat([a.detach(), b]) for a, b in zip(
        (bg.means, bg.log_scales, bg.quats, bg.opacity_logits, bg.features),
        (extra.means, extra.log_scales, extra.quats, extra.opacity_logits, extra.features)))))
    car = with_bumper.objects()["rigid:7"]
    covers = [object_cover([car], f, w2c, K_, w, h) for f, w2c, K_, w, h in CAMERAS]
    views = [(w2c, K_, w, h) for _, w2c, K_, w, h in CAMERAS]
    assert not hidden_by_objects(bumper, views, covers, covers)[0]
    for margin, red_left in ((0.3, False), (0.1, True)):
        filled, _ = vacated_background(with_bumper, ["rigid:7"], CAMERAS, up=UP, box_margin_m=margin)
        with torch.no_grad():
            colour = filled.decoders(filled.background.features[len(bg): len(bg) + 1], ["clear"]).numpy()[0]
        if red_left:  # outside a margin of 0.1 m: kept as trained
            np.testing.assert_allclose(colour, RED, atol=0.02)
        else:
            np.testing.assert_allclose(colour, ROAD, atol=0.02)
