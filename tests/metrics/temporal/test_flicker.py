"""Temporal flicker and flow warping error: closed forms, flows, occlusion masks, the fast path's twin,
the shared source-flow cache."""

from __future__ import annotations

import numpy as np
import pytest
from sequences import translated_sequence

from wcbench.metrics import flow_warping_error, temporal_flicker
from wcbench.metrics.temporal.flicker import FlowWarpingError, consistency_mask, dis_flow, warp

#: docs/design.md §5: our SSIM equals skimage's with these settings to 1e-12.
SSIM_SKIMAGE_ATOL = 1e-12


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


def test_temporal_flicker_closed_form():
    seq = np.zeros((3, 4, 4, 3))
    seq[1] = 0.5
    assert temporal_flicker(seq) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="at least 2 frames"):
        temporal_flicker(seq[:1])


def test_dis_flow_recovers_a_translation():
    seq = translated_sequence()
    flow = dis_flow(seq[0], seq[1])
    core = flow[10:-10, 10:-10]
    assert np.median(core[..., 0]) == pytest.approx(-3.0, abs=0.1)
    assert np.median(core[..., 1]) == pytest.approx(0.0, abs=0.1)


def test_flow_warping_error_zero_on_static_and_small_on_translation():
    seq = translated_sequence()
    static = np.repeat(seq[:1], 4, axis=0)
    assert flow_warping_error(static) == pytest.approx(0.0, abs=1e-12)
    assert flow_warping_error(seq) < 1e-3
    # an edit that does not move with the scene is penalised
    frozen_edit = np.repeat(seq[:1], 4, axis=0)
    assert flow_warping_error(frozen_edit, seq) > 10 * flow_warping_error(seq)


def test_flow_warp_error_is_a_deprecated_alias_of_the_metric_name():
    import wcbench.metrics as m
    from wcbench.metrics.temporal import flicker

    seq = translated_sequence(n=3)
    with pytest.warns(DeprecationWarning, match="flow_warp_error is deprecated, use flow_warping_error"):
        assert m.flow_warp_error(seq) == flow_warping_error(seq)
    with pytest.warns(DeprecationWarning, match="use flow_warping_errors"):
        np.testing.assert_array_equal(flicker.flow_warp_errors(seq), flicker.flow_warping_errors(seq))


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

    seq = translated_sequence(n=3, size=(40, 48))
    before = FLOW_CACHE.misses
    for edit in (seq * 0.9, seq * 0.8):  # two "weathers" of the same source
        m = FlowWarpingError()
        m.update(edit, source=seq)
    assert FLOW_CACHE.misses - before == 2  # two frame pairs, flowed once each


def test_pairs_in_worker_threads_give_the_one_thread_values_in_order(monkeypatch):
    from wcbench.core.parallel import THREADS_ENV
    from wcbench.metrics.temporal.flicker import FLOW_CACHE

    seq = translated_sequence(n=7, size=(48, 64))
    edit = np.clip(seq * 0.85 + 0.05 * np.sin(np.arange(7))[:, None, None, None], 0, 1).astype(np.float32)
    per_pair = {}
    for threads in ("1", "4"):
        monkeypatch.setenv(THREADS_ENV, threads)
        FLOW_CACHE.clear()
        m = FlowWarpingError()
        m.update(edit[:4], source=seq[:4])  # two batches: the pair across them too
        m.update(edit[4:], source=seq[4:])
        per_pair[threads] = (list(m._pred), list(m._src))
    assert len(per_pair["1"][0]) == 6
    assert per_pair["1"] == per_pair["4"]  # each pair is computed alone: the same bits


# ---- numeric guards (docs/design.md §9) -------------------------------------------------------


@pytest.mark.parametrize("n", [0, 1])
def test_fewer_than_two_frames_one_rule_for_both_metrics(n):
    from wcbench.metrics.base import MetricContext
    from wcbench.metrics.temporal.flicker import TemporalFlicker

    seq = np.zeros((n, 16, 16, 3))
    for fn in (temporal_flicker, flow_warping_error):
        with pytest.raises(ValueError, match=f"needs at least 2 frames, got {n}"):
            fn(seq)
    ctx = MetricContext(weather="rain", n_frames=n, has_reference=False)
    for metric in (TemporalFlicker(), FlowWarpingError()):
        assert "needs at least 2 frames" in metric.skip_reason(ctx)
        metric.update(seq, source=seq)
        for name, value in metric.compute().items():
            assert value.value is None and value.reason == f"needs at least 2 frames, got {n}", name


def test_dis_flow_names_the_size_it_needs():
    rng = np.random.default_rng(0)
    for h, w in ((11, 11), (5, 40), (40, 7)):
        seq = rng.random((2, h, w, 3)).astype(np.float32)
        with pytest.raises(ValueError, match=rf"8 px on the short side and 12 px on the long side, got {h}x{w}"):
            flow_warping_error(seq)
        m = FlowWarpingError()
        with pytest.raises(ValueError, match="dis flow needs frames"):
            m.update(seq, source=seq)
        # Farneback takes any size, down to one pixel (no gradient across a 1-px axis): a static
        # smooth sequence has zero error there
        ramp = np.linspace(0.2, 0.8, h * w).reshape(1, h, w, 1) * np.ones((3, 1, 1, 3))
        assert flow_warping_error(ramp, flow="farneback") == pytest.approx(0.0, abs=1e-6)  # float32 flow noise
    one = np.linspace(0.2, 0.8, 9).reshape(1, 1, 9, 1) * np.ones((3, 1, 1, 3))
    assert flow_warping_error(one, flow="farneback") == pytest.approx(0.0, abs=1e-6)
    m = FlowWarpingError(flow="farneback")
    m.update(one, source=one)
    assert m.compute()["flow_warping_error"].value == pytest.approx(0.0, abs=1e-6)


def test_a_flow_callable_must_return_finite_offsets_of_the_frame_size():
    seq = translated_sequence(n=2, size=(20, 24))

    def nan_flow(a, b):
        return np.full((*a.shape[:2], 2), np.nan, np.float32)

    def small_flow(a, b):
        return np.zeros((4, 4, 2), np.float32)

    for flow, what in ((nan_flow, "non-finite"), (small_flow, r"shape \(4, 4, 2\)")):
        with pytest.raises(ValueError, match=f"finite .H, W, 2. = .20, 24, 2. pixel offsets, got .*{what}"):
            flow_warping_error(seq, flow=flow)


def test_a_sequence_keeps_one_frame_size_across_batches():
    from wcbench.metrics.temporal.flicker import TemporalFlicker

    a, b = np.zeros((2, 16, 16, 3)), np.zeros((2, 16, 20, 3))
    for metric in (TemporalFlicker(), FlowWarpingError(flow="farneback")):
        metric.update(a, source=a)
        with pytest.raises(ValueError, match="frames of one sequence must share a size"):
            metric.update(b, source=b)
    with pytest.raises(ValueError, match="pred has shape"):
        TemporalFlicker().update(a, source=a[:1])
