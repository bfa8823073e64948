"""The unified weather render: occlusion, culling, determinism, up vector, extremes, CLI smoke test."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

from wcbench.reference_model.scene_graph.gaussians import GaussianCloud
from wcbench.reference_model.weather.conditions import Weather
from wcbench.reference_model.weather.particle_spec import ParticleGaussians, Wind
from wcbench.reference_model.weather.renderer import WeatherRenderer, camera_velocity, scale_camera
from wcbench.scenes.scene import Camera

UP = np.array([0.0, -1.0, 0.0])  # camera at the origin with OpenCV axes: world up is -y


def wall(distance: float = 5.0, half: float = 6.0, spacing: float = 0.05) -> GaussianCloud:
    """An opaque gray wall facing the camera at z = ``distance``."""
    g = np.arange(-half, half + 1e-9, spacing)
    x, y = np.meshgrid(g, g)
    n = x.size
    return GaussianCloud(
        means=np.stack([x.ravel(), y.ravel(), np.full(n, distance)], 1),
        quats=np.tile([1.0, 0, 0, 0], (n, 1)),
        scales=np.tile([spacing, spacing, spacing * 0.1], (n, 1)),
        opacities=np.full(n, 0.99),
        colors=np.full((n, 3), 0.3),
    )


def camera(width: int = 64, height: int = 48, f: float = 40.0, c2w: np.ndarray | None = None) -> Camera:
    K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    return Camera(K=K, width=width, height=height, camera_to_world=np.eye(4) if c2w is None else c2w)


def one_particle(z: float, *, scale: float = 0.05, opacity: float = 0.99) -> ParticleGaussians:
    f32 = np.float32
    return ParticleGaussians(
        means=np.array([[0.0, 0.0, z]], f32),
        quats=np.array([[1.0, 0, 0, 0]], f32),
        scales=np.full((1, 3), scale, f32),
        opacities=np.array([opacity], f32),
        colors=np.ones((1, 3), f32),
        particle=np.zeros(1, np.int64),
        velocity=np.zeros((1, 3), f32),
    )


def test_particle_behind_an_opaque_wall_is_invisible_and_in_front_visible() -> None:
    r = WeatherRenderer(wall(5.0), Weather(kind="rain", preset="paper"), up=UP)
    cam = camera()
    base = r.render(cam, 0.0, particles=ParticleGaussians.empty()).image
    front = r.render(cam, 0.0, particles=one_particle(3.0, scale=0.2)).image
    behind = r.render(cam, 0.0, particles=one_particle(8.0, scale=0.4)).image
    assert front[24, 32].min() > 0.9  # white particle drawn over the gray wall
    assert np.abs(behind - base).max() < 1e-3  # only the 1e-4 leftover transmittance of the wall


def test_clear_and_fog_build_no_particles_and_depth_only_for_the_postprocess() -> None:
    cam = camera()
    for weather, has_depth in (
        (Weather(), False),
        (Weather(kind="fog", visibility_m=50.0), False),
        (Weather(kind="fog", visibility_m=50.0, fog_mode="postprocess"), True),
    ):
        r = WeatherRenderer(wall(), weather, up=UP)
        assert r.field is None
        frame = r.render(cam, 1.0)
        assert frame.info["particles_in_view"] == 0 and frame.info["rasterized"] == len(wall())
        assert (frame.depth is not None) == has_depth


@pytest.mark.parametrize("weather", [
    Weather(kind="fog", visibility_m=30.0),
    Weather(kind="fog", visibility_m=30.0, fog_mode="postprocess"),
    Weather(kind="rain", preset="paper", visibility_m=200.0, fog_mode="exact"),
    Weather(),
])
def test_a_background_image_shows_exactly_when_the_renderer_says_it_can(weather) -> None:
    # a wall with a hole: the background shows through it unless fog hides it at infinity
    cloud = wall(5.0, half=6.0, spacing=0.05)
    keep = (np.abs(cloud.means[:, 0]) > 1.0) | (np.abs(cloud.means[:, 1]) > 1.0)
    cloud = GaussianCloud(**{k: getattr(cloud, k)[keep] for k in ("means", "quats", "scales", "opacities",
                                                                   "colors")})
    r = WeatherRenderer(cloud, weather, up=UP)
    cam = camera()
    sky = np.random.default_rng(0).uniform(0, 1, (cam.height, cam.width, 3)).astype(np.float32)
    with_sky = r.render(cam, 0.5, background_image=sky).image
    without = r.render(cam, 0.5, background_image=np.zeros_like(sky)).image
    if r.background_visible:
        assert np.abs(with_sky - without)[24, 32].max() > 0.1
    else:
        np.testing.assert_allclose(with_sky, without, rtol=0, atol=1e-6)


def test_particles_outside_the_frustum_are_dropped_before_rasterizing() -> None:
    cam = camera(80, 60, 50.0)
    r = WeatherRenderer(wall(9.0), Weather(kind="rain", preset="paper", wind=Wind(3.0, 0.0, 45.0)), up=UP)
    parts, counts = r.particles(cam, 2.0)
    in_range = r.field.gaussians(2.0, cam.center)  # type: ignore[union-attr]
    assert 0 < counts["particles_in_view"] == len(parts) < len(in_range) / 3
    uv, z = cam.project(parts.means)
    margin = 3 * 0.075 * 50.0 / z + 3  # 3-sigma streak extent in pixels + dilation
    assert np.all(z > r.near)
    assert np.all(
        (uv[:, 0] > -margin) & (uv[:, 0] < 80 + margin) & (uv[:, 1] > -margin) & (uv[:, 1] < 60 + margin)
    )
    frame = r.render(cam, 2.0)
    assert frame.info["rasterized"] == len(wall(9.0)) + len(parts)


def test_render_is_deterministic_and_frame_17_alone_matches_the_sequence() -> None:
    weather = Weather(kind="snow", preset="heavy", wind=Wind(4.0, 20.0, 30.0), seed=7)
    poses = []
    for k in range(18):  # the camera drives forward along +z
        c2w = np.eye(4)
        c2w[2, 3] = 0.4 * k
        poses.append(camera(c2w=c2w))
    seq = WeatherRenderer(wall(15.0, half=10.0, spacing=0.1), weather, up=UP)
    images = [seq.render(poses[k], 0.1 * k).image for k in (0, 5, 16, 17)]
    alone = WeatherRenderer(wall(15.0, half=10.0, spacing=0.1), weather, up=UP).render(poses[17], 1.7).image
    np.testing.assert_array_equal(images[-1], alone)
    assert not np.array_equal(images[-2], images[-1])  # the flakes move
    other = WeatherRenderer(
        wall(15.0, half=10.0, spacing=0.1), Weather(kind="snow", preset="heavy", seed=8), up=UP
    )
    assert not np.array_equal(other.render(poses[17], 1.7).image, alone)


@pytest.mark.parametrize("up", [np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0])])
def test_rain_falls_along_minus_up_in_the_rendered_frame(up: np.ndarray) -> None:
    # A camera looking horizontally in each world: for z-up its y axis (down) is -z.
    c2w = np.eye(4)
    if up[2] == 1.0:
        c2w[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    cam = camera(80, 60, 50.0, c2w)
    r = WeatherRenderer(
        GaussianCloud(*(np.zeros((0, k)) for k in (3, 4, 3)), np.zeros(0), np.zeros((0, 3))),
        Weather(kind="rain", preset="light"),
        up=up,
    )
    parts, _ = r.particles(cam, 0.5)
    v = parts.velocity / np.linalg.norm(parts.velocity, axis=1, keepdims=True)
    np.testing.assert_allclose(v, np.tile(-up, (len(v), 1)), atol=1e-6)
    # In the image the drops fall downward: camera y (down) grows along the velocity.
    v_cam = parts.velocity @ np.linalg.inv(c2w)[:3, :3].T
    assert np.all(v_cam[:, 1] > 0)


@pytest.mark.parametrize("kind", ["rain", "snow"])
def test_buffered_fast_render_matches_a_render_of_the_reference_particles(kind: str) -> None:
    """The renderer writes particles behind the scene in reused buffers (numba); rasterizing the
    numpy reference's particles, concatenated, gives the same image. Per-frame scenes (of the
    same size, then of another) refill the scene rows, and the renderer's own scene comes back."""
    from wcbench.reference_model.raster.common import EPS2D

    cam = camera(96, 64, 60.0)
    weather = Weather(kind=kind, preset="heavy", wind=Wind(3.0, 10.0, 45.0))
    r = WeatherRenderer(wall(8.0, spacing=0.2), weather, up=UP)
    scenes = (None, None, wall(6.0, spacing=0.2), None, wall(6.0, spacing=0.25), wall(5.0, spacing=0.25), None)
    for t, scene in zip(np.linspace(0.4, 1.9, len(scenes)), scenes):
        got = r.render(cam, t, gaussians=scene)
        assert r.field is not None
        ref_parts = r.field.gaussians(
            t,
            cam.center,
            exposure_s=weather.exposure(),
            view=(cam.world_to_camera, cam.K, cam.width, cam.height),
            near=r.near,
            dilation_eps2d=EPS2D,
            fast=False,
        )
        assert len(ref_parts) > 50 and got.info["particles_in_view"] == len(ref_parts)
        ref = r.render(cam, t, gaussians=scene, particles=ref_parts)
        # Particle parameters agree to ~1e-6 relative (float32 of float64 math).
        np.testing.assert_allclose(got.image, ref.image, atol=1e-4)
        np.testing.assert_allclose(got.alpha, ref.alpha, atol=1e-4)


