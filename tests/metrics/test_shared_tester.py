"""The shared metric tester on every pixel and temporal metric, edge inputs, FPS, applicability rules."""

from __future__ import annotations

import numpy as np
import pytest
from metric_tester import check_metric
from sequences import translated_sequence

from wcbench.metrics import flow_warping_error, psnr, ssim, temporal_flicker
from wcbench.metrics.base import MetricContext
from wcbench.metrics.fps import FPS
from wcbench.metrics.pixel.psnr import PSNR
from wcbench.metrics.pixel.ssim import SSIM
from wcbench.metrics.temporal.flicker import FlowWarpingError, TemporalFlicker

#: docs/design.md §5: our SSIM equals skimage's with these settings to 1e-12.
FUNCTIONAL = {
    PSNR: {"psnr": lambda p, s, r: psnr(p, r)},
    SSIM: {"ssim": lambda p, s, r: ssim(p, r)},
    TemporalFlicker: {"temporal_flicker": lambda p, s, r: temporal_flicker(p)},
    FlowWarpingError: {"flow_warping_error": lambda p, s, r: flow_warping_error(p, s)},
}


@pytest.mark.parametrize(
    ("factory", "needs"),
    [(PSNR, "reference"), (SSIM, "reference"), (TemporalFlicker, "source"), (FlowWarpingError, "source")],
)
def test_shared_metric_tester(factory, needs):
    seq = translated_sequence(n=4, size=(32, 40)).astype(np.float64)
    noisy = np.clip(seq + 0.05 * np.random.default_rng(1).standard_normal(seq.shape), 0, 1)
    kw = {"reference": seq} if needs == "reference" else {"source": seq}
    check_metric(factory, noisy, functional=FUNCTIONAL[factory], **kw)


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


def test_shared_metric_tester_on_fps():
    def bound() -> FPS:
        m = FPS()
        m.bind(MetricContext(weather="rain", n_frames=3, has_reference=False, fps_override=12.5))
        return m

    out = check_metric(bound, np.zeros((3, 8, 8, 3)))
    assert out["fps"].value == 12.5


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


