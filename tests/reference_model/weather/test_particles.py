"""Rain and snow particles: physics, kinematics, wrap, shapes, presets, extremes (numpy only)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wcbench.reference_model.transforms import quat_to_matrix
from wcbench.reference_model.weather.conditions import Weather, load_presets, preset_names
from wcbench.reference_model.weather.microphysics import (
    extinction_coefficient,
    number_density,
    precipitation_extinction,
    rain_extinction,
    rain_fall_speed,
    sample_diameters,
    size_distribution,
    snow_extinction,
    snow_fall_speed,
)
from wcbench.reference_model.weather.particle_geometry import horizontal_basis
from wcbench.reference_model.weather.particle_spec import ParticleSpec, Wind
from wcbench.reference_model.weather.particles import ParticleField

Z_UP = np.array([0.0, 0.0, 1.0])
# Positions are float64 closed forms; the only error is rounding of O(100 m) coordinates.
POS_TOL = 1e-9


def field(
    kind: str = "rain",
    preset: str = "heavy",
    *,
    wind: Wind | None = None,
    up: np.ndarray = Z_UP,
    seed: int = 3,
    **overrides: object,
) -> ParticleField:
    weather = Weather(kind=kind, preset=preset, **overrides)  # type: ignore[arg-type]
    spec = weather.particle_spec()
    assert spec is not None
    return ParticleField(spec, wind=wind or Wind(), up=up, seed=seed)


def box_coords(f: ParticleField, pos: np.ndarray, center: np.ndarray) -> np.ndarray:
    return (pos - center) @ f.basis.T


# ---- physics -----------------------------------------------------------------------------------


def test_marshall_palmer_and_fall_speed_match_published_values() -> None:
    n0, lam = size_distribution("rain", 25.0)
    assert n0 == 8000.0
    assert lam == pytest.approx(4.1 * 25.0**-0.21, rel=1e-12)
    # docs/design.md §7: a 1 mm drop falls at ~4 m/s, a 3 mm drop at ~8 m/s.
    assert rain_fall_speed(1.0) == pytest.approx(4.0, abs=0.05)
    assert rain_fall_speed(3.0) == pytest.approx(8.0, abs=0.1)
    v_snow = snow_fall_speed(np.array([0.01, 2.0, 50.0]))
    assert np.all((v_snow >= 0.5) & (v_snow <= 1.5))
    # Heavy rain (25 mm/h) leaves about 1 km of visibility (geometric optics, Q_ext = 2).
    beta = extinction_coefficient(n0, lam)
    assert 2.996 / beta == pytest.approx(1080.0, rel=0.05)


@pytest.mark.parametrize(("rate", "beta_per_km"), [(2.5, 0.57647), (7.6, 1.21423), (25.0, 2.69634)])
def test_rain_haze_is_the_weber_2015_extinction_of_the_rate(rate: float, beta_per_km: float) -> None:
    # beta = 0.312 R^0.67 km^-1 (Weber et al. 2015), evaluated by hand at the three presets.
    assert rain_extinction(rate) == pytest.approx(beta_per_km * 1e-3, rel=1e-4)
    # The geometric-optics extinction of the Marshall-Palmer population, pi N0 / Lambda^3, is the
    # same physics: within 13 % at these rates (0.650, 1.309, 2.771 km^-1).
    geometric = precipitation_extinction("rain", rate, model="geometric")
    assert geometric == pytest.approx(extinction_coefficient(*size_distribution("rain", rate)), rel=1e-12)
    assert 1.0 < geometric / rain_extinction(rate) < 1.13
    # The presets use the empirical relation for the haze beyond the particle box.
    f = field("rain", {2.5: "light", 7.6: "moderate", 25.0: "heavy"}[rate])
    assert f.spec.haze_model == "weber2015" and f.haze_density() == rain_extinction(rate)
    assert f.info()["haze_model"] == "weber2015"
    assert rain_extinction(0.0) == 0.0


def test_snow_haze_is_the_rasmussen_1999_extinction_of_the_rate() -> None:
    # beta = 3 rho_w S / (C3 v_t): dry aggregates (C3 = 0.017 g cm^-2, 1 m/s) 4.90 km^-1 per mm/h,
    # wet ones (0.072 g cm^-2, 2 m/s) 0.579 km^-1 per mm/h; linear in the rate.
    assert snow_extinction(1.0) == pytest.approx(3 / 3.6e6 / (0.017e-2 * 1.0), rel=1e-12)
    assert snow_extinction(1.0) == pytest.approx(4.902e-3, rel=1e-3)
    assert snow_extinction(1.0, aggregates="wet") == pytest.approx(5.787e-4, rel=1e-3)
    assert snow_extinction(2.5) == pytest.approx(2.5 * snow_extinction(1.0), rel=1e-12)
    # At 2 mm/h: MOR visibilities of 0.31 km (dry) and 2.6 km (wet), the spread Rasmussen et al.
    # report for one rate (a factor 3-10).
    assert 2.996 / snow_extinction(2.0) == pytest.approx(306.0, rel=0.01)
    assert 2.996 / snow_extinction(2.0, aggregates="wet") == pytest.approx(2590.0, rel=0.01)
    # The presets: light snow (0.5 mm/h) leaves 1.2 km, heavy snow (2.5 mm/h) 245 m (the US Federal
    # Meteorological Handbook calls snow heavy at a visibility of 1/4 mile, ~400 m, or less).
    light, heavy = field("snow", "light"), field("snow", "heavy")
    assert light.spec.haze_model == heavy.spec.haze_model == "rasmussen1999_dry"
    assert 2.996 / light.haze_density() == pytest.approx(1222.0, rel=0.01)
    assert 2.996 / heavy.haze_density() == pytest.approx(244.5, rel=0.01)
    # Geometric optics on the Gunn-Marshall flakes (4x their melted diameter) is within a factor 3.2.
    for f in (light, heavy):
        geometric = precipitation_extinction("snow", f.spec.rate_mm_h, model="geometric", spec=f.spec)  # type: ignore[arg-type]
        assert 1.0 < geometric / f.haze_density() < 3.2
    with pytest.raises(ValueError, match="aggregates"):
        snow_extinction(1.0, aggregates="slush")
    with pytest.raises(ValueError, match="rate_mm_h"):
        snow_extinction(-1.0)


def test_haze_model_is_a_setting_checked_per_kind() -> None:
    from dataclasses import replace

    empirical = field("rain", "heavy", max_particles=100)
    f = ParticleField(replace(empirical.spec, haze_model="geometric"), seed=3)
    # The geometric option keeps the former value: 2.8e-3 m^-1 at 25 mm/h.
    assert f.haze_density() == pytest.approx(2.771e-3, rel=1e-3)
    assert empirical.haze_density() == pytest.approx(2.696e-3, rel=1e-3)
    assert ParticleSpec(kind="snow", rate_mm_h=1.0).haze_model == "rasmussen1999_dry"  # the kind's default
    with pytest.raises(ValueError, match="haze_model"):
        ParticleSpec(kind="rain", rate_mm_h=1.0, haze_model="rasmussen1999_dry")
    with pytest.raises(ValueError, match="haze_model"):
        precipitation_extinction("snow", 1.0, model="weber2015")
    # A fixed-count (paper) preset has no haze.
    assert field("snow", "paper").haze_density() == 0.0 and field("snow", "paper").info()["haze_model"] is None


def test_number_density_and_sampling_follow_the_truncated_exponential() -> None:
    n0, lam = size_distribution("rain", 7.6)
    d = np.linspace(0.5, 6.0, 200001)
    numeric = np.trapezoid(n0 * np.exp(-lam * d), d)
    assert number_density(n0, lam, 0.5, 6.0) == pytest.approx(numeric, rel=1e-8)
    u = np.random.default_rng(0).random(200_000)
    sample = sample_diameters(u, lam, 0.5, 6.0)
    assert sample.min() >= 0.5 and sample.max() <= 6.0
    mean = np.trapezoid(d * np.exp(-lam * d), d) / np.trapezoid(np.exp(-lam * d), d)
    assert sample.mean() == pytest.approx(mean, rel=0.01)  # 200k samples: ~0.2 % standard error


def test_snowflakes_draw_their_sizes_from_gunn_marshall() -> None:
    """Every simulated flake has its own melted diameter from N(D) = N0 exp(-Lambda D) on
    [0.5, 5] mm, its three Gaussians scaled by it and its fall speed from it; the paper keeps one size."""
    from scipy.stats import kstest

    f = field("snow", "heavy")  # 2.5 mm/h: Lambda = 2.55 R^-0.48 = 1.643 mm^-1
    lo, hi, lam = f.spec.min_diameter_mm, f.spec.max_diameter_mm, f.lam
    assert lam == pytest.approx(2.55 * 2.5**-0.48, rel=1e-12) and f.n0 == pytest.approx(3800 * 2.5**-0.87, rel=1e-12)
    d = f.diameter_mm
    assert d.shape == (16000,) and d.min() >= lo and d.max() <= hi

    def cdf(x: np.ndarray) -> np.ndarray:  # the truncated exponential
        return np.clip(-np.expm1(-lam * (x - lo)) / -math.expm1(-lam * (hi - lo)), 0.0, 1.0)

    # Kolmogorov-Smirnov against the analytic CDF: for 16,000 draws the statistic is ~0.007 and
    # exceeds 1.95 / sqrt(n) = 0.015 with probability 1e-3.
    ks = kstest(d, cdf)
    assert ks.statistic < 1.95 / math.sqrt(d.size) and ks.pvalue > 1e-3
    grid = np.linspace(lo, hi, 400001)
    mean = np.trapezoid(grid * np.exp(-lam * grid), grid) / np.trapezoid(np.exp(-lam * grid), grid)
    assert mean == pytest.approx(lo + 1 / lam - (hi - lo) / math.expm1(lam * (hi - lo)), rel=1e-6)
    assert d.mean() == pytest.approx(mean, rel=0.02)  # standard error 0.4 %
    # Shapes: the long arm has sigma = D x flake_ratio / 4 (the flake's extent is 4 x its melted
    # diameter), the short axes 0.625 of it; fall speed 0.8 (D x ratio)^0.16 m/s.
    g = f.gaussians(0.8, np.zeros(3), fast=False)
    long = d[g.particle] * f.spec.flake_ratio * 1e-3 / 4.0
    np.testing.assert_allclose(g.scales[:, 0], long, rtol=1e-6)
    np.testing.assert_allclose(g.scales[:, 1:], np.repeat(long[:, None] * 0.625, 2, 1), rtol=1e-6)
    np.testing.assert_allclose(f.fall_speed, snow_fall_speed(d * f.spec.flake_ratio), rtol=1e-12)
    assert np.unique(g.scales[:, 0]).size > 1000 and np.ptp(f.fall_speed) > 0.2
    # The paper's flakes have one size and one speed.
    paper = field("snow", "paper")
    gp = paper.gaussians(0.8, np.zeros(3), fast=False)
    assert np.unique(gp.scales, axis=0).shape[0] == 1 and np.ptp(paper.fall_speed) == 0.0


def test_heavy_snow_looks_heavy_at_the_working_size() -> None:
    """At 480 x 270 (f = 300 px) heavy snow has flakes of several pixels near the camera (their box
    holds them at 1/1.8 of the physical density) and a haze of 245 m visibility beyond it."""
    K = np.array([[300.0, 0, 240], [0, 300.0, 135], [0, 0, 1]])
    view = (np.eye(4), K, 480, 270)  # at the origin, looking along +z; world up is -y
    sizes = {}
    for preset in ("light", "heavy"):
        f = field("snow", preset, up=np.array([0.0, -1.0, 0.0]), seed=1)
        # Nearly the physical density near the camera: each flake stands for fewer than 2.
        assert 1.0 < f.represented < 2.0 and f.spec.radius_m == 2.0
        px = []
        for t in (1.0, 2.0, 3.0, 4.0):
            g = f.gaussians(t, np.zeros(3), view=view, near=0.01)
            flakes = slice(None, None, 3)  # one row per flake (its long arm comes first)
            px.append(4.0 * g.scales[flakes, 0].astype(np.float64) * 300.0 / g.means[flakes, 2])  # +-2 sigma
        sizes[preset] = np.concatenate(px)
    heavy, light = sizes["heavy"], sizes["light"]
    # Per frame (seed 1): ~300 heavy flakes span a pixel or more, 11-24 span 3 px or more, the
    # largest 6-11 px; light snow has half as many of a pixel or more.
    assert (heavy >= 3).sum() / 4 >= 10 and heavy.max() >= 6
    assert (heavy >= 1).sum() > 1.5 * (light >= 1).sum()
    hazy = field("snow", "heavy")
    assert 2.996 / hazy.haze_density() < 400  # "heavy snow" in the US weather service's terms


def test_presets_are_data_and_the_paper_preset_matches_the_paper() -> None:
    presets = load_presets()
    assert set(preset_names("rain")) >= {"light", "moderate", "heavy", "paper"}
    assert set(preset_names("snow")) >= {"light", "heavy", "paper"}
    assert presets["rain"]["presets"]["light"]["rate_mm_h"] == 2.5
    assert presets["rain"]["presets"]["moderate"]["rate_mm_h"] == 7.6
    assert presets["rain"]["presets"]["heavy"]["rate_mm_h"] == 25.0
    rain = Weather(kind="rain", preset="paper").particle_spec()
    snow = Weather(kind="snow", preset="paper").particle_spec()
    assert rain is not None and snow is not None
    assert (rain.count, rain.color, rain.scale_m, rain.opacity) == (
        40000,
        (0.7, 0.7, 0.8),
        (0.0025, 0.0025, 0.075),
        0.13,
    )
    assert (snow.count, snow.color, snow.scale_m, snow.opacity) == (
        16000,
        (0.9, 0.9, 0.95),
        (0.0064, 0.004, 0.004),
        0.2,
    )
    for kind in ("rain", "snow"):
        for name in preset_names(kind):
            assert Weather(kind=kind, preset=name).particle_spec() is not None


def test_physical_count_above_the_cap_scales_opacity_and_is_recorded() -> None:
    f = field("rain", "heavy")
    info = f.info()
    assert f.count == 40000 and info["capped"]
    assert info["represented_per_particle"] == pytest.approx(f.physical_count / 40000)
    assert f.physical_count == pytest.approx(f.density_per_m3 * np.prod(f.spec.box_size))
    g = f.gaussians(0.5, np.zeros(3), exposure_s=0.01)
    # One drop's streak has opacity a = o_drop sigma_cross / sigma_long; k of them 1 - (1 - a)^k,
    # times the fade near the radius and the lens.
    a = f.spec.opacity * g.scales[:, 0].astype(np.float64) / g.scales[:, 2]
    d = np.linalg.norm(g.means.astype(np.float64), axis=1)
    fade = np.clip((f.spec.radius_m - d) / f.spec.fade_m, 0, 1) * np.clip(d / f.spec.min_distance_m - 1, 0, 1)
    expected = (1 - (1 - a) ** f.represented) * fade
    np.testing.assert_allclose(g.opacities, expected, atol=2e-5)  # float32 means and scales
    assert g.opacities.max() <= 1.0 and np.median(g.opacities / fade.clip(1e-3)) > 5 * np.median(a)


# ---- kinematics and wrap ----------------------------------------------------------------------


@pytest.mark.parametrize("kind,preset", [("rain", "heavy"), ("snow", "light")])
def test_position_follows_the_closed_form_until_it_wraps(kind: str, preset: str) -> None:
    f = field(kind, preset, wind=Wind(6.0, 15.0, 40.0))
    t = 0.05  # short enough that most particles are still inside the (4 m wide) snow box
    pos, wraps = f.positions(t, np.zeros(3))
    closed = f.initial_positions() + f.displacement(t)
    rel = box_coords(f, closed, np.zeros(3))
    inside = np.all((rel >= f.spec.box_low) & (rel < f.spec.box_low + f.spec.box_size), axis=1)
    assert inside.mean() > 0.8  # most have not wrapped yet
    assert np.all(wraps[inside] == 0)
    np.testing.assert_allclose(pos[inside], closed[inside], atol=POS_TOL)
    # Velocity is gravity along -up plus wind (plus flutter for snow): check the finite difference.
    v_fd = (f.displacement(t + 1e-6) - f.displacement(t - 1e-6)) / 2e-6
    np.testing.assert_allclose(v_fd, f.velocity(t), atol=1e-5)
    if kind == "rain":
        expected = -f.fall_speed[:, None] * Z_UP + Wind(6.0, 15.0, 40.0).vector(f.basis)
        np.testing.assert_allclose(f.velocity(t), expected, atol=1e-12)


def test_wrap_keeps_count_and_uniform_density() -> None:
    from scipy.stats import chi2

    f = field("rain", "moderate", wind=Wind(8.0, 0.0, 70.0))
    center = np.array([37.2, -14.9, 0.8])  # the camera drove away from the anchor
    pos, wraps = f.positions(23.7, center)
    assert pos.shape == (40000, 3) and np.all(np.isfinite(pos))
    assert (wraps != 0).mean() > 0.9  # after 23.7 s nearly every drop has wrapped
    rel = box_coords(f, pos, center)
    low, size = f.spec.box_low, f.spec.box_size
    assert np.all(rel >= low - 1e-9) and np.all(rel <= low + size + 1e-9)
    bins = (10, 10, 8)
    hist, _ = np.histogramdd(rel, bins=bins, range=list(zip(low, low + size)))
    expected = len(pos) / hist.size
    stat = float(((hist - expected) ** 2 / expected).sum())
    assert chi2.sf(stat, hist.size - 1) > 1e-3, f"chi-square {stat} on {hist.size - 1} dof"


def test_vertical_wrap_redraws_the_horizontal_position() -> None:
    f = field("rain", "paper")
    i = 0
    samples = []
    fall = f.fall_speed[i]
    period = f.spec.box_size[2] / fall
    for k in range(1, 400):
        pos, wraps = f.positions(k * period + 0.01, np.zeros(3))
        assert wraps[i] == -k
        samples.append(box_coords(f, pos[i : i + 1], np.zeros(3))[0, :2])
    xy = np.array(samples)
    # Without a re-draw every wrap would land on the same horizontal spot; with it they are uniform.
    assert np.unique(np.round(xy, 6), axis=0).shape[0] == len(xy)
    assert abs(xy[:, 0].mean()) < 2.0 and abs(xy[:, 1].mean()) < 2.0
    assert xy[:, 0].std() == pytest.approx(20.0 / math.sqrt(12), rel=0.15)


def test_frame_is_a_pure_function_of_seed_and_time() -> None:
    center17 = np.array([5.0, 2.0, 0.1])
    seq = field("snow", "heavy", wind=Wind(4.0, 20.0, 30.0))
    for k in range(17):  # a sequence renders the earlier frames first
        seq.gaussians(k * 0.1, center17 * k / 17)
    alone = field("snow", "heavy", wind=Wind(4.0, 20.0, 30.0))
    a, b = seq.gaussians(1.7, center17), alone.gaussians(1.7, center17)
    for name in ("means", "quats", "scales", "opacities", "colors", "particle"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    # The flake sizes are drawn once from the seed, never from the frames rendered before.
    np.testing.assert_array_equal(seq.diameter_mm, alone.diameter_mm)
    assert np.unique(a.scales[:, 0]).size > 100  # one size per flake, not one for all
    other = field("snow", "heavy", wind=Wind(4.0, 20.0, 30.0), seed=4).gaussians(1.7, center17)
    assert not np.array_equal(other.means[:10], a.means[:10])


def _numba_kernels_or_skip():  # type: ignore[no-untyped-def]
    pytest.importorskip("numba")
    from wcbench.reference_model.weather.particles import _numba_kernels

    kernels = _numba_kernels()
    if kernels is None:
        pytest.skip("numba kernels unavailable")
    return kernels


def test_fast_sin_and_cos_match_libm() -> None:
    """The kernels' branch-free sin/cos against numpy's, over the arguments a sequence can reach."""
    kernels = _numba_kernels_or_skip()
    import numba

    fast_sin, fast_cos = kernels.fast_sin, kernels.fast_cos

    @numba.njit
    def both(x, s, c):  # type: ignore[no-untyped-def]
        for i in range(x.size):
            s[i] = fast_sin(x[i])
            c[i] = fast_cos(x[i])

    rng = np.random.default_rng(0)
    x = np.concatenate(
        [
            np.linspace(-4000.0, 4000.0, 400_001),
            rng.normal(0.0, 30.0, 100_000),
            np.arange(-2000, 2001) * (np.pi / 2),  # the reduction's boundaries
            [0.0, -0.0, 1e-300, np.pi, -np.pi, 9.9e3],
        ]
    )
    s, c = np.empty_like(x), np.empty_like(x)
    both(x, s, c)
    # libm itself is within 0.5 ulp; the reduction of |x| < 1e4 loses at most a few ulp of 1.
    assert np.abs(s - np.sin(x)).max() < 1e-15
    assert np.abs(c - np.cos(x)).max() < 1e-15


@pytest.mark.parametrize(
    ("kind", "preset", "overrides"),
    [
        ("rain", "heavy", {}),
        ("rain", "paper", {}),
        ("rain", "light", {"max_particles": 500}),  # represented = 1 and no cap
        ("snow", "heavy", {}),
        ("snow", "paper", {}),
    ],
)
def test_fast_gaussians_match_the_numpy_reference(kind: str, preset: str, overrides: dict) -> None:
    """Positions, culling, shapes, opacities (with the dilation compensation) and buffers."""
    from wcbench.reference_model.weather.particle_spec import ParticleGaussians

    _numba_kernels_or_skip()
    K = np.array([[250.0, 0, 160], [0, 250.0, 90], [0, 0, 1]])
    for t in (0.0, 0.7, 31.3):
        c = np.array([3.0 * t, 0.5, 0.2])
        w2c = np.eye(4)
        w2c[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]  # looks along +x with z up
        w2c[:3, 3] = -w2c[:3, :3] @ c
        view = (w2c, K, 320, 180)
        f = field(kind, preset, wind=Wind(7.0, 10.0, 100.0), **overrides)  # type: ignore[arg-type]
        cam_vel = np.array([3.0, 0.2, 0.0])
        kw = dict(exposure_s=0.02, camera_velocity=cam_vel, view=view, near=0.05, dilation_eps2d=0.3)
        fast = f.gaussians(t, c, fast=True, **kw)  # type: ignore[arg-type]
        ref = f.gaussians(t, c, fast=False, **kw)  # type: ignore[arg-type]
        assert len(ref) > 20
        if f.spec.physical:  # the twins are compared on particles of many sizes
            assert np.unique(ref.scales[:, 0]).size > 10
        np.testing.assert_array_equal(fast.particle, ref.particle)
        np.testing.assert_array_equal(fast.colors, ref.colors)
        # float32 outputs of float64 math; only sin/cos differ (4e-16) and the matrix products'
        # summation order in the dilation factor.
        for name in ("means", "quats", "scales", "velocity"):
            np.testing.assert_allclose(getattr(fast, name), getattr(ref, name), rtol=1e-6, atol=1e-6, err_msg=name)
        np.testing.assert_allclose(fast.opacities, ref.opacities, rtol=1e-5, atol=1e-7)
        # Positions and culling of all particles, without a view.
        p_fast, i_fast = f.visible(t, c, fast=True)
        p_ref, i_ref = f.visible(t, c, fast=False)
        np.testing.assert_array_equal(i_fast, i_ref)
        np.testing.assert_allclose(p_fast, p_ref, atol=POS_TOL)
        # Into caller buffers (both paths): views of the first rows, the rest untouched.
        for fast_path in (True, False):
            out = ParticleGaussians.allocate(f.max_gaussians + 5)
            out.opacities[:] = -1.0
            g = f.gaussians(t, c, fast=fast_path, out=out, **kw)  # type: ignore[arg-type]
            assert np.shares_memory(g.means, out.means) and len(g) == len(ref)
            np.testing.assert_allclose(g.opacities, ref.opacities, rtol=1e-5, atol=1e-7)
            assert np.all(out.opacities[len(g) :] == -1.0)


def test_gaussians_reject_a_small_buffer_and_compensation_without_view() -> None:
    from wcbench.reference_model.weather.particle_spec import ParticleGaussians

    f = field("snow", "paper")
    with pytest.raises(ValueError, match="needs up to 48000"):
        f.gaussians(0.0, np.zeros(3), out=ParticleGaussians.allocate(16000))
    with pytest.raises(ValueError, match="needs the view"):
        f.gaussians(0.0, np.zeros(3), dilation_eps2d=0.3)


def test_numpy_path_runs_when_the_kernels_cannot_be_imported(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    from wcbench.reference_model import _numba_backend

    f = field("snow", "heavy")
    expected = f.gaussians(1.0, np.zeros(3), fast=False)
    monkeypatch.setattr(_numba_backend, "_loaded", {})
    monkeypatch.setattr(_numba_backend, "_failed", {})
    monkeypatch.setitem(sys.modules, "wcbench.reference_model.weather.particle_kernels", None)  # import fails
    got = f.gaussians(1.0, np.zeros(3))
    np.testing.assert_array_equal(got.means, expected.means)
    assert "halted" in str(_numba_backend.numba_error("weather.particle_kernels"))


# ---- shapes --------------------------------------------------------------------------------------


def test_raindrop_long_axis_is_parallel_to_its_velocity() -> None:
    f = field("rain", "heavy", wind=Wind(9.0, -10.0, 75.0))
    g = f.gaussians(2.0, np.zeros(3), exposure_s=0.02)
    assert len(g) > 100
    R = quat_to_matrix(g.quats)
    long_axis = R[:, :, 2]  # local z carries the largest scale
    assert np.all(g.scales[:, 2] >= g.scales[:, 0]) and np.all(g.scales[:, 0] == g.scales[:, 1])
    v = g.velocity / np.linalg.norm(g.velocity, axis=1, keepdims=True)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", long_axis, v)), 1.0, atol=1e-5)
    # Streak length from the exposure: sigma^2 = (D/4)^2 + (|v| t_exp)^2 / 12.
    speed = np.linalg.norm(g.velocity, axis=1)
    np.testing.assert_allclose(g.scales[:, 2] ** 2, g.scales[:, 0] ** 2 + (speed * 0.02) ** 2 / 12, rtol=1e-4)


def test_snowflake_is_three_gaussians_at_60_degrees_sharing_a_center() -> None:
    f = field("snow", "paper", wind=Wind(3.0, 0.0, 0.0))
    g = f.gaussians(1.3, np.zeros(3))
    assert len(g) % 3 == 0 and len(g) > 0
    means = g.means.reshape(-1, 3, 3)
    np.testing.assert_array_equal(means[:, 0], means[:, 1])
    np.testing.assert_array_equal(means[:, 0], means[:, 2])
    assert np.all(g.particle.reshape(-1, 3) == g.particle.reshape(-1, 3)[:, :1])
    np.testing.assert_allclose(g.scales, np.tile([0.0064, 0.004, 0.004], (len(g), 1)), rtol=1e-6)
    R = quat_to_matrix(g.quats).reshape(-1, 3, 3, 3)
    arms, normals = R[..., :, 0], R[..., :, 2]  # local x = long axis, local z = flake normal
    for a, b in ((0, 1), (1, 2), (0, 2)):
        np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", arms[:, a], arms[:, b])), 0.5, atol=1e-5)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", normals[:, 0], normals[:, 1])), 1.0, atol=1e-5)


# ---- up vector and extremes --------------------------------------------------------------------


@pytest.mark.parametrize("up", [np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0]), np.array([0.3, -0.9, 0.2])])
def test_gravity_and_the_box_follow_the_up_vector(up: np.ndarray) -> None:
    up = up / np.linalg.norm(up)
    f = field("rain", "light", up=up)
    v = f.velocity(0.0)
    np.testing.assert_allclose(v / np.linalg.norm(v, axis=1, keepdims=True), np.tile(-up, (len(v), 1)), atol=1e-12)
    center = np.array([1.0, 2.0, 3.0])
    pos, _ = f.positions(4.2, center)
    height = (pos - center) @ up
    assert height.min() >= -f.spec.below_m - 1e-9 and height.max() <= f.spec.above_m + 1e-9
    basis = horizontal_basis(up)
    np.testing.assert_allclose(basis @ basis.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(basis) == pytest.approx(1.0)


@pytest.mark.parametrize("speed", [0.0, 60.0])
def test_wind_extremes_stay_finite(speed: float) -> None:
    f = field("rain", "heavy", wind=Wind(speed, 30.0, 200.0))
    g = f.gaussians(12.5, np.array([4.0, 1.0, 0.0]), exposure_s=0.01)
    assert len(g) > 0
    for name in ("means", "quats", "scales", "opacities"):
        assert np.all(np.isfinite(getattr(g, name)))
    assert np.all((g.opacities >= 0) & (g.opacities <= 1))


@pytest.mark.parametrize("rate", [0.0, 500.0])
def test_rain_rate_extremes(rate: float) -> None:
    f = field("rain", "heavy", rate_mm_h=rate)
    g = f.gaussians(1.0, np.zeros(3))
    if rate == 0:
        assert f.count == 0 and len(g) == 0 and f.haze_density() == 0.0
    else:
        assert f.count == f.spec.max_particles and f.represented > 100
        assert np.all(np.isfinite(g.opacities)) and g.opacities.max() <= 1.0
        assert 100 < 2.996 / f.haze_density() < 300  # a cloudburst: visibility of about 150 m


def test_camera_on_the_wrap_boundary() -> None:
    f = field("snow", "light")
    size = f.spec.box_size
    # Camera offsets of exactly a half and a whole box period: every floor() sits on an edge.
    for offset in (size / 2, size, -size, np.zeros(3)):
        center = offset @ f.basis
        pos, _ = f.positions(0.0, center)
        rel = box_coords(f, pos, center)
        assert np.all(np.isfinite(pos))
        assert np.all(rel >= f.spec.box_low - 1e-9) and np.all(rel <= f.spec.box_low + size + 1e-9)


def test_bad_parameters_raise_value_errors_naming_them() -> None:
    with pytest.raises(ValueError, match="rate_mm_h"):
        size_distribution("rain", -1.0)
    with pytest.raises(ValueError, match="tilt_deg"):
        Wind(3.0, 120.0, 0.0)
    with pytest.raises(ValueError, match="speed_m_s"):
        Wind(-1.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="up"):
        horizontal_basis(np.zeros(3))
    with pytest.raises(ValueError, match="preset"):
        Weather(kind="rain", preset="drizzle")
    with pytest.raises(ValueError, match="unknown rain particle settings"):
        ParticleSpec.from_mapping("rain", {"rate_mm_h": 1.0, "colour": [1, 1, 1]})
    with pytest.raises(ValueError, match="t must be finite"):
        field().positions(math.nan, np.zeros(3))


# ---- numeric guards (docs/design.md §9) -------------------------------------------------------


@pytest.mark.parametrize(
    ("setting", "value"),
    [("turbulence_m_s", math.nan), ("spin_rad_s", math.inf), ("radius_m", math.inf), ("fade_m", math.nan),
     ("flake_ratio", -1.0), ("dsd_n0_b", math.nan), ("color", (0.5, 2.0, 0.5)), ("haze_color", (math.nan, 0, 0)),
     ("above_m", 1e38), ("fall_speed_m_s", 1e300), ("scale_m", (0.01, 0.01, 1e-40)), ("min_diameter_mm", 1e-40)],
)
def test_spec_refuses_numbers_without_a_meaning(setting: str, value: object) -> None:
    # lengths must be float32 positions (above_m) or normal float32 sizes (scale_m, diameters)
    name = "diameters" if setting == "min_diameter_mm" else setting
    with pytest.raises(ValueError, match=name):
        if setting == "scale_m":
            ParticleSpec(kind="snow", count=10, fall_speed_m_s=1.0, scale_m=value)  # type: ignore[arg-type]
        else:
            ParticleSpec(kind="snow", rate_mm_h=2.0, **{setting: value})  # type: ignore[arg-type]


def test_size_distribution_and_counts_that_overflow_are_refused() -> None:
    spec = ParticleSpec(kind="snow", rate_mm_h=1e-300, dsd_n0_b=-5.0)  # N0 = 3800 R^-5 overflows
    with pytest.raises(ValueError, match="not representable"):
        size_distribution("snow", 1e-300, spec)
    with pytest.raises(ValueError, match="not representable"):
        ParticleField(spec)


def test_frames_beyond_exact_kinematics_are_refused_by_both_paths() -> None:
    from dataclasses import replace

    _numba_kernels_or_skip()
    f = ParticleField(replace(field("snow", "heavy").spec, turbulence_m_s=0.5))  # flutter up to 2 pi rad/s
    for fast in (True, False):
        f.gaussians(1e5, np.zeros(3), fast=fast)  # phases ~6e5 rad: still exact
        with pytest.raises(ValueError, match="flutter and spin phases"):
            f.gaussians(1e6, np.zeros(3), fast=fast)
        with pytest.raises(ValueError, match="camera_center"):
            f.gaussians(0.0, np.array([1e38, 0.0, 0.0]), fast=fast)
        with pytest.raises(ValueError, match="camera_velocity"):
            f.gaussians(0.0, np.zeros(3), camera_velocity=np.array([np.nan, 0, 0]), fast=fast)
        with pytest.raises(ValueError, match="K must be finite"):
            f.gaussians(0.0, np.zeros(3), view=(np.eye(4), np.zeros((3, 3)), 64, 48), fast=fast)
    rain = field("rain", "heavy")
    with pytest.raises(ValueError, match="beyond float32"):
        rain.gaussians(0.0, np.zeros(3), exposure_s=1e38)  # streaks of ~1e38 m


def test_seeds_beyond_64_bits_give_the_same_particles_on_both_paths() -> None:
    _numba_kernels_or_skip()
    f = field("rain", "heavy", seed=2**64 + 7)
    c = np.array([0.0, 0.0, 0.0])
    t = 40.0  # late enough that particles have wrapped (the hash of the seed re-draws them)
    p_fast, i_fast = f.visible(t, c, fast=True)
    p_ref, i_ref = f.visible(t, c, fast=False)
    np.testing.assert_array_equal(i_fast, i_ref)
    np.testing.assert_allclose(p_fast, p_ref, atol=POS_TOL)


def test_long_thin_streaks_get_the_same_dilation_factor_on_both_paths() -> None:
    """Streaks 1e6 times longer than wide: det(Sigma) from the minors (Cauchy-Binet), not
    c00 c11 - c01^2, which is rounding noise there; fast and numpy paths agree."""
    from wcbench.reference_model.weather.particle_geometry import particle_dilation_compensation

    _numba_kernels_or_skip()
    K = np.array([[250.0, 0, 160], [0, 250.0, 90], [0, 0, 1]])
    w2c = np.eye(4)
    w2c[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]
    view = (w2c, K, 320, 180)
    f = field("rain", "heavy", wind=Wind(9.0, 20.0, 60.0))
    kw = dict(exposure_s=3.0, view=view, near=0.05, dilation_eps2d=0.3)
    fast = f.gaussians(5.0, np.zeros(3), fast=True, **kw)  # type: ignore[arg-type]
    ref = f.gaussians(5.0, np.zeros(3), fast=False, **kw)  # type: ignore[arg-type]
    assert len(ref) > 20 and float((ref.scales[:, 2] / ref.scales[:, 0]).max()) > 1e4
    np.testing.assert_allclose(fast.opacities, ref.opacities, rtol=1e-5, atol=1e-7)
    # The factor itself against a float64 closed form for one streak along the image x axis: a
    # Gaussian with sigmas (s, s, L) projected at depth z has det ~ (f s / z)^2 (f L / z)^2.
    means = np.array([[10.0, 0.0, 0.0]])
    quats = np.array([[np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]])  # local z -> world -y (image x)
    scales = np.array([[1e-4, 1e-4, 1e2]])
    got = particle_dilation_compensation(means, quats, scales, w2c, K, eps2d=0.3)
    a, b = (250.0 * 1e-4 / 10.0) ** 2, (250.0 * 1e2 / 10.0) ** 2
    expected = math.sqrt(a * b / ((a + 0.3) * (b + 0.3)))
    assert got[0] == pytest.approx(expected, rel=1e-5)
