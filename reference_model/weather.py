"""One render of a Gaussian scene under a weather: particles, scene and fog together.

A :class:`Weather` describes the weather in physical units (kind, preset from
``weather_presets.toml``, rain/snow rate, fog visibility or density, wind, seed, exposure). The
:class:`WeatherRenderer` turns it into images: rain and snow particles (:mod:`.particles`) are
rasterized together with the scene Gaussians in one call, so occlusion and blending are correct,
then fog (:mod:`.fog`) is composed on top: the exact per-layer form by default (one extra channel,
no depth map), or the paper's depth-map post-process. Far rain and snow act as haze (fog of their
own extinction coefficient starting at the particle radius). Clear and fog build no particles, and
particles outside the view frustum are dropped before rasterizing.

Frame t is a pure function of (weather, t, camera): rendering frame 17 alone equals frame 17 of a
sequence. Images are float32 RGB in [0, 1].
"""

from __future__ import annotations

import functools
import math
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, replace
from importlib import resources
from typing import Any, Protocol

import numpy as np

from .fog import (
    compose_exact,
    density_from_visibility,
    fog_postprocess,
    transmitted_channels,
    visibility_from_density,
)
from .particles import (
    ParticleField,
    ParticleGaussians,
    ParticleSpec,
    Wind,
    particle_dilation_compensation,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 only
    import tomli as tomllib

__all__ = [
    "FOG_MODES",
    "WEATHER_KINDS",
    "GaussianSet",
    "Weather",
    "WeatherFrame",
    "WeatherRenderer",
    "camera_velocity",
    "load_presets",
    "particle_dilation_compensation",
    "render_weather",
    "scale_camera",
]

WEATHER_KINDS = ("clear", "rain", "snow", "fog")
FOG_MODES = ("exact", "postprocess")
_PRESETS_FILE = "weather_presets.toml"


class GaussianSet(Protocol):
    """Anything with the five Gaussian arrays (e.g. :class:`.lidar_init.GaussianCloud`)."""

    means: Any  # [N, 3] world (m)
    quats: Any  # [N, 4] wxyz
    scales: Any  # [N, 3] (m)
    opacities: Any  # [N] in [0, 1]
    colors: Any  # [N, 3] RGB in [0, 1]


# --------------------------------------------------------------------------------------------
# Presets


@functools.lru_cache(maxsize=1)
def load_presets() -> dict[str, Any]:
    """The parsed ``weather_presets.toml`` (cached; do not mutate)."""
    text = resources.files(__package__).joinpath(_PRESETS_FILE).read_text(encoding="utf-8")
    return tomllib.loads(text)


def preset_names(kind: str) -> list[str]:
    """Preset names of a weather kind (empty for ``clear``)."""
    if kind not in WEATHER_KINDS:
        raise ValueError(f"kind must be one of {WEATHER_KINDS}, got {kind!r}")
    return sorted(load_presets().get(kind, {}).get("presets", {}))


def _preset_table(kind: str, preset: str | None) -> tuple[str | None, dict[str, Any]]:
    """(resolved preset name, base table merged with the preset's overrides)."""
    table = load_presets().get(kind, {})
    base = {k: v for k, v in table.items() if k != "presets"}
    presets = table.get("presets", {})
    name = preset if preset is not None else base.get("default_preset")
    base.pop("default_preset", None)
    if name is None:
        return None, base
    if name not in presets:
        raise ValueError(f"preset: unknown {kind} preset {name!r}; known: {sorted(presets)}")
    return name, {**base, **presets[name]}


# --------------------------------------------------------------------------------------------
# The weather description


@dataclass(frozen=True)
class Weather:
    """A weather in physical units; unset fields come from the preset.

    Attributes
    ----------
    kind : {"clear", "rain", "snow", "fog"}
    preset : str, optional
        Name in ``weather_presets.toml`` (rain: light, moderate, heavy, paper; snow: light, heavy,
        paper; fog: light, moderate, dense, paper). Default: the kind's ``default_preset``.
    rate_mm_h : float, optional
        Rain or snow rate (mm/h of liquid water); on a fixed-count preset (``paper``) it switches
        to the kind's physical settings at that rate.
    count : int, optional
        Fixed particle count (rain drops or snowflakes) instead of a rate, with the ``paper``
        preset's shapes when the preset is physical. ``rate_mm_h`` and ``count`` exclude each other.
    visibility_m : float, optional
        Fog visibility V (m), beta = 2.996 / V. For rain and snow: overrides the haze.
    fog_density : float, optional
        Fog extinction beta (m^-1); wins over ``visibility_m``.
    fog_color : tuple of 3 float, optional
        RGB of the fog in [0, 1] (rain/snow: of the haze).
    wind : Wind
        Magnitude (m/s), tilt and azimuth (degrees).
    seed : int
        Particle seed.
    exposure_s : float, optional
        Camera exposure (s) for rain streaks; default from the presets' ``[common]`` table.
    max_particles : int, optional
        Cap on simulated particles (physical presets).
    fog_mode : {"exact", "postprocess"}
        Per-layer Beer-Lambert, or the paper's depth-map post-process (for comparison).
    """

    kind: str = "clear"
    preset: str | None = None
    rate_mm_h: float | None = None
    count: int | None = None
    visibility_m: float | None = None
    fog_density: float | None = None
    fog_color: tuple[float, float, float] | None = None
    wind: Wind = field(default_factory=Wind)
    seed: int = 0
    exposure_s: float | None = None
    max_particles: int | None = None
    fog_mode: str = "exact"

    def __post_init__(self) -> None:
        if self.kind not in WEATHER_KINDS:
            raise ValueError(f"kind must be one of {WEATHER_KINDS}, got {self.kind!r}")
        if self.fog_mode not in FOG_MODES:
            raise ValueError(f"fog_mode must be one of {FOG_MODES}, got {self.fog_mode!r}")
        if self.rate_mm_h is not None and (not math.isfinite(self.rate_mm_h) or self.rate_mm_h < 0):
            raise ValueError(f"rate_mm_h must be a finite rate >= 0 mm/h, got {self.rate_mm_h}")
        if self.count is not None and self.count < 0:
            raise ValueError(f"count must be >= 0, got {self.count}")
        if self.count is not None and self.rate_mm_h is not None:
            raise ValueError("give rate_mm_h or count, not both")
        if self.visibility_m is not None and not self.visibility_m > 0:
            raise ValueError(f"visibility_m must be > 0 metres, got {self.visibility_m}")
        if self.fog_density is not None and not (0 <= self.fog_density < math.inf):
            raise ValueError(f"fog_density must be finite and >= 0 m^-1, got {self.fog_density}")
        if self.exposure_s is not None and not (0 <= self.exposure_s < math.inf):
            raise ValueError(f"exposure_s must be finite and >= 0 s, got {self.exposure_s}")
        if self.max_particles is not None and self.max_particles < 0:
            raise ValueError(f"max_particles must be >= 0, got {self.max_particles}")
        if not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.fog_color is not None:
            c = np.asarray(self.fog_color, np.float64)
            if c.shape != (3,) or not np.all(np.isfinite(c)):
                raise ValueError(f"fog_color must be 3 finite numbers, got {self.fog_color!r}")
        if self.kind != "clear" and self.preset is not None:
            _preset_table(self.kind, self.preset)  # fail early on an unknown preset

    @property
    def has_particles(self) -> bool:
        """Whether this weather builds particles (rain and snow)."""
        return self.kind in ("rain", "snow")

    def resolved_preset(self) -> str | None:
        """The preset actually used (the kind's default when none was given)."""
        if self.kind == "clear":
            return None
        return _preset_table(self.kind, self.preset)[0]

    def exposure(self) -> float:
        """Exposure time (s)."""
        if self.exposure_s is not None:
            return float(self.exposure_s)
        return float(load_presets().get("common", {}).get("exposure_s", 0.01))

    def particle_spec(self) -> ParticleSpec | None:
        """The particle population, or ``None`` for clear and fog."""
        if not self.has_particles:
            return None
        _, table = _preset_table(self.kind, self.preset)
        if self.rate_mm_h is not None and "count" in table:
            # A rate on a fixed-count preset: the kind's physical settings at that rate.
            table = _preset_table(self.kind, load_presets()[self.kind].get("default_preset"))[1]
        if self.count is not None and "count" not in table:
            # A count on a physical preset: the paper's fixed shapes with that count.
            table = _preset_table(self.kind, "paper")[1]
        if self.rate_mm_h is not None:
            table = {**table, "rate_mm_h": self.rate_mm_h}
            table.pop("count", None)
        if self.count is not None:
            table = {**table, "count": self.count}
            table.pop("rate_mm_h", None)
        if self.max_particles is not None:
            table["max_particles"] = self.max_particles
        return ParticleSpec.from_mapping(self.kind, table)

    def fog_parameters(self, field_: ParticleField | None = None) -> tuple[float, np.ndarray, float]:
        """(beta m^-1, fog color [3], offset m) of the fog or haze; beta 0 when there is none.

        Parameters
        ----------
        field_ : ParticleField, optional
            The rain/snow population whose haze to use (its extinction, starting at its radius).
        """
        if self.kind == "clear":
            return 0.0, np.zeros(3, np.float32), 0.0
        _, table = _preset_table(self.kind, self.preset)
        if self.kind == "fog":
            color = table.get("color", (0.8, 0.8, 0.85))
            beta = table.get("density_per_m")
            if beta is None:
                beta = density_from_visibility(float(table["visibility_m"]))
            offset = 0.0
        else:
            color = table.get("haze_color", (0.6, 0.62, 0.66))
            beta = field_.haze_density() if field_ is not None else 0.0
            offset = float(table.get("radius_m", 10.0))
        if self.visibility_m is not None:
            beta = density_from_visibility(self.visibility_m)
        if self.fog_density is not None:
            beta = self.fog_density
        if self.fog_color is not None:
            color = self.fog_color
        return float(beta), np.asarray(color, np.float32), offset

    def to_json(self) -> dict[str, Any]:
        """The description as given (JSON-ready)."""
        d = asdict(self)
        d["wind"] = asdict(self.wind)
        return d

    @classmethod
    def from_json(cls, obj: Mapping[str, Any]) -> Weather:
        """Inverse of :meth:`to_json`."""
        obj = dict(obj)
        wind = Wind(**obj.pop("wind", {}))
        if obj.get("fog_color") is not None:
            obj["fog_color"] = tuple(obj["fog_color"])
        return cls(wind=wind, **obj)


# --------------------------------------------------------------------------------------------
# Camera helpers


def scale_camera(camera: Any, width: int, height: int) -> Any:
    """A copy of ``camera`` (:class:`wcbench.scene.Camera`) resized to ``width`` x ``height`` px.

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
    import torch

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
        if rasterizer is None:
            from .raster import rasterize

            rasterizer = rasterize
        self.rasterizer: Callable[..., Any] = rasterizer
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

    def info(self) -> dict[str, Any]:
        """The resolved parameters of this renderer (JSON-ready), for ``info.json``."""
        from ._raster_common import EPS2D

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
        from ._raster_common import EPS2D

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
    ) -> WeatherFrame:
        """Render one frame.

        A renderer reuses its buffers from frame to frame: render from one thread at a time.

        Parameters
        ----------
        camera : wcbench.scene.Camera
            K, width, height, pose (OpenCV axes).
        t : float
            Seconds since the time origin of the particles (the scene's first frame).
        camera_velocity : ndarray [3], optional
            World camera velocity (m/s) for streak directions (see :func:`camera_velocity`).
        fog_mode : {"exact", "postprocess"}, optional
            Overrides the weather's ``fog_mode`` (the benchmark renders both).
        gaussians : GaussianSet, optional
            Scene Gaussians of this frame instead of the renderer's (dynamic scenes: e.g.
            :meth:`.lidar_init.SceneGaussians.at_frame`).
        particles : ParticleGaussians, optional
            Particle Gaussians to rasterize instead of the weather's own (custom effects, tests);
            used as given (no culling, no dilation compensation).

        Returns
        -------
        WeatherFrame
        """
        import torch

        mode = self.weather.fog_mode if fog_mode is None else fog_mode
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
            background = torch.from_numpy(self.background)
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
            image = fog_postprocess(
                color,
                depth,
                alpha,
                camera.K,
                beta=self.beta,
                fog_color=self.fog_color,
                background=self.background,
                offset_m=self.fog_offset,
            )
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


def render_weather(
    gaussians: GaussianSet,
    camera: Any,
    weather: Weather,
    *,
    t: float,
    up: np.ndarray,
    heading: np.ndarray | None = None,
    anchor: np.ndarray | None = None,
    background: np.ndarray | None = None,
    camera_velocity: np.ndarray | None = None,
    rasterizer: Callable[..., Any] | None = None,
) -> WeatherFrame:
    """Render one frame of ``gaussians`` seen by ``camera`` under ``weather`` at time ``t``.

    A functional form of :class:`WeatherRenderer` (same parameters); for sequences build the
    renderer once.
    """
    renderer = WeatherRenderer(
        gaussians,
        weather,
        up=up,
        heading=heading,
        anchor=anchor,
        background=background,
        rasterizer=rasterizer,
    )
    return renderer.render(camera, t, camera_velocity=camera_velocity)
