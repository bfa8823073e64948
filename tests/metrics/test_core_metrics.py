"""PSNR, SSIM, temporal flicker and flow warping error: definitions, references, edge cases."""

from __future__ import annotations

import numpy as np
import pytest
from metric_tester import check_metric
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from wcbench.core.image_io import read_rgb8, to_float
from wcbench.metrics import flow_warp_error, psnr, ssim, temporal_flicker
from wcbench.metrics.base import MetricContext
from wcbench.metrics.fps import FPS
from wcbench.metrics.pixel.psnr import PSNR
from wcbench.metrics.pixel.ssim import SSIM
from wcbench.metrics.temporal.flicker import FlowWarpingError, TemporalFlicker, consistency_mask, dis_flow, warp

#: DESIGN §5: our SSIM equals skimage's with these settings to 1e-12.
SSIM_SKIMAGE_ATOL = 1e-12


def _skimage_ssim(a, b):
    return structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                 data_range=1, channel_axis=-1)


@pytest.mark.parametrize("shape", [(11, 11, 3), (37, 53, 3), (64, 48, 3)])
def test_ssim_equals_skimage_on_random_images(rng, shape):
    a = rng.random(shape)
    b = np.clip(a + 0.2 * rng.standard_normal(shape), 0, 1)
    assert abs(ssim(a, b) - _skimage_ssim(a, b)) < SSIM_SKIMAGE_ATOL


def test_ssim_equals_skimage_on_real_frames(pandaset_root):
    a = to_float(read_rgb8(pandaset_root / "images" / "000_0.jpg")).astype(np.float64)[::4, ::4]
    b = to_float(read_rgb8(pandaset_root / "images" / "005_0.jpg")).astype(np.float64)[::4, ::4]
    assert abs(ssim(a, b) - _skimage_ssim(a, b)) < SSIM_SKIMAGE_ATOL


def test_ssim_rejects_tiny_images(rng):
    with pytest.raises(ValueError, match="at least 11 px"):
        ssim(rng.random((8, 20, 3)), rng.random((8, 20, 3)))


def test_psnr_matches_skimage_and_closed_form(rng):
    a = rng.random((20, 30, 3))
    b = np.clip(a + 0.05, 0, 1)
    assert psnr(a, b) == pytest.approx(peak_signal_noise_ratio(a, b, data_range=1), abs=1e-10)
    flat = np.full((4, 4, 3), 0.5)
    assert psnr(flat, flat + 0.1) == pytest.approx(20.0, abs=1e-9)  # 10 log10(1 / 0.01)
    assert psnr(flat, flat) == float("inf")


def test_shape_mismatch_names_both_shapes(rng):
    with pytest.raises(ValueError, match=r"\(1, 4, 4, 3\).*\(1, 5, 4, 3\)"):
        psnr(rng.random((4, 4, 3)), rng.random((5, 4, 3)))


def test_temporal_flicker_closed_form():
    seq = np.zeros((3, 4, 4, 3))
    seq[1] = 0.5
    assert temporal_flicker(seq) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="at least 2 frames"):
        temporal_flicker(seq[:1])


def _translated_sequence(n=4, shift=3, size=(96, 128)):
    rng = np.random.default_rng(0)
    import cv2

    base = cv2.GaussianBlur(rng.random((size[0], size[1] + n * shift, 3)).astype(np.float32), (0, 0), 2.0)
    base = (base - base.min()) / (base.max() - base.min())
    # content moves left by `shift` px per frame
    return np.stack([base[:, k * shift : k * shift + size[1]] for k in range(n)])


def test_dis_flow_recovers_a_translation():
    seq = _translated_sequence()
    flow = dis_flow(seq[0], seq[1])
    core = flow[10:-10, 10:-10]
    assert np.median(core[..., 0]) == pytest.approx(-3.0, abs=0.1)
    assert np.median(core[..., 1]) == pytest.approx(0.0, abs=0.1)


def test_flow_warp_error_zero_on_static_and_small_on_translation():
    seq = _translated_sequence()
    static = np.repeat(seq[:1], 4, axis=0)
    assert flow_warp_error(static) == pytest.approx(0.0, abs=1e-12)
    assert flow_warp_error(seq) < 1e-3
    # an edit that does not move with the scene is penalised
    frozen_edit = np.repeat(seq[:1], 4, axis=0)
    assert flow_warp_error(frozen_edit, seq) > 10 * flow_warp_error(seq)


def test_consistency_mask_flags_inconsistent_flow_and_borders():
    h, w = 20, 30
    fwd = np.zeros((h, w, 2), np.float32)
    fwd[..., 0] = 2.0
    bwd = -fwd.copy()
    mask = consistency_mask(fwd, bwd)
    assert mask[:, : w - 3].all() and not mask[:, w - 2 :].any()  # targets past the right edge
    bad_bwd = bwd.copy()
    bad_bwd[5:10, 5:10] = 5.0
    assert not consistency_mask(fwd, bad_bwd)[5:8, 4:8].any()


