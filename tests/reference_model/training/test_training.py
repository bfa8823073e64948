"""Multi-weather training on the demo street: it learns, ablations differ, a killed run resumes exactly."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import torch.nn.functional as F  # noqa: E402

from wcbench.methods.filter2d import Filter2DMethod  # noqa: E402
from wcbench.reference_model.model.objects import NonRigidObject  # noqa: E402
from wcbench.reference_model.training.build import build_model  # noqa: E402
from wcbench.reference_model.training.checkpoint import load_checkpoint, save_checkpoint  # noqa: E402
from wcbench.reference_model.training.config import make_config  # noqa: E402
from wcbench.reference_model.training.losses import ContentLoss, training_ssim  # noqa: E402
from wcbench.reference_model.training.trainer import Trainer, evaluate_views  # noqa: E402
from wcbench.reference_model.training.views import build_views  # noqa: E402

pytestmark = pytest.mark.model

SIZE = (96, 54)
#: Small, fast settings: the demo street at 96x54, 120 steps.
TINY = dict(width=SIZE[0], iterations=120, voxel_m=0.4, budget=20_000, densify_from=40, densify_until=100,
            densify_interval=30, checkpoint_interval=1000, far_points=False, content_interval=1,
            content_size=(48, 27))


@pytest.fixture(scope="module")
def demo(demo_scene):
    return demo_scene


@pytest.fixture(scope="module")
def demo_views(demo):
    f2d = Filter2DMethod(effects=False)
    edits = {"fog": [f2d.render_frame(demo, "fog", k, seed=0) for k in range(len(demo))]}
    views, _ = build_views(demo, size=SIZE, supervision=edits)
    return views


def _trainer(demo, views, *, content=None, **settings) -> Trainer:
    config = make_config("quick", **{**TINY, **settings})
    train_views = [v for v in views if v.frame not in config.holdout]
    model, _ = build_model(demo, train_views, config, weathers=("clear", "fog"))
    return Trainer(model, views, config, content=content)


class _TinyFeatures(torch.nn.Module):
    """A small fixed convolution network standing in for VGG16 features."""

    def __init__(self):
        super().__init__()
        torch.manual_seed(0)
        self.conv = torch.nn.Conv2d(3, 8, 3, padding=1)

    def forward(self, x):
        return [torch.relu(self.conv(x))]


def test_a_tiny_scene_trains_to_a_stated_psnr_and_the_loss_decreases(demo, demo_views):
    trainer = _trainer(demo, demo_views, holdout=(5,), content=ContentLoss(_TinyFeatures(), size=(48, 27)))
    before = evaluate_views(trainer.model, trainer.train_views)["mean_psnr"]
    logs = trainer.train()
    after = evaluate_views(trainer.model, trainer.train_views)["mean_psnr"]
    held = evaluate_views(trainer.model, [v for v in demo_views if v.frame == 5])["mean_psnr"]
    first = np.mean([s.loss for s in logs[:20]])
    last = np.mean([s.loss for s in logs[-20:]])
    assert last < 0.8 * first
    # measured: 21.4 dB before, 30.4 dB after 120 steps (2.3 s), 31.0 dB on the held-out frame
    assert after > before + 6.0
    assert after > 28.5, f"train PSNR {after:.2f} dB (was {before:.2f})"
    assert held > 28.0, f"held-out PSNR {held:.2f} dB"
    assert any("content" in s.terms for s in logs) and any("fog" in "".join(s.terms) for s in logs)
    assert trainer.densify_log, "densification ran"


def test_no_wgs_shares_one_decoder_and_trains_to_other_colors(demo, demo_views):
    full = _trainer(demo, demo_views, iterations=30)
    ablated = _trainer(demo, demo_views, iterations=30, shared_decoder=True)
    assert full.model.decoders.w1.shape[0] == 2 and ablated.model.decoders.w1.shape[0] == 1
    full.train()
    ablated.train()
    v = demo_views[0]
    from_full = full.model.decoders(full.model.background.features, ["clear", "fog"]).detach()
    from_ablated = ablated.model.decoders(ablated.model.background.features, ["clear", "fog"]).detach()
    # one decoder: fog = clear (up to the GEMM's summation order)
    torch.testing.assert_close(from_ablated[:, :3], from_ablated[:, 3:], atol=1e-6, rtol=0)
    assert (from_full[:, :3] - from_full[:, 3:]).abs().mean() > 0.02  # fog learned apart
    assert v.images["fog"].mean() > v.images["clear"].mean()


def test_resuming_from_a_checkpoint_gives_the_same_next_step_loss(demo, demo_views, tmp_path):
    # densification (clone, split, prune with its random split samples) falls inside both halves
    settings = dict(iterations=24, densify_from=8, densify_until=20, densify_interval=8)
    whole = _trainer(demo, demo_views, **settings)
    whole.train(until=12)
    save_checkpoint(whole, tmp_path / "ckpt")
    expected = [whole.step().loss for _ in range(4)]

    fresh = _trainer(demo, demo_views, **settings)
    resumed = load_checkpoint(tmp_path / "ckpt", model=fresh.model, views=demo_views,
                              make_trainer=lambda m: Trainer(m, demo_views, fresh.config))
    assert resumed.step_index == 12
    got = [resumed.step().loss for _ in range(4)]
    np.testing.assert_allclose(got, expected, rtol=1e-5)


def test_the_centres_learning_rate_decays_exponentially_to_its_final_fraction(demo, demo_views):
    trainer = _trainer(demo, demo_views, iterations=8, means_lr_final=0.01, densify_from=10**6)
    group = trainer.optimizer.group("background.means")
    start = trainer.config.lr["means"] * trainer.extent
    rates = []
    for _ in range(8):
        trainer.step()
        rates.append(group["lr"])
    # the rate used at step k is start * 0.01 ** (k / 8)
    np.testing.assert_allclose(rates, [start * 0.01 ** (k / 8) for k in range(8)], rtol=1e-12)
    assert trainer.optimizer.group("background.features")["lr"] == trainer.config.lr["features"]


def test_a_scaled_config_scales_the_iterations_and_the_densification_schedule():
    config = make_config("default")
    half = config.scaled(0.5)
    assert (half.iterations, half.densify_from, half.densify_until, half.densify_interval) == (
        config.iterations // 2, config.densify_from // 2, config.densify_until // 2, config.densify_interval // 2)
    assert half.lr == config.lr and half.budget == config.budget
    with pytest.raises(ValueError, match="fraction"):
        config.scaled(0)


def test_a_scene_without_pedestrians_builds_no_nonrigid_node_and_runs_no_deformation(demo, demo_views, monkeypatch):
    config = make_config("quick", **TINY)
    model, facts = build_model(demo, demo_views, config, weathers=("clear", "fog"))
    assert len(model.nonrigid) == 0 and model.counts()["nonrigid"] == 0
    assert "not built" in facts["skipped"]["nonrigid_nodes"]

    def boom(*_a, **_k):
        raise AssertionError("deformation code ran")

    monkeypatch.setattr(NonRigidObject, "local_means", boom)
    monkeypatch.setattr(NonRigidObject, "deformation_penalty", boom)
    trainer = Trainer(model, demo_views, config)
    log = trainer.step()
    assert "deform" not in log.terms


def test_separable_training_ssim_equals_the_2d_window():
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(40, 50, 6, generator=g, dtype=torch.float64), torch.rand(40, 50, 6, generator=g,
                                                                               dtype=torch.float64)
    x = torch.arange(11, dtype=torch.float64) - 5
    w1 = torch.exp(-(x**2) / (2 * 1.5**2))
    w1 = w1 / w1.sum()
    win = (w1[:, None] * w1[None, :]).expand(6, 1, 11, 11)

    def blur(t):
        return F.conv2d(t.permute(2, 0, 1)[None], win, padding=5, groups=6)

    mx, my = blur(a), blur(b)
    vx, vy, cxy = blur(a * a) - mx**2, blur(b * b) - my**2, blur(a * b) - mx * my
    c1, c2 = 0.01**2, 0.03**2
    ref = (((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2))).mean(dim=(0, 2, 3))
    torch.testing.assert_close(training_ssim(a, b), ref, atol=1e-12, rtol=0)


def test_a_step_times_its_phases_and_train_sizes_the_thread_pools_for_its_run(demo, demo_views):
    from wcbench.reference_model.raster.threads import get_threads

    trainer = _trainer(demo, demo_views, iterations=2, densify_from=10**6)
    trainer.threads = 1
    before = get_threads()
    seen = []
    logs = trainer.train(callback=lambda log: seen.append(get_threads()["numba"]))
    assert seen == [1, 1] and get_threads() == before
    log = logs[-1]
    assert list(log.phase_ms) == ["data", "render", "losses", "backward", "stats", "optimizer", "densify", "log"]
    assert all(v >= 0 for v in log.phase_ms.values())
    assert sum(log.phase_ms.values()) == pytest.approx(1e3 * log.seconds, rel=1e-6)
    assert {"project", "sort", "bin", "fwd_blend", "bwd_blend", "bwd_reduce", "bwd_project"} <= set(log.raster_ms)


def test_the_weather_weight_scales_each_edited_weathers_rgb_loss_and_one_is_the_papers_sum(demo, demo_views):
    settings = dict(iterations=2, densify_from=10**6, opacity_weight=0.0, depth_weight=0.0)
    paper, light = _trainer(demo, demo_views, **settings), _trainer(demo, demo_views, weather_weight=0.25, **settings)
    assert paper._weather_step(0) and not paper._weather_step(1)  # quick: every 2nd step
    a, b = paper.step(), light.step()
    # the same model and view: the same terms; the total takes the fog term at a quarter
    assert a.terms == b.terms and set(a.terms) == {"rgb_clear", "rgb_fog"}
    assert a.loss == pytest.approx(a.terms["rgb_clear"] + a.terms["rgb_fog"], rel=1e-6)
    assert b.loss == pytest.approx(b.terms["rgb_clear"] + 0.25 * b.terms["rgb_fog"], rel=1e-6)
    # a clear-only step has nothing to weight (the two models differ after one update, so each is
    # checked against its own terms)
    c = light.step()
    assert set(c.terms) == {"rgb_clear"} and c.loss == pytest.approx(c.terms["rgb_clear"], rel=1e-6)
    assert make_config("default").weather_weight == 1.0
    with pytest.raises(ValueError, match="weather_weight"):
        make_config("default", weather_weight=-1.0)