def test_dilation_compensation_keeps_a_thin_streaks_coverage_resolution_independent() -> None:
    streak = ParticleGaussians(
        means=np.array([[0.0, 0.0, 4.0]], np.float32),
        quats=np.array([[1.0, 0, 0, 0]], np.float32),
        scales=np.array([[0.002, 0.002, 0.1]], np.float32),
        opacities=np.array([0.9], np.float32),
        colors=np.ones((1, 3), np.float32),
        particle=np.zeros(1, np.int64),
        velocity=np.zeros((1, 3), np.float32),
    )
    # Tilt the streak into the image plane (local z -> camera y).
    streak.quats[:] = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0, 0]
    empty = GaussianCloud(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    from wcbench.reference_model.raster.common import EPS2D
    from wcbench.reference_model.weather.particle_geometry import particle_dilation_compensation

    coverage = {}
    for compensate in (True, False):
        for size in (64, 256):
            cam = camera(size, size, size * 0.8)
            r = WeatherRenderer(empty, Weather(), up=UP, compensate_dilation=compensate)
            p = ParticleGaussians(**{k: v.copy() for k, v in streak.__dict__.items()})
            if compensate:
                p.opacities *= particle_dilation_compensation(
                    p.means, p.quats, p.scales, cam.world_to_camera, cam.K, eps2d=EPS2D
                )
            coverage[compensate, size] = float(r.render(cam, 0.0, particles=p).alpha.sum()) / size**2
    # Pairs under 1/255 are skipped: a faint Gaussian loses exp(-r^2 / 2) = 1 / (255 o) of its
    # integral beyond the box radius r, ~10 % here at 64 px and ~2 % at 256 px.
    assert coverage[True, 64] == pytest.approx(coverage[True, 256], rel=0.15)
    assert coverage[False, 64] > 2.0 * coverage[False, 256]  # the dilation inflates it at low resolution


def test_extremes_render_finite_images() -> None:
    cam = camera()
    scene = wall(5.0)
    for weather in (
        Weather(kind="rain", rate_mm_h=500.0),
        Weather(kind="rain", preset="heavy", wind=Wind(60.0)),
        Weather(kind="snow", preset="heavy", wind=Wind(0.0)),
        Weather(kind="fog", fog_density=1e3),
        Weather(kind="rain", rate_mm_h=0.0),
    ):
        frame = WeatherRenderer(scene, weather, up=UP).render(
            cam, 3.3, camera_velocity=np.array([0, 0, 30.0])
        )
        assert np.all(np.isfinite(frame.image)) and frame.image.min() >= 0 and frame.image.max() <= 1
    r = WeatherRenderer(scene, Weather(kind="rain", preset="paper"), up=UP)
    for z in (r.near, r.near * 1.001, 0.0, -1.0):  # on, just past, at and behind the near plane
        frame = r.render(cam, 0.0, particles=one_particle(z, scale=0.01))
        assert np.all(np.isfinite(frame.image))


def test_camera_helpers() -> None:
    cam = camera(64, 48, 40.0)
    half = scale_camera(cam, 32, 24)
    np.testing.assert_allclose(half.K, np.array([[20.0, 0, 16], [0, 20.0, 12], [0, 0, 1]]))
    uv, _ = cam.project(np.array([[0.3, -0.2, 2.0]]))
    uv_half, _ = half.project(np.array([[0.3, -0.2, 2.0]]))
    np.testing.assert_allclose(uv_half, uv / 2)
    centers = np.array([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0]])
    times = np.array([0.0, 0.1, 0.2])
    np.testing.assert_allclose(camera_velocity(centers, times, 1), [15.0, 0, 0])
    np.testing.assert_allclose(camera_velocity(centers, times, 0), [10.0, 0, 0])
    with pytest.raises(ValueError, match="width"):
        scale_camera(cam, 0, 10)




