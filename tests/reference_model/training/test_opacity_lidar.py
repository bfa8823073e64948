"""The opacity loss's lidar term: a pixel a trusted lidar return lands in is pulled toward opacity 1
harder than any other non-sky pixel, so that thin structure against the sky (a wire, a mast) is the
Gaussians', not the sky map's (docs/findings.md, "WeatherCity's lidar hits as sky")."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from wcbench.reference_model.scene_analysis.analysis import analyse_scene  # noqa: E402
from wcbench.reference_model.training.config import make_config  # noqa: E402
from wcbench.reference_model.training.losses import LIDAR_OPAQUE, opacity_loss  # noqa: E402
from wcbench.reference_model.training.views import build_views, scaled_view  # noqa: E402

SIZE = (96, 54)


def _grad(alpha: np.ndarray, sky: np.ndarray | None, **kwargs) -> np.ndarray:
    a = torch.tensor(alpha, dtype=torch.float64, requires_grad=True)
    opacity_loss(a, None if sky is None else torch.from_numpy(sky), **kwargs).backward()
    assert a.grad is not None
    return a.grad.numpy()


def test_a_lidar_hit_pixel_is_pulled_toward_opacity_one_lidar_weight_times_harder_until_opaque():
    alpha = np.full((3, 4), 0.3)
    sky = np.zeros((3, 4), bool)
    sky[0] = True
    lidar = np.zeros((3, 4), bool)
    lidar[2, 1] = True
    entropy = _grad(alpha, None)  # the entropy term alone: the same at every pixel of the same opacity
    plain = _grad(alpha, sky, solid=True) - entropy
    pulled = _grad(alpha, sky, solid=True, lidar=torch.from_numpy(lidar), lidar_weight=10.0) - entropy
    assert plain[1, 1] < 0 and plain[0, 0] > 0  # non-sky pulled up, sky pushed down
    np.testing.assert_allclose(pulled[2, 1], 11.0 * plain[2, 1], rtol=1e-9)  # 1 + lidar_weight
    lidar_free = ~lidar
    np.testing.assert_allclose(pulled[lidar_free], plain[lidar_free], rtol=1e-9)  # nothing else moves
    # above LIDAR_OPAQUE the pixel is solid already: no extra pull
    opaque = np.full((3, 4), 0.5 * (1.0 + LIDAR_OPAQUE))
    np.testing.assert_allclose(_grad(opaque, sky, solid=True, lidar=torch.from_numpy(lidar), lidar_weight=10.0),
                               _grad(opaque, sky, solid=True), rtol=1e-12)
    # a weight of 0 or no mask is the loss as it was
    base = opacity_loss(torch.from_numpy(alpha), torch.from_numpy(sky), solid=True)
    assert float(opacity_loss(torch.from_numpy(alpha), torch.from_numpy(sky), solid=True,
                              lidar=torch.from_numpy(lidar), lidar_weight=0.0)) == pytest.approx(float(base))


def test_the_sky_push_scales_only_the_sky_pixels_gradient_and_one_is_the_papers_loss():
    rng = np.random.default_rng(3)
    alpha = rng.uniform(0.05, 0.95, (4, 5))
    sky = np.zeros((4, 5), bool)
    sky[:2] = True
    lidar = np.zeros((4, 5), bool)
    lidar[3, 2] = True
    kwargs = dict(solid=True, lidar=torch.from_numpy(lidar), lidar_weight=30.0)
    one = _grad(alpha, sky, **kwargs)
    entropy = _grad(alpha, None)
    heavy = _grad(alpha, sky, sky_weight=4.0, **kwargs)
    # the sky term's gradient, 1 / (1 - O) / (H W) at each sky pixel, four times as large
    np.testing.assert_allclose(heavy[sky] - entropy[sky], 4.0 * (one[sky] - entropy[sky]), rtol=1e-9)
    np.testing.assert_allclose(heavy[~sky], one[~sky], rtol=1e-12)
    np.testing.assert_allclose(one[sky] - entropy[sky], 1.0 / (1.0 - alpha[sky]) / alpha.size, rtol=1e-9)
    # 1 (the default) is the loss as it was before the weight, to the bit: the same terms in the
    # same order (a product with 1.0 is exact)
    o = torch.from_numpy(alpha).clamp(1e-6, 1 - 1e-6)
    m, lid = torch.from_numpy(sky).to(o.dtype), torch.from_numpy(lidar).to(o.dtype)
    before = (-(o * torch.log(o)).mean() - (m * torch.log(1 - o)).mean() - ((1.0 - m) * torch.log(o)).mean()
              - 30.0 * (lid * torch.log(o.clamp(max=LIDAR_OPAQUE))).mean())
    assert float(opacity_loss(torch.from_numpy(alpha), torch.from_numpy(sky), **kwargs)) == float(before)
    assert make_config("default").opacity_sky == 1.0
    with pytest.raises(ValueError, match="opacity_sky"):
        make_config("default", opacity_sky=-0.5)


def test_the_lidar_pull_is_a_bounded_setting_on_by_default():
    assert make_config("default").opacity_lidar == 30.0  # docs/findings.md, "Lidar fill"
    assert make_config("default").lidar_fill
    assert make_config("default", opacity_lidar=0.0).opacity_lidar == 0.0
    with pytest.raises(ValueError, match="opacity_lidar"):
        make_config("default", opacity_lidar=-1.0)


def test_training_views_mark_the_trusted_lidar_pixels_solid_never_sky_nor_the_ego_body(demo_scene):
    views, _ = build_views(demo_scene, size=SIZE, supervision={})
    analysis = analyse_scene(demo_scene)
    for v in views:
        assert v.solid is not None and v.solid.shape == (SIZE[1], SIZE[0])
        expected = analysis.solid_mask(v.frame, SIZE) & ~v.ignore
        if v.sky is not None:
            expected &= ~v.sky
            assert not (v.solid & v.sky).any()
        np.testing.assert_array_equal(v.solid, expected)
        assert v.solid.any()
        half = scaled_view(v, 2)  # progressive resolution keeps the mask at its size
        assert half.solid is not None and half.solid.shape == (half.height, half.width)
    unanalysed, _ = build_views(demo_scene, size=SIZE, supervision={}, derive_sky=False)
    assert all(v.solid is None for v in unanalysed)
    # only the lidar term reads the masks: without it they are not made, and nothing else changes
    unmarked, _ = build_views(demo_scene, size=SIZE, supervision={}, solid=False)
    assert all(v.solid is None for v in unmarked)
    for a, b in zip(views, unmarked):
        np.testing.assert_array_equal(a.sky, b.sky)
        np.testing.assert_array_equal(a.images["clear"], b.images["clear"])


@pytest.mark.parametrize(("weight", "fill"), [(0.0, False), (10.0, False), (0.0, True), (10.0, True)])
def test_a_training_makes_the_solid_masks_only_when_the_lidar_term_or_fill_reads_them(demo_scene, weight, fill):
    from wcbench.methods.scene_training import training_inputs

    config = make_config("default", width=SIZE[0], opacity_lidar=weight, lidar_fill=fill)
    inputs = training_inputs(demo_scene, config, supervision="filter2d", weathers=("fog",))
    assert all((v.solid is not None) == (weight > 0 or fill) for v in inputs.views)
    assert all((v.anchor_depth is not None) == fill for v in inputs.views)
