"""PSNR and SSIM: equal to scikit-image, closed forms, shape errors."""

from __future__ import annotations

import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from wcbench.core.image_io import read_rgb8, to_float
from wcbench.metrics import psnr, ssim

#: docs/design.md §5: our SSIM equals skimage's with these settings to 1e-12.
SSIM_SKIMAGE_ATOL = 1e-12


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


# ---- numeric guards (docs/design.md §9) -------------------------------------------------------


def test_psnr_of_denormal_differences_is_finite_and_only_identical_frames_are_infinite():
    from wcbench.metrics.pixel.psnr import PSNR

    a = np.zeros((2, 4, 4, 3))
    b = a.copy()
    b[0, 1, 2, 0] = 5e-324  # its square underflows float64
    value = psnr(a[0], b[0])
    # 10 log10(1 / mse), mse = (5e-324)^2 / 48, from logarithms
    assert value == pytest.approx(-10 * (2 * np.log10(5e-324) - np.log10(48)), rel=1e-12)
    m = PSNR()
    m.update(a, reference=b)
    out = m.compute()["psnr"]
    assert out.value is None and "identical" in out.reason  # frame 1 is identical: PSNR inf
    assert out.per_frame[0] == pytest.approx(value) and out.per_frame[1] is None


def test_empty_inputs_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="at least 1 x 1 px, got 0 x 4"):
        psnr(np.zeros((0, 4, 3)), np.zeros((0, 4, 3)))
    for fn in (psnr, ssim):
        with pytest.raises(ValueError, match="no frames"):
            fn(np.zeros((0, 16, 16, 3)), np.zeros((0, 16, 16, 3)))
    with pytest.raises(ValueError, match=r"at least 11 px on each side, got 10 x 30 px"):
        ssim(np.zeros((10, 30, 3)), np.zeros((10, 30, 3)))


@pytest.mark.parametrize("cls", ["PSNR", "SSIM"])
def test_frames_equal_to_their_reference_get_the_computed_value_without_the_work(rng, cls):
    from wcbench.metrics.pixel import psnr as psnr_module
    from wcbench.metrics.pixel import ssim as ssim_module

    metric_cls = getattr(psnr_module if cls == "PSNR" else ssim_module, cls)
    ref = rng.random((4, 40, 56, 3)).astype(np.float32)
    pred = ref.copy()
    pred[1] = np.clip(pred[1] + 0.05 * rng.standard_normal(pred[1].shape), 0, 1)
    calls: list[int] = []

    class Counting(metric_cls):
        def frame_values(self, p, r):
            calls.append(len(p))
            return super().frame_values(p, r)

    skipping, computing = Counting(), Counting(skip_identical=False)
    skipping.update(pred, reference=ref)
    computing.update(pred, reference=ref)
    assert calls == [1, 4]
    fast, slow = skipping.compute()[cls.lower()], computing.compute()[cls.lower()]
    # the exact value of a pair of equal frames is what the computation gives (PSNR inf, SSIM 1)
    assert fast.per_frame == slow.per_frame
    assert skipping._values == computing._values