@pytest.mark.parametrize("weather", [Weather(kind="rain", preset="paper"), Weather()])
def test_rows_changed_in_place_and_refreshed_render_as_the_same_scene_passed_per_frame(weather: Weather) -> None:
    # refresh_scene is the fast path of a moving scene; passing the frame's Gaussians is its twin
    g = wall(4.0, half=2.0, spacing=0.1)
    arrays = {name: np.array(getattr(g, name), np.float32) for name in ("means", "quats", "scales", "opacities",
                                                                        "colors")}
    own = WeatherRenderer(GaussianCloud(**arrays), weather, up=UP, anchor=np.zeros(3))
    twin = WeatherRenderer(GaussianCloud(**arrays), weather, up=UP, anchor=np.zeros(3))
    cam = camera()
    own.render(cam, 0.0)  # fills the buffers in front of the particles
    moved = slice(100, 900)
    for t in (0.1, 0.2):
        arrays["means"][moved] += np.float32(0.3)
        arrays["opacities"][moved] = np.float32(t)
        own.scene["means"].numpy()[moved] = arrays["means"][moved]
        own.scene["opacities"].numpy()[moved] = arrays["opacities"][moved]
        own.refresh_scene([moved])
        got = own.render(cam, t).image
        ref = twin.render(cam, t, gaussians=GaussianCloud(**{k: v.copy() for k, v in arrays.items()})).image
        assert np.array_equal(got, ref)  # the same Gaussians in the same order: the same bits
    with pytest.raises(ValueError, match="contiguous ranges"):
        own.refresh_scene([slice(0, len(g) + 1)])
