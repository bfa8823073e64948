"""The appearance models against closed forms, independent sums and the physics renderer's fog."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wcbench.reference_model.appearance.shading import (
    LightModel,
    _diffuse_fresnel,
    apply_haze,
    fresnel_schlick,
    linear_to_srgb,
    overcast_gain,
    overcast_irradiance,
    smoothstep,
    snow_cover,
    srgb_to_linear,
    wet_albedo,
)
from wcbench.reference_model.weather.fog import fog_postprocess


def test_srgb_transfer_round_trips_and_hits_the_standards_values():
    x = np.linspace(0.0, 1.0, 1001, dtype=np.float32)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=2e-6)
    # IEC 61966-2-1: display 0.5 is linear 0.2140, the linear segment ends at 0.04045 / 0.0031308
    assert float(srgb_to_linear(np.float32(0.5))) == pytest.approx(0.21404, abs=1e-5)
    assert float(linear_to_srgb(np.float32(0.0031308))) == pytest.approx(0.04045, abs=1e-5)


@pytest.mark.parametrize("convert", [srgb_to_linear, linear_to_srgb], ids=lambda f: f.__name__)
def test_srgb_transfer_kernels_are_the_numpy_references_to_half_a_millionth(convert):
    # the numba kernels mirror the reference's float32 operations; the power is the C library's
    # powf in the kernel and numpy's own float32 power in the reference, whose last bit varies with
    # numpy's version and the CPU it dispatches for (numpy 2.4.6 on an AMD EPYC with AVX-512: a float32
    # step or two of the power on 0.8 % of the values decoded and 1.2 % encoded, up to 3.9e-7 of the
    # result once the encoding's offset is taken off; the same bits on the earlier machines,
    # docs/findings.md).
    # Every 61st float32 of [0, 1], the knees, out of range and NaN, float64 and non-contiguous
    # input, and an array below the kernels' size
    from wcbench.reference_model._numba_backend import load_numba_kernels

    if load_numba_kernels("appearance.shading_kernels") is None:
        pytest.skip("numba shading kernels unavailable")
    bits = np.arange(0, int(np.float32(1.0).view(np.uint32)) + 1, 61, dtype=np.uint32)
    edges = np.array([-1.0, -0.0, 0.0, np.nan, np.inf, -np.inf, 2.0, 1.0, 1e-45, 0.04045, 0.0031308,
                      np.nextafter(np.float32(0.04045), np.float32(1.0)),
                      np.nextafter(np.float32(0.0031308), np.float32(1.0))], np.float32)
    values = np.concatenate([bits.view(np.float32), np.tile(edges, 400)])
    fast, slow = convert(values), convert(values, fast=False)
    assert fast.dtype == np.float32 and fast.shape == values.shape
    np.testing.assert_allclose(fast, slow, rtol=5e-7, atol=0.0)  # NaN where NaN
    # the linear segments and the clip are exact: no power there
    linear = np.where(convert is srgb_to_linear, values <= 0.04045, values <= 0.0031308) | (values >= 1.0)
    np.testing.assert_array_equal(fast[linear].view(np.uint32), slow[linear].view(np.uint32))
    frame = np.random.default_rng(0).uniform(-0.1, 1.1, (64, 96, 3))  # float64
    for x in (frame, frame[:, ::2], frame[..., 1], frame[:3, :3]):
        np.testing.assert_allclose(convert(x), convert(x, fast=False), rtol=5e-7, atol=0.0)
        assert convert(x).shape == x.shape


def test_cie_overcast_sky_lights_a_vertical_plane_with_0_396_of_the_horizontal():
    # Moon & Spencer's overcast sky: E_v / E_h = 0.396 (no ground light)
    model = LightModel(ground_albedo=0.0)
    assert float(overcast_irradiance(np.float32(1.0), model=model)) == pytest.approx(1.0, abs=1e-6)
    assert float(overcast_irradiance(np.float32(0.0), model=model)) == pytest.approx(0.396, abs=0.004)
    assert float(overcast_irradiance(np.float32(-1.0), model=model)) == pytest.approx(0.0, abs=1e-6)
    # the ground lights what faces down: albedo times the horizontal irradiance
    lit = LightModel(ground_albedo=0.2)
    assert float(overcast_irradiance(np.float32(-1.0), model=lit)) == pytest.approx(0.2, abs=1e-3)


def test_overcast_gain_is_the_exposure_on_a_horizontal_plane_and_a_ratio_of_skies_elsewhere():
    model = LightModel(sun_elevation_deg=45.0, direct_to_diffuse=4.0, ground_albedo=0.0)
    assert float(overcast_gain(np.float32(1.0), model=model, exposure=0.6)) == pytest.approx(0.6, rel=1e-5)
    # a uniform clear sky and no sun: a vertical plane sees half the sky (1/2), the overcast sky 0.396
    flat = LightModel(direct_to_diffuse=0.0, ground_albedo=0.0)
    assert float(overcast_gain(np.float32(0.0), model=flat, exposure=1.0)) == pytest.approx(0.396 / 0.5, abs=0.01)
    # with the sun: the clear side is E = 1/2 + D cos(e) / pi over 1 + D sin(e) (azimuth averaged)
    e = math.radians(45.0)
    clear_ratio = (0.5 + 4.0 * math.cos(e) / math.pi) / (1.0 + 4.0 * math.sin(e))
    assert float(overcast_gain(np.float32(0.0), model=model, exposure=1.0)) == pytest.approx(
        0.396 / clear_ratio, rel=0.02)
    with pytest.raises(ValueError, match="exposure"):
        overcast_gain(np.float32(0.0), model=model, exposure=0.0)


def test_diffuse_fresnel_of_water_and_the_lekner_dorf_film_against_its_series():
    assert _diffuse_fresnel(1.333) == pytest.approx(0.066, abs=0.002)  # hemispherical reflectance of water
    r_e = _diffuse_fresnel(1.333)
    r_i = 1.0 - (1.0 - r_e) / 1.333 ** 2
    a = np.linspace(0.0, 1.0, 11)
    # light bouncing between the surface and the film's top, summed term by term in float64
    series = sum((1 - r_e) * a * (1 - r_i) * (r_i * a) ** k for k in range(400))
    np.testing.assert_allclose(wet_albedo(np.repeat(a[:, None], 3, 1), 1.0)[:, 0], series, atol=1e-6)
    # dark surfaces lose about half, bright ones little; a dry surface is unchanged
    dark, bright = wet_albedo(np.full((1, 3), 0.05), 1.0)[0, 0], wet_albedo(np.full((1, 3), 0.9), 1.0)[0, 0]
    assert 0.4 < dark / 0.05 < 0.55 and bright / 0.9 > 0.8
    np.testing.assert_array_equal(wet_albedo(np.full((2, 3), 0.3, np.float32), 0.0), np.full((2, 3), 0.3, np.float32))


def test_schlick_snow_cover_and_smoothstep_limits():
    assert float(fresnel_schlick(np.float32(1.0), 0.02)) == pytest.approx(0.02)
    assert float(fresnel_schlick(np.float32(0.0), 0.02)) == pytest.approx(1.0)
    assert float(fresnel_schlick(np.float32(-1.0), 0.02)) == pytest.approx(0.02)  # either side of the surface
    up = np.array([-1.0, 0.0, 0.5, 0.7, 0.87, 1.0], np.float32)
    cover = snow_cover(up, np.ones(6), amount=0.8, facing_from=0.5, facing_full=0.87)
    np.testing.assert_allclose(cover[[0, 1, 2]], 0.0)
    np.testing.assert_allclose(cover[[4, 5]], 0.8, atol=1e-6)
    assert 0.0 < cover[3] < 0.8
    assert float(snow_cover(up[-1:], np.zeros(1), amount=1.0, facing_from=0.5, facing_full=0.87)[0]) == 0.0
    np.testing.assert_allclose(smoothstep(np.array([0.0, 0.5, 1.0]), 0.0, 1.0), [0.0, 0.5, 1.0])


def test_apply_haze_is_the_renderers_depth_fog_on_an_opaque_surface(rng):
    h, w = 20, 30
    K = np.array([[25.0, 0, w / 2], [0, 25.0, h / 2], [0, 0, 1]])
    image = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    depth = rng.uniform(2, 80, (h, w)).astype(np.float32)
    xs = (np.arange(w) + 0.5 - K[0, 2]) / K[0, 0]
    ys = (np.arange(h) + 0.5 - K[1, 2]) / K[1, 1]
    dist = depth * np.sqrt(1 + xs[None, :] ** 2 + ys[:, None] ** 2)
    color = np.array([0.8, 0.8, 0.85], np.float32)
    ours = apply_haze(image, dist, beta=0.02, color=color, offset_m=3.0)
    physics = fog_postprocess(image, depth, np.ones((h, w), np.float32), K, beta=0.02, fog_color=color, offset_m=3.0)
    np.testing.assert_allclose(ours, physics, atol=2e-6)
    sky = apply_haze(image, np.full((h, w), np.inf), beta=0.02, color=color)
    np.testing.assert_allclose(sky, np.broadcast_to(color, (h, w, 3)), atol=1e-7)
    np.testing.assert_array_equal(apply_haze(image, dist, beta=0.0, color=color), image)
