"""The lidar fill: a pixel a trusted static lidar return lands in that the render leaves below half
opacity gets a Gaussian at the return (``TrainConfig.lidar_fill``, docs/findings.md, "Lidar fill")."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from wcbench.methods.filter2d import Filter2DMethod  # noqa: E402
from wcbench.reference_model.model.gaussians import GaussianParams  # noqa: E402
from wcbench.reference_model.model.scene_model import BACKGROUND  # noqa: E402
from wcbench.reference_model.model.sky import view_directions  # noqa: E402
from wcbench.reference_model.scene_analysis.analysis import (  # noqa: E402
    _static_pool,
    _trusted_static,
    analyse_scene,
    anchor_depths,
)
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud  # noqa: E402
from wcbench.reference_model.training.build import build_model  # noqa: E402
from wcbench.reference_model.training.checkpoint import load_checkpoint, save_checkpoint  # noqa: E402
from wcbench.reference_model.training.config import make_config  # noqa: E402
from wcbench.reference_model.training.densify import (  # noqa: E402
    FILL_OPACITY,
    NodeOptimizer,
    append_gaussians,
    fill_from_lidar,
)
from wcbench.reference_model.training.trainer import Trainer  # noqa: E402
from wcbench.reference_model.training.views import build_views, scaled_view  # noqa: E402
from wcbench.reference_model.transforms import project_points  # noqa: E402

SIZE = (96, 54)
TINY = dict(width=SIZE[0], iterations=24, voxel_m=0.4, budget=20_000, densify_from=8, densify_until=20,
            densify_interval=8, checkpoint_interval=1000, far_points=False, content_interval=1,
            content_size=(48, 27))


@pytest.fixture(scope="module")
def anchored_views(demo_scene):
    f2d = Filter2DMethod(effects=False)
    edits = {"fog": [f2d.render_frame(demo_scene, "fog", k, seed=0) for k in range(len(demo_scene))]}
    views, _ = build_views(demo_scene, size=SIZE, supervision=edits, anchors=True)
    return views


def _trainer(scene, views, **settings) -> Trainer:
    config = make_config("quick", **{**TINY, **settings})
    model, _ = build_model(scene, [v for v in views if v.frame not in config.holdout], config,
                           weathers=("clear", "fog"))
    return Trainer(model, views, config)


def test_a_fill_gaussian_sits_on_its_pixels_ray_at_the_anchor_depth_in_the_pixels_colour():
    rng = np.random.default_rng(0)
    h, w = 9, 12
    K = np.array([[20.0, 0, 6.3], [0, 21.0, 4.1], [0, 0, 1]])
    angle = 0.3
    c2w = np.eye(4)
    c2w[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    c2w[:3, 3] = [1.0, -2.0, 5.0]
    depth = rng.uniform(2.0, 40.0, (h, w)).astype(np.float32)
    depth[0, :] = 0.0  # no anchor: nothing to place
    holes = rng.random((h, w)) < 0.5
    image = rng.random((h, w, 3)).astype(np.float32)
    cloud = fill_from_lidar(holes, depth, K, c2w, image)
    rows, cols = np.nonzero(holes & (depth > 0))
    assert len(cloud) == len(rows) > 0
    uv, z = project_points(cloud.means.astype(np.float64), np.linalg.inv(c2w), K)
    # float32 means: a few micro-pixels off the pixel centre at 40 m
    np.testing.assert_allclose(uv, np.stack([cols + 0.5, rows + 0.5], 1), atol=1e-3)
    np.testing.assert_allclose(z, depth[rows, cols], rtol=1e-5)
    np.testing.assert_allclose(cloud.colors, image[rows, cols])
    np.testing.assert_allclose(cloud.opacities, FILL_OPACITY)
    # half a pixel's footprint at the anchor's depth, the same on every axis
    np.testing.assert_allclose(cloud.scales, np.repeat(0.5 * depth[rows, cols, None] / K[0, 0], 3, 1), rtol=1e-6)
    with pytest.raises(ValueError, match="same"):
        fill_from_lidar(holes[1:], depth, K, c2w, image)


def test_anchor_depths_are_the_nearest_trusted_static_return_per_pixel_as_a_loop_finds_it(demo_scene):
    analysis = analyse_scene(demo_scene)
    frames = [0, len(demo_scene) // 2]
    maps = anchor_depths(analysis.views, analysis.returns, SIZE, frames)
    static, everything = _static_pool(analysis.returns)
    sx, sy = SIZE[0] / analysis.views.width, SIZE[1] / analysis.views.height
    for k, got in zip(frames, maps):
        assert got.shape == (SIZE[1], SIZE[0]) and got.dtype == np.float32
        slow = np.zeros_like(got)
        K = np.diag([sx, sy, 1.0]) @ analysis.views.K[k]
        uv, z = project_points(_trusted_static(analysis.views, static, everything, k),
                               analysis.views.world_to_camera(k), K)
        for (u, v), depth in zip(uv, z):
            i, j = int(np.floor(v)), int(np.floor(u))
            if depth > 0 and 0 <= i < SIZE[1] and 0 <= j < SIZE[0] and (slow[i, j] == 0 or depth < slow[i, j]):
                slow[i, j] = depth
        np.testing.assert_allclose(got, slow, rtol=1e-6)
        assert (got > 0).any()
        # the anchored pixels are the solid masks' static part: the masks project in float32 (relative
        # to the points' origin), the anchors in float64, so a return on a pixel's edge may fall on
        # either side; the training views keep the anchors inside their solid pixels (next test)
        own = anchor_depths(analysis.views, analysis.returns, analysis.views.size, [k])[0]
        assert ((own > 0) & ~analysis.solid[k]).sum() <= 0.002 * (own > 0).sum()


def test_training_views_anchor_only_their_solid_pixels_and_only_when_asked(demo_scene, anchored_views):
    for v in anchored_views:
        assert v.anchor_depth is not None and v.solid is not None
        assert not ((v.anchor_depth > 0) & ~v.solid).any()  # never sky, never the ego body
        assert (v.anchor_depth > 0).any()
        half = scaled_view(v, 2)
        assert half.anchor_depth is not None and half.anchor_depth.shape == (half.height, half.width)
    plain, _ = build_views(demo_scene, size=SIZE, supervision={})
    assert all(v.anchor_depth is None for v in plain)


def test_appended_gaussians_keep_the_old_rows_and_their_adam_moments_and_start_new_ones_at_zero():
    rng = np.random.default_rng(1)

    def cloud(n):
        return GaussianCloud(means=rng.normal(size=(n, 3)), quats=np.tile([1.0, 0, 0, 0], (n, 1)),
                             scales=np.full((n, 3), 0.1), opacities=np.full(n, 0.5), colors=rng.random((n, 3)))

    params = GaussianParams.from_cloud(cloud(5), feature_dim=4)
    opt = NodeOptimizer([(f"bg.{k}", p, 1e-2) for k, p in params.tensors().items()])
    sum(p.square().sum() for p in params.tensors().values()).backward()
    opt.step()
    old = {k: p.detach().clone() for k, p in params.tensors().items()}
    moments = opt.adam.state[params.means]["exp_avg"].clone()
    new = GaussianParams.from_cloud(cloud(3), feature_dim=4)
    assert append_gaussians("bg", params, opt, new) == 3
    assert len(params) == 8
    for k, p in params.tensors().items():
        np.testing.assert_array_equal(p[:5].detach().numpy(), old[k].numpy())
        np.testing.assert_array_equal(p[5:].detach().numpy(), getattr(new, k).detach().numpy())
    state = opt.adam.state[params.means]["exp_avg"]
    np.testing.assert_array_equal(state[:5].numpy(), moments.numpy())
    assert not state[5:].any()
    assert opt.group("bg.means")["params"][0] is params.means


def test_a_densification_fills_the_anchored_pixels_left_uncovered_and_they_are_covered_after(
        demo_scene, anchored_views):
    trainer = _trainer(demo_scene, anchored_views, densify_from=10**6, budget=10**6)  # no cap in reach
    v = trainer.train_views[0]
    assert v.anchor_depth is not None
    model = trainer.model

    def alpha() -> np.ndarray:
        with torch.no_grad():
            grid = model.sky.grid(torch.from_numpy(view_directions(v.camera_to_world, v.K, v.width, v.height)))
            return model.render(v.frame, v.world_to_camera, v.K, v.width, v.height, ["clear"], sky_grid=grid,
                                depth=False).alpha.numpy()

    before = alpha()
    holes = (before < 0.5) & (v.anchor_depth > 0)
    assert holes.sum() >= 5  # the lidar-initialised start is faint (opacity 0.1)
    trainer.holes = {v.frame: torch.from_numpy(holes)}
    n = len(model.background)
    record = trainer.densify()
    pruned = record.get(BACKGROUND, {}).get("pruned", 0)  # no gradient statistics: nothing cloned or split
    assert len(model.background) == n - pruned + record["lidar_fill"]
    assert record["lidar_fill"] == holes.sum()  # one per pixel: no two of its returns share a 2 cm cell
    assert trainer.holes == {}  # read once
    after = alpha()
    assert (after[holes] >= 0.5).all()
    # the budget's share bounds one densification's fill
    capped = _trainer(demo_scene, anchored_views, densify_from=10**6, budget=300)
    capped.holes = {v.frame: torch.from_numpy(v.anchor_depth > 0)}
    assert capped.densify()["lidar_fill"] == 3


def test_steps_record_the_holes_of_the_views_they_render_and_off_records_none(demo_scene, anchored_views):
    on = _trainer(demo_scene, anchored_views, densify_from=10**6)
    on.train(until=3)
    assert 1 <= len(on.holes) <= 3
    for frame, holes in on.holes.items():
        v = next(x for x in anchored_views if x.frame == frame)
        assert v.anchor_depth is not None
        assert not (holes.numpy() & ~(v.anchor_depth > 0)).any()
    off = _trainer(demo_scene, anchored_views, densify_from=10**6, lidar_fill=False)
    off.train(until=3)
    assert off.holes == {} and "lidar_fill" not in off.densify()


def test_resuming_with_holes_pending_gives_the_same_next_steps(demo_scene, anchored_views, tmp_path):
    whole = _trainer(demo_scene, anchored_views)
    whole.train(until=12)
    assert whole.holes  # the densification at step 16 reads them
    saved = {k: h.clone() for k, h in whole.holes.items()}
    save_checkpoint(whole, tmp_path / "ckpt")
    expected = [whole.step().loss for _ in range(6)]
    fresh = _trainer(demo_scene, anchored_views)
    resumed = load_checkpoint(tmp_path / "ckpt", model=fresh.model, views=anchored_views,
                              make_trainer=lambda m: Trainer(m, anchored_views, fresh.config))
    assert set(resumed.holes) == set(saved)
    for frame, holes in saved.items():
        assert torch.equal(resumed.holes[frame], holes)
    got = [resumed.step().loss for _ in range(6)]
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    assert len(resumed.model.background) == len(whole.model.background)
    assert any("lidar_fill" in r for r in resumed.densify_log)
