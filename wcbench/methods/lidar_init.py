"""``lidar-init``: the untrained reference scene under physics-driven weather, as a runnable method.

The scene is the lidar initialisation training starts from (static Gaussians plus one rigid node
per moving object, colored from the images, see :mod:`wcbench.reference_model.scene_graph.lidar_init`);
rain and snow particles are rasterized with it and fog is composed on top
(:mod:`wcbench.reference_model.weather`). ``wcbench render`` and ``wcbench run --method lidar-init``
both render it through the same units of work (:mod:`wcbench.units`).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.image_io import to_uint8
from wcbench.core.options import Option, Range
from wcbench.core.progress import phase
from wcbench.core.weathers import WEATHERS
from wcbench.methods.protocol import MethodInfo
from wcbench.methods.runnable import FrameRenderer, size_option
from wcbench.methods.weather_spec import (
    PhysicsSpec,
    describe_option,
    old_physics_option,
    physics_argument,
    physics_option,
    physics_record,
    resolve_physics,
    truth_draw,
)
from wcbench.reference_model.scene_graph.lidar_init import LidarInitOptions, estimate_sky_color, init_scene_from_lidar
from wcbench.reference_model.weather.conditions import Weather
from wcbench.reference_model.weather.renderer import WeatherRenderer, camera_velocity, scale_camera
from wcbench.scenes.scene import Scene


class LidarInitMethod(FrameRenderer):
    """Lidar-initialised Gaussians rendered under a physics weather per kind.

    Each kind draws the :class:`~wcbench.reference_model.weather.conditions.Weather` the run's one
    weather spec gives it (:func:`~wcbench.methods.weather_spec.resolve_physics`), with the run's
    particle seed.

    Parameters
    ----------
    physics : "auto", "truth", "presets" or dict, optional
        The physics weather per kind (:func:`~wcbench.methods.weather_spec.parse_physics`; a dict
        of :class:`Weather` or of its fields). Default ``"auto"``: the weather a scene's truth
        requested where it records one (``synth_*``), else each kind's default preset.
    size : (int, int), optional
        Output (width, height); ``scale`` is used when not given.
    scale : float
        Output size as a fraction of the scene's (default 0.25: 480x270 for 1920x1080, the size
        ``render`` and ``run`` both use unless told otherwise; frames are scored at the scene's working size).
    voxel_m : float
        Voxel size of the lidar initialisation (m).
    init_frames : list of int, optional
        Frames whose lidar sweeps build the scene (default: all).
    weathers : optional
        Deprecated name of ``physics`` (one release; a :class:`DeprecationWarning`).
    """

    version = "1"

    OPTIONS: ClassVar[dict[str, Option]] = {
        "physics": physics_option(who="lidar-init"),
        "size": size_option("output (width, height) in pixels; default the scene's size times scale"),
        "scale": Option("scale", "float", "output size as a fraction of the scene's", default=0.25,
                        range=Range(0, 4, low_open=True)),
        "voxel_m": Option("voxel_m", "float", "voxel of the lidar initialisation (m)", default=0.2,
                          range=Range(0, low_open=True)),
        "init_frames": Option("init_frames", "ints", "frames whose lidar sweeps build the scene (default: all)",
                              range=Range(0), nullable=True),
        "weathers": old_physics_option(who="lidar-init"),
    }

    def __init__(
        self,
        *,
        physics: Any = None,
        size: tuple[int, int] | None = None,
        scale: float = 0.25,
        voxel_m: float = 0.2,
        init_frames: list[int] | None = None,
        weathers: Any = None,
    ):
        if not 0 < scale <= 4:
            raise InputError(f"scale must be in (0, 4], got {scale}")
        if size is not None and (size[0] < 1 or size[1] < 1):
            raise InputError(f"size must be positive, got {size}")
        self.physics_spec: PhysicsSpec = physics_argument(physics, weathers, who="lidar-init")
        self.size, self.scale, self.voxel_m, self.init_frames = size, scale, voxel_m, init_frames
        self.info = MethodInfo(
            name="lidar-init",
            description="Untrained lidar-initialised Gaussians + physics weather (particles, Beer-Lambert fog)",
            kind="runnable",
            weathers=WEATHERS,
            layout="writes <out>/lidar-init/<scene>/<weather>/{frame:03d}.png + info.json",
            requires=("torch",),
        )
        self._scene_key: tuple[str, str] | None = None
        self._gaussians: Any = None
        self._background: np.ndarray | None = None
        self._renderer: WeatherRenderer | None = None

    def weather_for(self, kind: str, seed: int, scene: Scene) -> Weather:
        """The physics weather of ``kind`` for ``scene`` with particle seed ``seed``.

        Raises
        ------
        InputError
            ``seed`` is the particle seed of the scene's truth (:func:`resolve_physics`), or
            ``physics="truth"`` on a scene that records none.
        """
        if kind == "clear":
            return Weather(kind="clear", seed=seed)
        return resolve_physics(scene, self.physics_spec, seed=seed)[kind]

    def parameters(self, weather: str) -> dict[str, Any]:
        """The weather option (the resolved weather: :meth:`physics`) and scene settings."""
        return {"weather": "clear" if weather == "clear" else describe_option(self.physics_spec, weather),
                "init": {"voxel_m": self.voxel_m, "frames": self.init_frames}}

    def check_scene(self, scene: Scene, weather: str) -> None:
        """``physics="truth"`` needs the scene's recorded weather (checked before any render)."""
        if weather != "clear":
            resolve_physics(scene, self.physics_spec, draws=False)

    def physics(self, scene: Scene, weather: str, *, seed: int) -> dict[str, Any] | str:
        """The physics weather its particles and fog are drawn with (clear: none)."""
        if weather == "clear":
            return "none: clear renders no weather"
        return physics_record(self.weather_for(weather, seed, scene))

    def truth_draw(self, scene: Scene, weather: str, *, seed: int) -> dict[str, Any]:
        """Its particle seed against the truth's (:func:`~wcbench.methods.weather_spec.truth_draw`)."""
        return truth_draw(scene, None if weather == "clear" else self.weather_for(weather, seed, scene),
                          option=self.physics_spec)

    def native_size(self, scene: Scene) -> tuple[int, int]:
        """``size`` if given, else the scene's size times ``scale``."""
        if self.size is not None:
            return self.size
        w, h = scene.image_size
        return max(1, round(w * self.scale)), max(1, round(h * self.scale))

    def prepare(self, scene: Scene, weather: str, *, seed: int) -> None:
        """Build the scene's Gaussians once per scene, and the weather renderer for ``weather``."""
        key = (scene.id, str(scene.root))
        if self._scene_key != key:
            try:
                with phase(f"lidar-init {scene.id}: Gaussians from {len(scene)} lidar sweeps"):
                    self._gaussians = init_scene_from_lidar(scene, LidarInitOptions(voxel_m=self.voxel_m),
                                                            frames=self.init_frames)
            except ValueError as exc:
                raise InputError(f"{scene.root}: cannot initialise Gaussians from lidar: {exc}") from None
            self._background = estimate_sky_color(scene)
            self._scene_key = key
        first = scene.frames[0].camera
        self._renderer = WeatherRenderer(
            self._gaussians.static, self.weather_for(weather, seed, scene), up=scene.up,
            heading=first.camera_to_world[:3, 2], anchor=first.center, background=self._background,
        )
        self._centers = np.stack([f.camera.center for f in scene.frames])
        self._times = np.array([f.timestamp for f in scene.frames], np.float64)

    def describe(self) -> dict[str, Any]:
        """The renderer's settings and the scene's Gaussian counts."""
        if self._renderer is None:
            return {}
        g = self._gaussians
        return {"renderer": self._renderer.info(),
                "scene_gaussians": {"static": len(g.static), "rigid_nodes": len(g.nodes), "total": len(g)}}

    def render_frame(self, scene: Scene, weather: str, index: int, *, seed: int) -> tuple[np.ndarray, dict[str, Any]]:
        """Frame ``index``: a pure function of (seed, frame time, parameters)."""
        assert self._renderer is not None, "prepare() runs before render_frame()"
        cam = scale_camera(scene.frames[index].camera, *self.output_size(scene))
        frame = self._renderer.render(
            cam, float(self._times[index] - self._times[0]),
            camera_velocity=camera_velocity(self._centers, self._times, index),
            gaussians=self._gaussians.at_frame(index),
        )
        return to_uint8(frame.image), {**frame.info, "timings_ms": frame.timings_ms}
