"""One render of a Gaussian scene under a weather: particles, scene and fog together.

The :class:`WeatherRenderer` turns a :class:`~.conditions.Weather` into images: rain and snow
particles (:mod:`.particles`) are rasterized together with the scene Gaussians in one call, so
occlusion and blending are correct, then fog (:mod:`.fog`) is composed on top: the exact per-layer
form by default (one extra channel, no depth map), or the paper's depth-map post-process. Far rain
and snow act as haze (fog of their own extinction coefficient starting at the particle radius).
Clear and fog build no particles, and particles outside the view frustum are dropped before
rasterizing.

Frame t is a pure function of (weather, t, camera): rendering frame 17 alone equals frame 17 of a
sequence. Images are float32 RGB in [0, 1].
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any, Protocol

import numpy as np
import torch

from wcbench.reference_model.raster.common import EPS2D
from wcbench.reference_model.raster.rasterizer import rasterize
from wcbench.reference_model.weather.conditions import FOG_MODES, Weather
from wcbench.reference_model.weather.fog import (
    compose_exact,
    fog_postprocess,
    transmitted_channels,
    visibility_from_density,
)
from wcbench.reference_model.weather.particle_spec import ParticleGaussians
from wcbench.reference_model.weather.particles import ParticleField

__all__ = [
    "GaussianArrays",
    "GaussianSet",
    "WeatherFrame",
    "WeatherRenderer",
    "camera_velocity",
    "scale_camera",
]


class GaussianSet(Protocol):
    """Anything with the five Gaussian arrays (e.g. a
    :class:`~wcbench.reference_model.scene_graph.gaussians.GaussianCloud`)."""

    means: Any  # [N, 3] world (m)
    quats: Any  # [N, 4] wxyz
    scales: Any  # [N, 3] (m)
    opacities: Any  # [N] in [0, 1]
    colors: Any  # [N, 3] RGB in [0, 1]


@dataclass
class GaussianArrays:
    """The five Gaussian arrays as given (numpy arrays or torch tensors, not copied): a
    :class:`GaussianSet` for callers that hold loose arrays (a frame's decoded Gaussians, a
    generated scene)."""

    means: Any  # [N, 3] world (m)
    quats: Any  # [N, 4] wxyz
    scales: Any  # [N, 3] (m)
    opacities: Any  # [N] in [0, 1]
    colors: Any  # [N, 3] RGB in [0, 1]


# --------------------------------------------------------------------------------------------
# Camera helpers


def scale_camera(camera: Any, width: int, height: int) -> Any:
    """A copy of ``camera`` (:class:`wcbench.scenes.scene.Camera`) resized to ``width`` x ``height`` px.

    With pixel centers at +0.5 a resize scales continuous pixel coordinates, so
    K' = diag(width / W, height / H, 1) K exactly.

    Raises
    ------
    ValueError
        If ``width`` or ``height`` is not a positive integer.
    """
    if int(width) != width or int(height) != height or width < 1 or height < 1:
        raise ValueError(f"width and height must be positive integers, got {width} x {height}")
    sx, sy = width / camera.width, height / camera.height
    K = np.diag([sx, sy, 1.0]) @ np.asarray(camera.K, np.float64)
    return replace(camera, K=K, width=int(width), height=int(height))


def camera_velocity(centers: np.ndarray, times: np.ndarray, index: int) -> np.ndarray:
    """World velocity (m/s) of the camera at frame ``index`` by central differences.

    Parameters
    ----------
    centers : ndarray [F, 3]
        Camera centers of the sequence (m).
    times : ndarray [F]
        Timestamps (s).
    index : int
        Frame.

    Returns
    -------
    ndarray [3] float64
        Zero for a single frame or a non-increasing clock.
    """
    centers = np.asarray(centers, np.float64)
    times = np.asarray(times, np.float64)
    if len(centers) < 2:
        return np.zeros(3)
    i0, i1 = max(index - 1, 0), min(index + 1, len(centers) - 1)
    dt = times[i1] - times[i0]
    if not dt > 0:
        return np.zeros(3)
    return (centers[i1] - centers[i0]) / dt


# --------------------------------------------------------------------------------------------
# Rendering


def _as_tensors(gaussians: GaussianSet) -> dict[str, Any]:
    """The five arrays as contiguous float32 CPU tensors (no copy for float32 numpy), shapes checked."""
    arrays = {}
    for name in ("means", "quats", "scales", "opacities", "colors"):
        value = getattr(gaussians, name)
        t = value.detach() if isinstance(value, torch.Tensor) else torch.from_numpy(np.asarray(value))
        arrays[name] = t.to(torch.float32).contiguous()
    n = arrays["means"].shape[0]
    shapes = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,), "colors": (n, 3)}
    for name, shape in shapes.items():
        if tuple(arrays[name].shape) != shape:
            raise ValueError(f"gaussians.{name} must have shape {shape}, got {tuple(arrays[name].shape)}")
    return arrays


_GAUSSIAN_ARRAYS = ("means", "quats", "scales", "opacities", "colors")


@dataclass
class _CombinedBuffers:
    """Scene Gaussians (first ``n_scene`` rows) followed by room for a frame's particles."""

    n_scene: int
    arrays: dict[str, np.ndarray]  # the five Gaussian arrays, [n_scene + max particles, ...]
    tail: ParticleGaussians  # views of the particle rows (+ their own index/velocity arrays)
    holds_own_scene: bool = False  # the scene rows hold the renderer's own scene (not yet filled)

    @staticmethod
    def allocate(n_scene: int, n_particles: int) -> _CombinedBuffers:
        tail = ParticleGaussians.allocate(n_particles)
        arrays = {
            name: np.empty((n_scene + n_particles, *getattr(tail, name).shape[1:]), np.float32)
            for name in _GAUSSIAN_ARRAYS
        }
        for name in _GAUSSIAN_ARRAYS:
            setattr(tail, name, arrays[name][n_scene:])
        return _CombinedBuffers(n_scene=n_scene, arrays=arrays, tail=tail)