def test_warp_samples_at_i_plus_flow():
    img = np.arange(12, dtype=np.float32).reshape(3, 4, 1)
    flow = np.zeros((3, 4, 2), np.float32)
    flow[..., 0] = 1.0
    np.testing.assert_allclose(warp(img, flow)[:, :3, 0], img[:, 1:, 0])


@pytest.mark.parametrize(
    ("factory", "needs"),
    [(PSNR, "reference"), (SSIM, "reference"), (TemporalFlicker, "source"), (FlowWarpingError, "source")],
)
def test_shared_metric_tester(factory, needs):
    seq = _translated_sequence(n=4, size=(32, 40)).astype(np.float64)
    noisy = np.clip(seq + 0.05 * np.random.default_rng(1).standard_normal(seq.shape), 0, 1)
    kw = {"reference": seq} if needs == "reference" else {"source": seq}
    check_metric(factory, noisy, **kw)


@pytest.mark.parametrize("factory", [PSNR, SSIM, TemporalFlicker, FlowWarpingError])
@pytest.mark.parametrize("case", ["constant", "identical", "one_frame"])
def test_metrics_finite_or_null_with_reason_on_edge_input(factory, case):
    const = np.full((2, 16, 16, 3), 0.3)
    pred = const if case != "one_frame" else const[:1]
    other = pred.copy() if case != "constant" else np.full_like(pred, 0.7)
    m = factory()
    ctx = MetricContext(weather="clear", n_frames=len(pred), has_reference=True)
    if m.skip_reason(ctx):
        assert case == "one_frame" and m.min_frames == 2
        return
    check_metric(factory, pred, source=other, reference=other)


def test_fps_from_info_or_override_or_skipped():
    m = FPS()
    assert "no timing" in m.skip_reason(MetricContext("rain", 3, False))
    ctx = MetricContext("rain", 3, False, method_info={"timings": {"fps": 12.5, "resolution": [4, 3]}})
    assert m.skip_reason(ctx) is None
    assert m.compute()["fps"].value == 12.5
    m.bind(MetricContext("rain", 3, False, method_info={"timings": {"fps": 12.5}}, fps_override=2.0))
    assert m.compute()["fps"].value == 2.0


def test_content_metrics_skip_in_fog_reference_metrics_without_truth():
    fog = MetricContext(weather="fog", n_frames=5, has_reference=False)
    assert "ground-truth" in PSNR().skip_reason(fog)
    assert TemporalFlicker().skip_reason(fog) is None


def _reference_mask(forward, backward):
    """The slow twin of consistency_mask: float64 throughout, numpy's own gradient."""
    h, w = forward.shape[:2]
    f = forward.astype(np.float64)
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    tx, ty = gx + f[..., 0], gy + f[..., 1]
    inside = (tx >= 0) & (tx <= w - 1) & (ty >= 0) & (ty <= h - 1)
    b = warp(backward.astype(np.float32), forward.astype(np.float32)).astype(np.float64)
    occluded = ((f + b) ** 2).sum(-1) > 0.01 * ((f**2).sum(-1) + (b**2).sum(-1)) + 0.5
    dby, dbx = np.gradient(b, axis=(0, 1))
    boundary = (dbx**2).sum(-1) + (dby**2).sum(-1) > 0.01 * (b**2).sum(-1) + 0.002
    return inside & ~occluded & ~boundary


#: float32 vs float64 flips only pixels sitting on a threshold.
MASK_MAX_DISAGREEMENT = 1e-3


def test_fast_mask_and_error_match_float64_twin(rng):
    import cv2

    h, w = 90, 120
    fwd = cv2.GaussianBlur(rng.normal(0, 8, (h, w, 2)).astype(np.float32), (0, 0), 6) * 2
    bwd = -fwd + cv2.GaussianBlur(rng.normal(0, 1.5, (h, w, 2)).astype(np.float32), (0, 0), 2)
    fast, slow = consistency_mask(fwd, bwd), _reference_mask(fwd, bwd)
    assert 0.1 < slow.mean() < 0.98  # a mix of valid and masked pixels
    assert np.mean(fast != slow) < MASK_MAX_DISAGREEMENT
    v0, v1 = rng.random((h, w, 3)), rng.random((h, w, 3))
    from wcbench.metrics.temporal.flicker import warp_error_pair

    d = v0 - warp(v1.astype(np.float32), fwd).astype(np.float64)
    ref = ((d**2).sum(-1) * slow).sum() / slow.sum()
    assert warp_error_pair(v0, v1, fwd, slow) == pytest.approx(ref, rel=1e-6)


def test_source_flow_is_computed_once_across_weathers():
    from wcbench.metrics.temporal.flicker import FLOW_CACHE

    seq = _translated_sequence(n=3, size=(40, 48))
    before = FLOW_CACHE.misses
    for edit in (seq * 0.9, seq * 0.8):  # two "weathers" of the same source
        m = FlowWarpingError()
        m.update(edit, source=seq)
    assert FLOW_CACHE.misses - before == 2  # two frame pairs, flowed once each
