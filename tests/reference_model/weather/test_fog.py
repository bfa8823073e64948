"""Beer-Lambert fog: formulas on synthetic buffers (numpy) and rendered planes (torch)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wcbench.reference_model.weather.fog import (
    compose_exact,
    density_from_visibility,
    fog_postprocess,
    gaussian_transmittance,
    ray_distance,
    transmitted_channels,
    visibility_from_density,
)
from wcbench.scenes.scene import Camera

FOG = np.array([0.8, 0.8, 0.85], np.float32)
# float32 image arithmetic: a few ulps of values in [0, 1].
F32_TOL = 2e-6


def pinhole(width: int = 64, height: int = 48, f: float = 40.0) -> np.ndarray:
    return np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def test_visibility_and_density_are_koschmieder_inverses() -> None:
    from wcbench.reference_model.weather.fog import KOSCHMIEDER_CONSTANT, MOR_CONSTANT, VISIBILITY_CONTRAST

    # The convention is the WMO's meteorological optical range (5 % contrast); Koschmieder's 2 %
    # threshold is exposed for conversions and gives 1.31x longer visibilities.
    assert VISIBILITY_CONTRAST == MOR_CONSTANT == pytest.approx(2.9957, abs=1e-4)
    assert KOSCHMIEDER_CONSTANT == pytest.approx(3.9120, abs=1e-4)
    assert math.exp(-MOR_CONSTANT) == pytest.approx(0.05) and math.exp(-KOSCHMIEDER_CONSTANT) == pytest.approx(0.02)
    assert density_from_visibility(60.0) * 60.0 == pytest.approx(2.996, abs=1e-3)
    assert visibility_from_density(density_from_visibility(123.0)) == pytest.approx(123.0)
    assert visibility_from_density(0.0) == math.inf and density_from_visibility(math.inf) == 0.0
    with pytest.raises(ValueError, match="visibility_m"):
        density_from_visibility(0.0)
    with pytest.raises(ValueError, match="beta"):
        visibility_from_density(-1.0)


def test_ray_distance_uses_the_longer_off_axis_ray() -> None:
    K = pinhole()
    depth = np.full((48, 64), 10.0, np.float32)
    l_ray = ray_distance(depth, K)
    u, v = 0.5, 0.5  # the corner pixel's center
    expected = 10.0 * math.sqrt(1 + ((u - 32) / 40) ** 2 + ((v - 24) / 40) ** 2)
    assert l_ray[0, 0] == pytest.approx(expected, rel=1e-6)
    assert l_ray[24, 32] == pytest.approx(10.0 * math.sqrt(1 + (0.5 / 40) ** 2 * 2), rel=1e-6)


def test_postprocess_on_an_opaque_plane_is_exact_per_pixel() -> None:
    K = pinhole()
    rng = np.random.default_rng(0)
    color = rng.random((48, 64, 3)).astype(np.float32)
    depth = np.full((48, 64), 7.5, np.float32)
    alpha = np.ones((48, 64), np.float32)
    beta = 0.13
    out = fog_postprocess(color, depth, alpha, K, beta=beta, fog_color=FOG)
    t = np.exp(-beta * ray_distance(depth, K))[..., None]
    np.testing.assert_allclose(out, t * color + (1 - t) * FOG, atol=F32_TOL)


def test_exact_equals_postprocess_when_every_layer_of_a_pixel_shares_its_distance() -> None:
    # sum w c t = t sum w c and sum w t = t A: the two forms agree; they differ only across depths.
    rng = np.random.default_rng(1)
    K = pinhole()
    alpha = rng.uniform(0, 1, (48, 64)).astype(np.float32)
    premult = (rng.random((48, 64, 3)) * alpha[..., None]).astype(np.float32)
    depth = rng.uniform(1, 40, (48, 64)).astype(np.float32)
    beta, bg = 0.07, np.array([0.2, 0.4, 0.9], np.float32)
    t = np.exp(-beta * ray_distance(depth, K))
    exact = compose_exact(premult * t[..., None], alpha * t, alpha, beta=beta, fog_color=FOG, background=bg)
    post = fog_postprocess(
        premult + (1 - alpha[..., None]) * bg, depth, alpha, K, beta=beta, fog_color=FOG, background=bg
    )
    np.testing.assert_allclose(post, exact, atol=1e-5)


def test_sky_is_at_infinity_and_beta_zero_changes_nothing() -> None:
    alpha = np.zeros((4, 5), np.float32)
    zeros3 = np.zeros((4, 5, 3), np.float32)
    bg = np.array([0.1, 0.5, 0.9], np.float32)
    for beta in (1e-4, 0.2, 1e3):
        sky = compose_exact(zeros3, alpha, alpha, beta=beta, fog_color=FOG, background=bg)
        np.testing.assert_allclose(sky, np.broadcast_to(FOG, sky.shape), atol=F32_TOL)
    clear = compose_exact(zeros3, alpha, alpha, beta=0.0, fog_color=FOG, background=bg)
    np.testing.assert_allclose(clear, np.broadcast_to(bg, clear.shape), atol=F32_TOL)
    np.testing.assert_array_equal(gaussian_transmittance(np.ones((3, 3)), np.zeros(3), 0.0), np.ones(3))


def test_float32_transmittance_matches_a_float64_computation() -> None:
    means = np.random.default_rng(2).uniform(-300, 300, (1000, 3)).astype(np.float32)
    center = np.array([3.0, -2.0, 1.5])
    d = np.linalg.norm(means.astype(np.float64) - center, axis=1)
    for beta, offset in ((0.0, 0.0), (0.02, 0.0), (0.2, 10.0), (1e3, 0.0)):
        t = gaussian_transmittance(means, center, beta, offset_m=offset)
        assert t.dtype == np.float32
        # float32 distances of up to ~500 m: 3e-5 m, i.e. a relative 3e-5 * beta in t.
        np.testing.assert_allclose(t, np.exp(-beta * np.maximum(d - offset, 0)), rtol=1e-5, atol=1e-30)


def test_gaussian_transmittance_extremes_and_offset() -> None:
    means = np.array([[0.0, 0.0, 5.0], [3.0, 4.0, 0.0], [0.0, 0.0, 1e6]])
    t = gaussian_transmittance(means, np.zeros(3), 0.1)
    np.testing.assert_allclose(t, [math.exp(-0.5), math.exp(-0.5), 0.0], rtol=1e-6)
    assert np.all(np.isfinite(gaussian_transmittance(means, np.zeros(3), 1e3)))
    # Rain haze: nothing before the offset (the explicit particles), Beer-Lambert beyond it.
    t_off = gaussian_transmittance(means, np.zeros(3), 0.1, offset_m=10.0)
    np.testing.assert_allclose(t_off[:2], 1.0)
    with pytest.raises(ValueError, match="beta"):
        gaussian_transmittance(means, np.zeros(3), math.inf)
    with pytest.raises(ValueError, match="means"):
        gaussian_transmittance(np.zeros((3, 2)), np.zeros(3), 0.1)


def _fog_kernels_or_skip() -> None:
    pytest.importorskip("numba")
    from wcbench.reference_model._numba_backend import load_numba_kernels

    if load_numba_kernels("weather.fog_kernels") is None:
        pytest.skip("numba fog kernels unavailable")


@pytest.mark.parametrize(("beta", "offset"), [(0.0, 0.0), (0.05, 0.0), (0.2, 10.0), (1e3, 0.0)])
def test_transmitted_channels_fast_path_matches_the_numpy_reference(beta: float, offset: float) -> None:
    _fog_kernels_or_skip()
    rng = np.random.default_rng(4)
    means = rng.uniform(-300, 300, (10_001, 3)).astype(np.float32)  # not a multiple of the chunk
    colors = rng.uniform(0, 1, (10_001, 3)).astype(np.float32)
    center = np.array([3.0, -2.0, 1.5])
    ref = transmitted_channels(means, colors, center, beta, offset_m=offset, fast=False)
    out = np.full((10_001, 4), np.nan, np.float32)
    fast = transmitted_channels(means, colors, center, beta, offset_m=offset, out=out)
    assert fast is out and ref.dtype == np.float32
    # numpy's float32 exp is within 1 ulp, the kernel's (float64 exp, rounded) within 0.5.
    np.testing.assert_allclose(fast, ref, rtol=3e-7, atol=1e-37)
    np.testing.assert_allclose(ref[:, 3], gaussian_transmittance(means, center, beta, offset_m=offset))
    np.testing.assert_array_equal(ref[:, :3], colors * ref[:, 3:])
    with pytest.raises(ValueError, match="out must be"):
        transmitted_channels(means, colors, center, beta, out=np.empty((10_001, 3), np.float32))


def test_compose_exact_fast_path_matches_the_numpy_reference() -> None:
    _fog_kernels_or_skip()
    rng = np.random.default_rng(5)
    h, w = 37, 53
    alpha = rng.uniform(0, 1, (h, w)).astype(np.float32)
    alpha[0, :5] = [0.0, 1.0, 1.0, 0.0, 0.5]
    sum_t = (alpha * rng.uniform(0, 1.001, (h, w))).astype(np.float32)  # a few A < sum t: clamped
    rendered = rng.uniform(0, 1, (h, w, 4)).astype(np.float32)  # a non-contiguous [H, W, 3] view
    rendered[..., 3] = sum_t
    for beta, bg in ((0.05, np.array([0.2, 0.4, 0.9])), (0.0, np.array([0.2, 0.4, 0.9])), (0.1, None)):
        args = (rendered[..., :3], rendered[..., 3], alpha)
        ref = compose_exact(*args, beta=beta, fog_color=FOG, background=bg, fast=False)
        fast = compose_exact(*args, beta=beta, fog_color=FOG, background=bg)
        assert fast.dtype == np.float32 and fast.shape == (h, w, 3)
        np.testing.assert_allclose(fast, ref, atol=F32_TOL, rtol=0)


# ---- rendered -----------------------------------------------------------------------------------


def _plane(distance: float, half: float, spacing: float, color: tuple[float, float, float]):
    """A fronto-parallel opaque plane of small Gaussians at camera z = ``distance`` (camera at origin)."""
    from wcbench.reference_model.scene_graph.gaussians import GaussianCloud

    g = np.arange(-half, half + 1e-9, spacing)
    x, y = np.meshgrid(g, g)
    n = x.size
    means = np.stack([x.ravel(), y.ravel(), np.full(n, distance)], 1)
    quats = np.tile([1.0, 0, 0, 0], (n, 1))
    scales = np.tile([spacing, spacing, spacing * 0.1], (n, 1))
    return GaussianCloud(
        means=means, quats=quats, scales=scales, opacities=np.full(n, 0.99), colors=np.tile(color, (n, 1))
    )


def _camera(width: int = 64, height: int = 48, f: float = 40.0) -> Camera:
    return Camera(K=pinhole(width, height, f), width=width, height=height, camera_to_world=np.eye(4))


@pytest.mark.parametrize("mode", ["exact", "postprocess"])
def test_rendered_plane_matches_beer_lambert_per_pixel(mode: str) -> None:
    pytest.importorskip("torch")
    from wcbench.reference_model.weather.conditions import Weather
    from wcbench.reference_model.weather.renderer import WeatherRenderer

    d, beta, c = 6.0, 0.15, (0.2, 0.5, 0.3)
    cam = _camera()
    plane = _plane(d, half=12.0, spacing=0.05, color=c)
    r = WeatherRenderer(plane, Weather(kind="fog", fog_density=beta, fog_mode=mode), up=np.array([0, -1.0, 0]))
    frame = r.render(cam, 0.0)
    assert frame.alpha.min() > 0.9998  # the plane covers the view (T stops at 1e-4): no sky
    assert (frame.depth is None) == (mode == "exact")  # the exact form needs no depth channel
    t = np.exp(-beta * ray_distance(np.full((48, 64), d, np.float32), cam.K))[..., None]
    expected = t * np.array(c) + (1 - t) * FOG
    # exact: each pixel mixes Gaussians up to ~3 sigma (0.15 m) off its ray, whose distances differ
    # from the ray's by up to ~0.15 sin(angle): |dt| <= beta * 0.15 * 0.6 * t ~ 0.01.
    tol = 1e-4 if mode == "postprocess" else 1.2e-2
    np.testing.assert_allclose(frame.image, expected, atol=tol)
    # Off-axis pixels see the longer ray: the corner is foggier than the center by the ray factor.
    assert frame.image[0, 0, 0] > frame.image[24, 32, 0] + 0.01


@pytest.mark.parametrize("mode", ["exact", "postprocess"])
def test_sky_pixels_are_fog_colored_in_dense_fog(mode: str) -> None:
    pytest.importorskip("torch")
    from wcbench.reference_model.weather.conditions import Weather
    from wcbench.reference_model.weather.renderer import WeatherRenderer

    plane = _plane(5.0, half=2.0, spacing=0.05, color=(0.1, 0.1, 0.1))  # covers the image center only
    bg = np.array([0.3, 0.5, 1.0], np.float32)
    r = WeatherRenderer(
        plane, Weather(kind="fog", visibility_m=20.0, fog_mode=mode), up=np.array([0, -1.0, 0]), background=bg
    )
    frame = r.render(_camera(), 0.0)
    sky = frame.alpha < 1e-6
    assert sky.sum() > 100
    np.testing.assert_allclose(frame.image[sky], np.broadcast_to(FOG, frame.image[sky].shape), atol=F32_TOL)


def test_zero_density_fog_equals_clear_and_huge_density_is_finite() -> None:
    pytest.importorskip("torch")
    from wcbench.reference_model.weather.conditions import Weather
    from wcbench.reference_model.weather.renderer import WeatherRenderer

    plane = _plane(5.0, half=2.0, spacing=0.05, color=(0.1, 0.7, 0.2))
    bg = np.array([0.3, 0.5, 1.0], np.float32)
    up = np.array([0, -1.0, 0])
    clear = WeatherRenderer(plane, Weather(), up=up, background=bg).render(_camera(), 0.0).image
    zero = WeatherRenderer(plane, Weather(kind="fog", fog_density=0.0), up=up, background=bg).render(_camera(), 0.0)
    np.testing.assert_array_equal(zero.image, clear)
    dense = WeatherRenderer(plane, Weather(kind="fog", fog_density=1e3), up=up, background=bg).render(_camera(), 0.0)
    assert np.all(np.isfinite(dense.image))
    np.testing.assert_allclose(dense.image, np.broadcast_to(FOG, dense.image.shape), atol=1e-5)


# ---- numeric guards (docs/design.md §9) -------------------------------------------------------


@pytest.mark.parametrize("fast", [True, False])
def test_no_fog_is_transmittance_one_even_for_overflowing_distances(fast: bool) -> None:
    means = np.array([[3e38, 3e38, 0.0], [1.0, 2.0, 3.0], [-3e38, 0.0, 3e38]], np.float32)
    colors = np.array([[0.2, 0.4, 0.6]] * 3, np.float32)
    # beta = 0, and a beta that rounds to 0 in float32: 0 * Inf would be NaN
    for beta in (0.0, 1e-46):
        out = transmitted_channels(means, colors, np.zeros(3), beta, fast=fast)
        np.testing.assert_array_equal(out[:, -1], 1.0)
        np.testing.assert_array_equal(out[:, :-1], colors)
    fogged = transmitted_channels(means, colors, np.zeros(3), 0.01, fast=fast)
    assert np.all(np.isfinite(fogged)) and fogged[0, -1] == 0.0 and fogged[2, -1] == 0.0


def test_fog_parameters_beyond_float32_or_the_color_bound_are_refused() -> None:
    means, colors = np.zeros((2, 3), np.float32), np.ones((2, 3), np.float32)
    with pytest.raises(ValueError, match="beta"):
        transmitted_channels(means, colors, np.zeros(3), 1e39)
    with pytest.raises(ValueError, match="offset_m"):
        gaussian_transmittance(means, np.zeros(3), 0.1, offset_m=1e300)
    with pytest.raises(ValueError, match="visibility_m must be at least"):
        density_from_visibility(1e-300)
    a = np.full((4, 5), 0.5, np.float32)
    for bad in (np.array([np.nan, 0.5, 0.5]), np.array([1e16, 0.0, 0.0]), np.array([0.5, 0.5])):
        with pytest.raises(ValueError, match="fog_color must be finite RGB"):
            compose_exact(np.zeros((4, 5, 3), np.float32), a * 0.5, a, beta=0.1, fog_color=bad)
    with pytest.raises(ValueError, match="background must be finite RGB"):
        compose_exact(np.zeros((4, 5, 3), np.float32), a * 0.5, a, beta=0.1, fog_color=FOG,
                      background=np.full((4, 5, 3), np.inf))
    with pytest.raises(ValueError, match="K must be finite"):
        ray_distance(np.ones((4, 5), np.float32), np.zeros((3, 3)))


def test_postprocess_of_rays_too_long_for_float32_is_finite() -> None:
    depth = np.full((4, 6), 3e38, np.float32)
    K = pinhole(6, 4, 1e-300)  # every off-axis ray is longer than float32 holds
    assert np.all(np.isinf(ray_distance(depth, K)))
    color = np.full((4, 6, 3), 0.3, np.float32)
    alpha = np.ones((4, 6), np.float32)
    for beta in (0.0, 0.02, 3e38):
        out = fog_postprocess(color, depth, alpha, K, beta=beta, fog_color=FOG)
        assert np.all(np.isfinite(out))
        # no fog keeps the color; any fog at an unbounded distance is the fog color
        np.testing.assert_allclose(out, color if beta == 0 else np.broadcast_to(FOG, out.shape), atol=F32_TOL)