@dataclass
class WeatherFrame:
    """One rendered frame.

    Attributes
    ----------
    image : ndarray [H, W, 3] float32
        RGB in [0, 1] (fog and particles included).
    alpha : ndarray [H, W] float32
        Accumulated opacity of scene + particles.
    depth : ndarray [H, W] float32 or None
        Expected depth, only when the fog mode needed it (``postprocess``).
    info : dict
        Counts and settings of this frame (JSON-ready).
    timings_ms : dict
        ``particles``, ``raster``, ``fog``, ``total`` wall times (ms).
    """

    image: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray | None
    info: dict[str, Any]
    timings_ms: dict[str, float]


class WeatherRenderer:
    """Renders a Gaussian scene under a :class:`Weather`, frame by frame.

    The particle field is built once (it is a pure function of the weather and the parameters
    below), so a sequence costs one construction; each frame only evaluates closed forms.

    Parameters
    ----------
    gaussians : GaussianSet
        Scene Gaussians (numpy arrays or torch tensors): means [N, 3] world m, quats [N, 4] wxyz,
        scales [N, 3] m, opacities [N] in [0, 1], colors [N, 3] RGB in [0, 1].
    weather : Weather
    up : ndarray [3]
        World up vector (gravity along ``-up``).
    heading : ndarray [3], optional
        Direction of wind azimuth 0 (projected on the horizontal plane); e.g. the first camera's
        z axis.
    anchor : ndarray [3], optional
        Where the particle box is centred at t = 0 (default: origin).
    background : ndarray [3], optional
        Background (sky) color; black when omitted.
    near : float
        Rasterizer near plane (m).
    compensate_dilation : bool
        Scale particle opacities by :func:`particle_dilation_compensation` (default on).
    rasterizer : callable, optional
        ``rasterize``-compatible function (default: :func:`.rasterize.rasterize`).
    """

    def __init__(
        self,
        gaussians: GaussianSet,
        weather: Weather,
        *,
        up: np.ndarray,
        heading: np.ndarray | None = None,
        anchor: np.ndarray | None = None,
        background: np.ndarray | None = None,
        near: float = 0.01,
        compensate_dilation: bool = True,
        rasterizer: Callable[..., Any] | None = None,
    ) -> None:

        self.weather = weather
        self.near = float(near)
        self.compensate_dilation = compensate_dilation
        self.rasterizer: Callable[..., Any] = rasterize if rasterizer is None else rasterizer
        self.background = np.zeros(3, np.float32) if background is None else np.asarray(background, np.float32)
        if self.background.shape != (3,) or not np.all(np.isfinite(self.background)):
            raise ValueError(f"background must be 3 finite numbers, got {background!r}")
        self.scene = _as_tensors(gaussians)
        spec = weather.particle_spec()
        self.field = (
            ParticleField(
                spec,
                wind=weather.wind,
                up=np.asarray(up),
                heading=heading,
                seed=int(weather.seed),
                anchor=anchor,
            )
            if spec is not None
            else None
        )
        self.beta, self.fog_color, self.fog_offset = weather.fog_parameters(self.field)
        self._buffers: _CombinedBuffers | None = None
        self._channels: np.ndarray | None = None

    @property
    def background_visible(self) -> bool:
        """Whether a ``background_image`` can show in this weather's frames. Under any fog or haze
        (extinction ``beta`` > 0: fog in either mode, and the haze of rain and snow beyond the
        particle box, so every edited weather of the default presets; not the ``paper`` rain and
        snow, which have no haze) the background is at infinite distance, seen through a
        transmittance of 0: it contributes nothing, so a caller need not compute one (a sky lookup
        per pixel, ~4 ms at 480x270). Only clear weather and haze-free precipitation show it."""
        return not self.beta > 0

    def info(self) -> dict[str, Any]:
        """The resolved parameters of this renderer (JSON-ready), for ``info.json``."""
        out: dict[str, Any] = {
            "weather": self.weather.to_json(),
            "preset": self.weather.resolved_preset(),
            "exposure_s": self.weather.exposure(),
            "fog": {
                "mode": self.weather.fog_mode,
                "density_per_m": self.beta,
                "visibility_m": visibility_from_density(self.beta),
                "color": [float(c) for c in self.fog_color],
                "offset_m": self.fog_offset,
            },
            "scene_gaussians": int(self.scene["means"].shape[0]),
            "background": [float(c) for c in self.background],
            "particle_dilation_compensation": self.compensate_dilation,
            "rasterizer_eps2d": EPS2D,
        }
        if self.field is not None:
            out["particles"] = self.field.info()
            out["particles"]["spec"] = {k: v for k, v in asdict(self.field.spec).items()}
        return out

    def particles(
        self,
        camera: Any,
        t: float,
        *,
        camera_velocity: np.ndarray | None = None,
        out: ParticleGaussians | None = None,
    ) -> tuple[ParticleGaussians, dict[str, int]]:
        """The particle Gaussians of time ``t`` inside the view frustum of ``camera``.

        Returns the Gaussians (opacities already compensated for the dilation when enabled),
        written into ``out`` when given (see :meth:`.particles.ParticleField.gaussians`), and
        their count ``particles_in_view``.
        """
        if self.field is None:
            return ParticleGaussians.empty(), {"particles_in_view": 0}
        g = self.field.gaussians(
            t,
            np.asarray(camera.center, np.float64),
            exposure_s=self.weather.exposure(),
            camera_velocity=camera_velocity,
            view=(
                np.asarray(camera.world_to_camera, np.float64),
                np.asarray(camera.K, np.float64),
                int(camera.width),
                int(camera.height),
            ),
            near=self.near,
            dilation_eps2d=EPS2D if self.compensate_dilation else None,
            out=out,
        )
        return g, {"particles_in_view": len(g)}

    def refresh_scene(self, rows: list[slice]) -> None:
        """Say that the renderer's own scene arrays changed in place at ``rows`` (row ranges).

        The arrays given at construction are not copied (float32 numpy arrays or tensors), so a
        caller may move Gaussians between frames by writing into them (e.g.
        :class:`~wcbench.reference_model.model.scene_model.FrameRows`); a rain or snow renderer
        keeps a copy of them in front of its particles, and this copies the changed rows there.
        """
        n = int(self.scene["means"].shape[0])
        for r in rows:
            if not (0 <= (r.start or 0) <= (n if r.stop is None else r.stop) <= n) or r.step not in (None, 1):
                raise ValueError(f"rows must be contiguous ranges within the scene's {n} rows, got {r}")
        buffers = self._buffers
        if buffers is None or not buffers.holds_own_scene:
            return  # the next frame copies the whole scene anyway
        for name in _GAUSSIAN_ARRAYS:
            src, dst = self.scene[name].numpy(), buffers.arrays[name]
            for r in rows:
                dst[r] = src[r]

    def _combined_buffers(self, scene: dict[str, Any], *, own_scene: bool) -> _CombinedBuffers:
        """Buffers holding the scene Gaussians followed by room for this weather's particles.

        The renderer's own scene is copied in once; a per-frame scene (``gaussians=``) every frame
        it is given. A rain frame then rasterizes scene + particles without concatenating arrays.
        """
        n = int(scene["means"].shape[0])
        assert self.field is not None
        buffers = self._buffers
        if buffers is None or buffers.n_scene != n:
            buffers = self._buffers = _CombinedBuffers.allocate(n, self.field.max_gaussians)
        if not (own_scene and buffers.holds_own_scene):
            for name in _GAUSSIAN_ARRAYS:
                buffers.arrays[name][:n] = scene[name].numpy()
            buffers.holds_own_scene = own_scene
        return buffers

    def render(
        self,
        camera: Any,
        t: float,
        *,
        camera_velocity: np.ndarray | None = None,
        fog_mode: str | None = None,
        gaussians: GaussianSet | None = None,
        particles: ParticleGaussians | None = None,
        background_image: np.ndarray | None = None,
    ) -> WeatherFrame:
        """Render one frame.

        A renderer reuses its buffers from frame to frame: render from one thread at a time.

        Parameters
        ----------
        camera : wcbench.scenes.scene.Camera
            K, width, height, pose (OpenCV axes).
        t : float
            Seconds since the time origin of the particles (the scene's first frame).
        camera_velocity : ndarray [3], optional
            World camera velocity (m/s) for streak directions (see :func:`camera_velocity`).
        fog_mode : {"exact", "postprocess"}, optional
            Overrides the weather's ``fog_mode`` (the benchmark renders both).
        gaussians : GaussianSet, optional
            Scene Gaussians of this frame instead of the renderer's (dynamic scenes: e.g.
            :meth:`~wcbench.reference_model.scene_graph.nodes.SceneGaussians.at_frame`).
        particles : ParticleGaussians, optional
            Particle Gaussians to rasterize instead of the weather's own (custom effects, tests);
            used as given (no culling, no dilation compensation).
        background_image : ndarray [H, W, 3], optional
            A per-pixel background (a sky map's colors, RGB in [0, 1]) instead of the constant
            ``background``. Fog and haze put the sky at infinite distance, so there it is the fog
            color whatever the background.

        Returns
        -------
        WeatherFrame
        """
        mode = self.weather.fog_mode if fog_mode is None else fog_mode
        bg_image = None
        if background_image is not None:
            bg_image = np.asarray(background_image, np.float32)
            if bg_image.shape != (int(camera.height), int(camera.width), 3):
                raise ValueError(f"background_image must have shape ({camera.height}, {camera.width}, 3), "
                                 f"got {bg_image.shape}")
        if mode not in FOG_MODES:
            raise ValueError(f"fog_mode must be one of {FOG_MODES}, got {mode!r}")
        t_start = time.perf_counter()
        scene = self.scene if gaussians is None else _as_tensors(gaussians)
        n_scene = int(scene["means"].shape[0])
        arrays = {name: scene[name].numpy() for name in _GAUSSIAN_ARRAYS}
        if particles is not None:
            counts = {"particles_in_view": len(particles)}
            if len(particles):
                # One Gaussian set: scene and particles are sorted and blended together (occlusion).
                arrays = {
                    name: np.concatenate([arrays[name], np.asarray(getattr(particles, name), np.float32)])
                    for name in _GAUSSIAN_ARRAYS
                }
        elif self.field is not None:
            buffers = self._combined_buffers(scene, own_scene=gaussians is None)
            # The particles are written straight behind the scene Gaussians.
            parts, counts = self.particles(camera, t, camera_velocity=camera_velocity, out=buffers.tail)
            arrays = {name: buffers.arrays[name][: n_scene + len(parts)] for name in _GAUSSIAN_ARRAYS}
        else:
            counts = {"particles_in_view": 0}
        t_particles = time.perf_counter()

        means, quats, scales, opac, colors = (torch.from_numpy(arrays[name]) for name in _GAUSSIAN_ARRAYS)
        fog = self.beta > 0
        exact = fog and mode == "exact"
        if exact:
            # Channels: c_i t_i (3) and t_i (1); the fog composes from their rasterized sums.
            n = means.shape[0]
            if self._channels is None or self._channels.shape[0] < n:
                self._channels = np.empty((n, 4), np.float32)
            channels = transmitted_channels(
                arrays["means"],
                arrays["colors"],
                np.asarray(camera.center, np.float64),
                self.beta,
                offset_m=self.fog_offset,
                out=self._channels[:n],
            )
            colors = torch.from_numpy(channels)
            background = None
        else:
            background = None if bg_image is not None else torch.from_numpy(self.background)
        viewmat = np.asarray(camera.world_to_camera, np.float32)
        K = np.asarray(camera.K, np.float32)
        with torch.no_grad():
            out = self.rasterizer(
                means,
                quats,
                scales,
                opac,
                colors,
                torch.from_numpy(viewmat),
                torch.from_numpy(K),
                int(camera.width),
                int(camera.height),
                near=self.near,
                background=background,
                render_depth=fog and not exact,
            )
        t_raster = time.perf_counter()
        color = out.color.numpy()
        alpha = out.alpha.numpy()
        depth = out.depth.numpy() if out.depth is not None else None
        if exact:
            image = compose_exact(
                color[..., :3],
                color[..., 3],
                alpha,
                beta=self.beta,
                fog_color=self.fog_color,
                background=self.background,
            )
        elif fog:
            assert depth is not None
            if bg_image is not None:  # rasterized without a background: composite the image's now
                color = color + (1.0 - alpha)[..., None] * bg_image
            image = fog_postprocess(
                color,
                depth,
                alpha,
                camera.K,
                beta=self.beta,
                fog_color=self.fog_color,
                background=self.background if bg_image is None else bg_image,
                offset_m=self.fog_offset,
            )
        elif bg_image is not None:
            image = color + (1.0 - alpha)[..., None] * bg_image
        else:
            image = color.copy()  # the rasterizer's buffer stays untouched
        np.clip(image, 0.0, 1.0, out=image)
        t_end = time.perf_counter()
        info = {
            "time_s": float(t),
            "scene_gaussians": n_scene,
            **counts,
            "rasterized": int(means.shape[0]),
            "fog_mode": mode if fog else "none",
            "raster_meta": {k: v for k, v in out.meta.items() if isinstance(v, (int, float, str))},
        }
        timings = {
            "particles": 1e3 * (t_particles - t_start),
            "raster": 1e3 * (t_raster - t_particles),
            "fog": 1e3 * (t_end - t_raster),
            "total": 1e3 * (t_end - t_start),
        }
        return WeatherFrame(image=image, alpha=alpha, depth=depth, info=info, timings_ms=timings)

