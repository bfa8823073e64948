"""CLIP preprocessing (torch-free) against transformers' CLIPImageProcessor and by hand."""

from __future__ import annotations

import numpy as np
import pytest

from wcbench.metrics.clip.config import CLIP_MEAN, CLIP_STD
from wcbench.metrics.clip.preprocess import ClipPreprocess, preprocess_images, resized_size, to_uint8

#: Same uint8 pixels and float64 arithmetic on both sides: only float32 rounding of the output.
HF_TOL = 1e-6

# Driving-camera sizes (Waymo front and side, nuScenes, our demo scene), a portrait frame, an
# exact 224 square and an upscaled small frame. 886 x 1920 exercises an odd crop margin.
SIZES = [(1280, 1920), (886, 1920), (900, 1600), (180, 320), (300, 200), (224, 224), (100, 150)]


@pytest.mark.parametrize(("h", "w"), SIZES)
def test_matches_clip_image_processor(h: int, w: int) -> None:
    pytest.importorskip("transformers")
    from transformers.models.clip.image_processing_pil_clip import CLIPImageProcessorPil

    img = np.random.default_rng(h * w).integers(0, 256, (h, w, 3), dtype=np.uint8)
    ref = CLIPImageProcessorPil()(images=img, return_tensors="np")["pixel_values"]
    ours = preprocess_images(img)
    assert ours.shape == ref.shape == (1, 3, 224, 224)
    np.testing.assert_allclose(ours, ref, rtol=0, atol=HF_TOL)


def test_float_and_uint8_agree(rng: np.random.Generator) -> None:
    u8 = rng.integers(0, 256, (2, 90, 160, 3), dtype=np.uint8)
    for dtype in (np.float16, np.float32, np.float64):
        f = (u8 / 255.0).astype(dtype)
        np.testing.assert_array_equal(to_uint8(f), u8)
        np.testing.assert_array_equal(preprocess_images(f), preprocess_images(u8))


def test_to_uint8_inverts_division_exactly() -> None:
    k = np.arange(256, dtype=np.uint8)
    for dtype in (np.float16, np.float32, np.float64):
        np.testing.assert_array_equal(to_uint8((k / dtype(255)).astype(dtype)), k)
        np.testing.assert_array_equal(to_uint8(k.astype(dtype) / dtype(255)), k)


def test_constant_image_normalises_to_mean() -> None:
    gray = np.full((120, 200, 3), 128, np.uint8)
    out = preprocess_images(gray)[0]
    expected = (128 / 255.0 - np.asarray(CLIP_MEAN)) / np.asarray(CLIP_STD)
    np.testing.assert_allclose(out.reshape(3, -1).mean(axis=1), expected, atol=1e-6)


def test_center_crop_takes_the_middle() -> None:
    # A 224 x 448 frame needs no resize; the centre crop is columns 112..335.
    img = np.zeros((224, 448, 3), np.uint8)
    img[:, 112:336] = 255
    out = preprocess_images(img, crop="center")[0]
    white = (1.0 - np.asarray(CLIP_MEAN)) / np.asarray(CLIP_STD)
    np.testing.assert_allclose(out[:, :, 0], np.broadcast_to(white[:, None], (3, 224)), atol=1e-6)
    np.testing.assert_allclose(out[:, :, -1], np.broadcast_to(white[:, None], (3, 224)), atol=1e-6)


def test_squash_keeps_the_whole_frame() -> None:
    img = np.zeros((224, 448, 3), np.uint8)
    img[:, :50] = 255  # only at the far left: gone under the centre crop, kept by squash
    assert preprocess_images(img, crop="squash")[0, 0, :, 0].max() > 1.0
    assert preprocess_images(img, crop="center")[0, 0, :, 0].max() < 0.0


def test_resized_size_truncates() -> None:
    assert resized_size(1080, 1920) == (224, 398)
    assert resized_size(886, 1920) == (224, 485)
    assert resized_size(1920, 1080) == (398, 224)


def test_pil_bicubic_differs_from_opencv() -> None:
    # Why docs/design.md §5 insists on PIL: OpenCV's cubic kernel (a = -0.75, no antialiasing) gives
    # other pixels, enough to move CLIP scores in the third decimal.
    cv2 = pytest.importorskip("cv2")
    from PIL import Image

    img = np.random.default_rng(0).integers(0, 256, (360, 640, 3), dtype=np.uint8)
    pil = np.asarray(Image.fromarray(img).resize((398, 224), Image.Resampling.BICUBIC)).astype(int)
    ocv = cv2.resize(img, (398, 224), interpolation=cv2.INTER_CUBIC).astype(int)
    assert np.abs(pil - ocv).mean() > 5


def test_config_records_crop() -> None:
    cfg = ClipPreprocess(crop="center").config()
    assert cfg["crop"] == "center" and "center crop 224x224" in cfg["geometry"]
    assert "aspect not kept" in ClipPreprocess(crop="squash").config()["geometry"]


def test_bad_inputs() -> None:
    with pytest.raises(ValueError, match=r"got shape \(4, 4\)"):
        preprocess_images(np.zeros((4, 4)))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        preprocess_images(np.full((4, 4, 3), 2.0))
    with pytest.raises(ValueError, match="crop must be one of"):
        preprocess_images(np.zeros((4, 4, 3)), crop="letterbox")
    with pytest.raises(ValueError, match="crop must be one of"):
        ClipPreprocess(crop="pad")
