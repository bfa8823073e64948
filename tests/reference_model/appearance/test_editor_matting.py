"""The editor's sky matting holds for radiance (docs/design.md §7, "The sky and its edge"): a pixel
the sky shows through partly sums the linear light of the sky and of the surface in their shares
of its area, so an edited pole's or wire's edge against the bright overcast is no darker or wider
than its share of the pixel."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

from wcbench.reference_model.appearance.editor import decontaminate, over_sky
from wcbench.reference_model.appearance.shading import linear_to_srgb, srgb_to_linear


def _pole_edge(sky: float, pole: float, share: float) -> tuple[np.ndarray, np.ndarray]:
    """A 24x24 frame: clear sky (matte 1) left of column 10, a dark pole (matte 0) right of column
    11, and columns 10-11 the pole's edge, ``share`` of each pixel the sky's, summed in linear light."""
    alpha = np.zeros((24, 24), np.float32)
    alpha[:, :10] = 1.0
    alpha[:, 10:12] = share
    lin = np.where(alpha[..., None] > 0.999, srgb_to_linear(np.full(3, sky)), srgb_to_linear(np.full(3, pole)))
    lin[:, 10:12] = share * srgb_to_linear(np.full(3, sky)) + (1 - share) * srgb_to_linear(np.full(3, pole))
    return linear_to_srgb(lin), alpha


def test_a_mixed_sky_pixel_gives_back_the_surface_it_sums_with_the_sky():
    image, alpha = _pole_edge(0.46, 0.2, 0.5)
    surface = decontaminate(srgb_to_linear(image), alpha, sigma_px=6.0)
    np.testing.assert_allclose(surface[:, 10:12], srgb_to_linear(np.full(3, 0.2))[None, None].repeat(2, 1)
                               .repeat(24, 0), atol=1e-4)
    # the same sky and surface composited again give the frame back
    sky = np.full(image.shape, 0.46, np.float32)
    np.testing.assert_allclose(over_sky(linear_to_srgb(surface), sky, alpha)[:, 10:], image[:, 10:], atol=2e-3)


def test_a_dark_edge_against_the_bright_overcast_sums_radiance_not_display_values():
    # a pole (0.17 display) half covering a pixel of the snow's airlight (0.86): 0.64 in display RGB
    # by their radiance; blending display values (0.515) drew the edge darker, the pole wider
    alpha = np.full((1, 1), 0.5, np.float32)
    out = over_sky(np.full((1, 1, 3), 0.17, np.float32), np.full((1, 1, 3), 0.86, np.float32), alpha)
    expected = linear_to_srgb(0.5 * srgb_to_linear(np.float32(0.86)) + 0.5 * srgb_to_linear(np.float32(0.17)))
    assert out[0, 0, 0] == pytest.approx(float(expected), abs=1e-4)
    assert out[0, 0, 0] > 0.6
    # the ends: all sky, all surface
    assert over_sky(np.zeros((1, 1, 3)), np.ones((1, 1, 3)), np.ones((1, 1)))[0, 0, 0] == pytest.approx(1.0)
    assert over_sky(np.zeros((1, 1, 3)), np.ones((1, 1, 3)), np.zeros((1, 1)))[0, 0, 0] == pytest.approx(0.0)


def _decontaminate_whole_frame(image, alpha, sigma):
    """The slow twin: the clear sky behind every pixel blurred on the whole frame, the estimate
    computed everywhere and kept where the matte is mixed."""
    import cv2

    img = np.asarray(image, np.float32)
    a = np.clip(alpha, 0.0, 0.9)
    inside = (alpha >= 0.99).astype(np.float32)
    blurred = cv2.GaussianBlur(np.dstack([img * inside[..., None], inside]), (0, 0), sigma)
    num, den = blurred[..., :3], blurred[..., 3:]
    behind = np.where(den > 1e-3, num / np.maximum(den, 1e-3), img)
    fg = np.clip((img - a[..., None] * behind) / (1.0 - a[..., None]), 0.0, 1.0)
    mixed = (a > 0.0) & (a < 0.9)
    return np.where(mixed[..., None], fg, img).astype(np.float32)


@pytest.mark.parametrize("where", ["middle", "top edge", "corner", "everywhere", "one pixel"])
def test_the_matting_blurred_around_the_mixed_pixels_is_the_whole_frames(rng, where):
    # the blur of the clear sky computed only in the mixed pixels' rectangle grown by its kernel's
    # radius: equal to the bit to the whole frame's, the reflected border at the frame's edges
    # included (sigma 6 px: a 49-tap kernel; 2.5 px: 21 taps)
    h, w = 135, 240
    image = rng.random((h, w, 3)).astype(np.float32)
    alpha = (rng.random((h, w)) > 0.5).astype(np.float32)
    region = {"middle": np.s_[60:75, 100:140], "top edge": np.s_[0:6, 30:200], "corner": np.s_[120:, 220:],
              "everywhere": np.s_[:, :], "one pixel": np.s_[70:71, 90:91]}[where]
    edge = np.zeros((h, w), bool)
    edge[region] = True
    alpha[edge] = rng.uniform(0.05, 0.95, int(edge.sum())).astype(np.float32)
    for sigma in (6.0, 2.5):
        np.testing.assert_array_equal(decontaminate(image, alpha, sigma_px=sigma),
                                      _decontaminate_whole_frame(image, alpha, sigma))
    # no mixed pixel: the frame as it is
    solid = (alpha > 0.5).astype(np.float32)
    np.testing.assert_array_equal(decontaminate(image, solid), image)
