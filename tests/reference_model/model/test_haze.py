"""Haze in the training render: the same image as the renderer's exact Beer-Lambert fog, and it
trains the decoders behind the haze."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import weather_models as wm  # noqa: E402

from wcbench.reference_model.model.haze import Haze, compose_haze, haze_transmittance  # noqa: E402
from wcbench.reference_model.weather.conditions import Weather  # noqa: E402
from wcbench.reference_model.weather.fog import compose_exact, transmitted_channels  # noqa: E402
from wcbench.reference_model.weather.renderer import WeatherRenderer  # noqa: E402
from wcbench.scenes.scene import Camera  # noqa: E402

pytestmark = pytest.mark.model

# a camera moved off the origin, so the haze's distances need its true centre
W2C = np.eye(4)
W2C[:3, 3] = [0.4, -0.3, 1.5]


class _Set:
    def __init__(self, means, quats, scales, opacities, colors):
        self.means, self.quats, self.scales, self.opacities, self.colors = means, quats, scales, opacities, colors


def _render(model, weathers, hazes=None):
    return model.render(1, W2C, wm.K, wm.WIDTH, wm.HEIGHT, weathers, sky_grid=wm.sky_grid(model), depth=False,
                        hazes=hazes)


def test_hazed_training_render_equals_the_renderers_exact_fog():
    model = wm.make_model(("clear", "rain", "fog"))
    with torch.no_grad():
        model.decoders.b2[2] += 0.4  # fog colors differ from clear ones
    weather = Weather(kind="fog", visibility_m=25.0)
    haze = Haze.of(weather)
    assert haze.beta == pytest.approx(-np.log(0.05) / 25.0, rel=1e-9)  # the 5 % MOR
    with torch.no_grad():
        out = _render(model, ("clear", "fog"), {"fog": haze})
        plain = _render(model, ("clear", "fog"))
        g = model.frame_gaussians(1)
        colors = g.colors(lambda f: model.decoders(f, ["fog"]))
    camera = Camera(K=wm.K, width=wm.WIDTH, height=wm.HEIGHT, camera_to_world=np.linalg.inv(W2C))
    renderer = WeatherRenderer(_Set(g.means, g.quats, g.scales, g.opacities, colors), weather,
                               up=np.array([0.0, -1.0, 0.0]))
    reference = renderer.render(camera, 0.0).image  # numpy channels + compose_exact
    torch.testing.assert_close(out.image("fog"), torch.from_numpy(reference), atol=2e-5, rtol=0)
    # the weather without a haze is untouched, and the haze really changed the fog image
    torch.testing.assert_close(out.image("clear"), plain.image("clear"), atol=0, rtol=0)
    assert (out.image("fog") - plain.image("fog")).abs().max() > 0.1


def test_offset_haze_matches_the_numpy_channels_and_composition():
    # rain and snow haze starts at the particle box's radius: offset_m
    haze = Haze(beta=0.08, color=(0.6, 0.62, 0.66), offset_m=7.0)
    gen = torch.Generator().manual_seed(0)
    means = torch.randn(200, 3, generator=gen) * 6.0
    center = torch.tensor([0.5, -0.2, 1.0])
    t = haze_transmittance(means, center, [haze])[:, 0]
    colors = torch.rand(200, 3, generator=gen)
    ref = transmitted_channels(means.numpy(), colors.numpy(), center.numpy(), haze.beta, offset_m=haze.offset_m,
                               fast=False)
    torch.testing.assert_close(torch.cat([colors * t[:, None], t[:, None]], 1), torch.from_numpy(ref),
                               atol=1e-6, rtol=0)
    sum_ct, sum_t = torch.rand(5, 7, 3, generator=gen) * 0.5, torch.rand(5, 7, generator=gen) * 0.5
    alpha = (sum_t + torch.rand(5, 7, generator=gen) * 0.4).clamp(max=1.0)
    expected = compose_exact(sum_ct.numpy(), sum_t.numpy(), alpha.numpy(), beta=haze.beta,
                             fog_color=np.array(haze.color), fast=False)
    torch.testing.assert_close(compose_haze(sum_ct, sum_t, alpha, haze), torch.from_numpy(expected),
                               atol=1e-6, rtol=0)


@pytest.mark.slow  # 57 s: a decoder trained to convergence; the compositing it relies on is tested above
def test_a_decoder_fitted_through_the_haze_learns_the_colors_behind_it():
    # Targets: the fog render of known colors. Fitted through the haze, the fog decoder recovers
    # those colors; fitted to the hazed frames as they are (no haze), it learns the haze into them.
    haze = Haze(beta=0.12, color=(0.8, 0.8, 0.85))
    truth_model = wm.make_model(("clear", "fog"), with_car=False)
    with torch.no_grad():
        truth_model.decoders.b2[1] += 0.5
        target = _render(truth_model, ("fog",), {"fog": haze}).images
        g = truth_model.frame_gaussians(1)
        true_colors = g.colors(lambda f: truth_model.decoders(f, ["fog"]))

    def fit(hazes):
        model = wm.make_model(("clear", "fog"), with_car=False)
        opt = torch.optim.Adam(model.decoders.parameters(), lr=0.02)
        for _ in range(150):
            opt.zero_grad()
            loss = (_render(model, ("fog",), hazes).images - target).abs().mean()
            loss.backward()
            opt.step()
        with torch.no_grad():
            colors = model.frame_gaussians(1).colors(lambda f: model.decoders(f, ["fog"]))
        return float((colors - true_colors).abs().mean())

    through, as_is = fit({"fog": haze}), fit(None)
    assert through < 0.03, through
    assert as_is > 3 * through, (as_is, through)


@pytest.mark.parametrize("fields", [{"kind": "rain", "preset": "heavy"}, {"kind": "snow", "preset": "light"},
                                    {"kind": "rain", "rate_mm_h": 4.0, "seed": 3}, {"kind": "snow", "preset": "paper"},
                                    {"kind": "fog", "visibility_m": 80.0}])
def test_weather_haze_without_particles_equals_the_renderers(fields):
    from wcbench.reference_model.weather.particles import ParticleField

    weather = Weather(**fields)
    spec = weather.particle_spec()
    field_ = None if spec is None else ParticleField(spec, wind=weather.wind, seed=weather.seed)
    beta, color, offset = weather.fog_parameters(field_)  # what WeatherRenderer uses
    h_beta, h_color, h_offset = weather.haze()  # no particle drawn
    assert h_beta == beta and h_offset == offset and np.array_equal(h_color, color)


def test_haze_is_validated():
    with pytest.raises(ValueError, match="beta"):
        Haze(beta=-1.0, color=(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="color"):
        Haze(beta=0.1, color=(0.5, 1.5, 0.5))
    with pytest.raises(ValueError, match="offset_m"):
        Haze(beta=0.1, color=(0.5, 0.5, 0.5), offset_m=float("nan"))
    assert Haze.of(Weather(kind="clear")).beta == 0.0
    rain = Haze.of(Weather(kind="rain", preset="heavy"))
    assert rain.beta > 0 and rain.offset_m > 0
