"""``physical-editor``: physically based weather on each raw frame, from the scene's own 3D.

The built-in weather editor and WeatherCity's default supervision. Per frame it renders the scene's
lidar surfaces with the project's rasterizer (normals, ground, open sky, puddle and wheel-path
fields, depth; :mod:`wcbench.reference_model.appearance`) and edits the raw frame with physical
models: overcast light, a water film with Fresnel reflections of the scene mirrored about the
ground and puddles that stay put (rain), snow cover on open upward surfaces with the wheel paths
cleared (snow), and Koschmieder haze with the weather's own visibility and airlight (fog, and rain
and snow beyond their particles). It draws no particles: a method rendering the weather draws its
own.

It reads only what a real scene has: frames, poses, lidar, tracks, and sky masks where the scene
ships them (never a ``truth/`` frame). Its weather is the run's physics weather
(:mod:`wcbench.methods.weather_spec`): on a scene that records the weather its truth requested
(``synth_*``), those rates, visibilities and wind, never the truth's particle seed (it draws no
particles anyway); ``info.json`` records it (``parameters.physics``) so that a folder of its frames
used as supervision can be checked against another run's physics.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Sequence
from typing import Any, ClassVar

import cv2
import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.image_io import read_rgb8, to_uint8
from wcbench.core.options import Option
from wcbench.core.progress import progress
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
)
from wcbench.reference_model.appearance.editor import AppearanceParams, WeatherEditor, appearance_options
from wcbench.reference_model.weather.conditions import Weather
from wcbench.reference_model.weather.renderer import scale_camera
from wcbench.scenes.scene import Scene

__all__ = ["NAME", "VERSION", "PhysicalEditorMethod", "check_lidar", "edit_scene", "raw_frame"]

NAME = "physical-editor"
#: Bumped whenever the same scene, weather and settings would give other frames.
VERSION = "2"
#: Width it edits at unless told otherwise (WeatherCity's training width).
DEFAULT_WIDTH = 480


def check_lidar(scene: Scene) -> None:
    """Refuse a scene without lidar: the editor's geometry comes from it.

    Raises
    ------
    InputError
        Naming the scene folder and what is missing.
    """
    if not any(f.lidar_path is not None for f in scene.frames):
        raise InputError(f"{scene.root}: {NAME} needs the scene's lidar (depth, normals, ground and sky come from "
                         f"it) and the scene has none (no lidar sweep for any of its {len(scene)} frames); use "
                         "filter2d, or a scene with lidar/")


def raw_frame(scene: Scene, index: int, size: tuple[int, int]) -> np.ndarray:
    """Raw frame ``index`` as float32 display RGB at ``size`` (area-resized)."""
    raw = read_rgb8(scene.frames[index].image_path)
    if (raw.shape[1], raw.shape[0]) != size:
        raw = cv2.resize(raw, size, interpolation=cv2.INTER_AREA)
    return raw.astype(np.float32) / 255.0


def edit_scene(scene: Scene, weathers: dict[str, Weather], size: tuple[int, int], *,
               editor: WeatherEditor | None = None, show_progress: bool = True
               ) -> tuple[dict[str, list[np.ndarray]], dict[str, Any], dict[str, float]]:
    """Every frame of ``scene`` edited into each of ``weathers`` at ``size`` (WeatherCity's supervision).

    Parameters
    ----------
    scene : Scene
    weathers : dict of str to Weather
        The physics weather per edited kind.
    size : (int, int)
        (width, height) of the frames.
    editor : WeatherEditor, optional
        One already built for ``scene``.
    show_progress : bool
        Count the frames with their time left on stderr (:func:`~wcbench.core.progress.progress`): at
        a scene's native size (the ``paper`` training profile) the edits take minutes.

    Returns
    -------
    frames : dict of str to list of ndarray [H, W, 3] float32
    record : dict
        Method, version, size, sha256 of each weather's frames (float32 bytes), appearance
        parameters, surface counts and physics per kind: everything that makes the frames.
    timings : dict
        ``ms_per_frame`` (mean over frames and weathers) and ``setup_s`` (the lidar surfaces).

    Raises
    ------
    InputError
        A scene without lidar.
    """
    check_lidar(scene)
    editor = editor or WeatherEditor(scene)
    frames: dict[str, list[np.ndarray]] = {w: [] for w in weathers}
    start = time.perf_counter()
    desc = f"editing {scene.id} into {', '.join(weathers)} at {size[0]}x{size[1]}"
    frames_done = progress(range(len(scene)), desc=desc, enabled=show_progress and bool(weathers), unit="frame")
    for k in frames_done:
        camera = scale_camera(scene.frames[k].camera, *size)
        raw = raw_frame(scene, k, size)
        for kind, weather in weathers.items():
            frames[kind].append(editor.edit(raw, k, camera, weather)[0])
    per_frame = 1e3 * (time.perf_counter() - start) / max(1, len(scene) * len(weathers))
    digests = {}
    for kind, seq in frames.items():  # the frames themselves key a training on them
        h = hashlib.sha256()
        for f in seq:
            h.update(np.ascontiguousarray(f, np.float32).tobytes())
        digests[kind] = h.hexdigest()
    record = {"method": NAME, "version": VERSION, "size": list(size), "sha256": digests,
              "appearance": editor.params.to_json(), "surfaces": editor.surfaces.facts,
              "physics": {k: physics_record(w) for k, w in weathers.items()}}
    timings = {"ms_per_frame": round(per_frame, 2), "setup_s": round(editor.setup_seconds, 3)}
    return frames, record, timings


class PhysicalEditorMethod(FrameRenderer):
    """The physical weather editor as a runnable method (see the module docstring).

    Parameters
    ----------
    physics : "auto", "truth", "presets" or dict, optional
        The physics weather per kind (:func:`~wcbench.methods.weather_spec.parse_physics`;
        default ``"auto"``: the weather a scene's truth requested where it records one, else the
        presets).
    appearance : dict, optional
        Overrides of the ``[appearance]`` preset tables, per table
        (``'appearance={"rain": {"puddle_max": 0.2}}'``).
    size : (int, int), optional
        Output (width, height); default 480 px wide at the scene's aspect ratio (WeatherCity's
        training size), or the scene's size when smaller.
    weathers : optional
        Deprecated name of ``physics`` (one release; a :class:`DeprecationWarning`).
    """

    version = VERSION
    OPTIONS: ClassVar[dict[str, Option]] = {
        "physics": physics_option(who=NAME),
        "appearance": Option("appearance", "table", "overrides of the presets' [appearance] tables, e.g. "
                             "appearance.rain.puddle_max=0.2", table=appearance_options()),
        "size": size_option("output (width, height) in pixels; default 480 px wide at the scene's aspect ratio"),
        "weathers": old_physics_option(who=NAME),
    }

    def __init__(self, *, physics: Any = None, appearance: dict[str, Any] | None = None,
                 size: Sequence[int] | None = None, weathers: Any = None):
        self.physics_spec: PhysicsSpec = physics_argument(physics, weathers, who=NAME)
        try:
            self.appearance = AppearanceParams.load(appearance)
        except ValueError as exc:
            raise InputError(f"{NAME}: {exc}") from None
        self._appearance_overrides = dict(appearance or {})
        if size is not None and (len(size) != 2 or min(int(v) for v in size) < 1):
            raise InputError(f"{NAME}: size must be (width, height) in pixels, got {size!r}")
        self.size = None if size is None else (int(size[0]), int(size[1]))
        self.info = MethodInfo(
            name=NAME,
            description="Physical weather from the scene's lidar: overcast light, wet ground with reflections and "
                        "puddles, snow cover, Koschmieder haze (no particles)",
            kind="runnable",
            weathers=WEATHERS,
            requires=("torch",),
            layout=f"writes <out>/{NAME}/<scene>/<weather>/{{frame:03d}}.png + info.json (480 px wide)",
        )
        self._editor: WeatherEditor | None = None
        self._scene_key: tuple[str, str] | None = None
        self._weather: Weather | None = None

    def parameters(self, weather: str) -> dict[str, Any]:
        """The weather the physics option asks for and the appearance overrides (the resolved weather:
        :meth:`physics`)."""
        return {"weather": "clear" if weather == "clear" else describe_option(self.physics_spec, weather),
                "appearance": self._appearance_overrides}

    def native_size(self, scene: Scene) -> tuple[int, int]:
        """``size``, else 480 px wide at the scene's aspect ratio (the scene's size when smaller)."""
        if self.size is not None:
            return self.size
        w, h = scene.image_size
        if w <= DEFAULT_WIDTH:
            return w, h
        return DEFAULT_WIDTH, max(1, round(DEFAULT_WIDTH * h / w))

    def check_scene(self, scene: Scene, weather: str) -> None:
        """The scene needs lidar; ``physics="truth"`` needs its recorded weather."""
        check_lidar(scene)
        if weather != "clear":
            resolve_physics(scene, self.physics_spec, draws=False)

    def prepare(self, scene: Scene, weather: str, *, seed: int) -> None:
        """Build the scene's lidar surfaces once per scene; resolve ``weather``'s physics."""
        key = (scene.id, str(scene.root))
        if self._scene_key != key:
            check_lidar(scene)
            self._editor = WeatherEditor(scene, params=self.appearance)
            self._scene_key = key
        self._weather = self._resolve(scene, weather, seed)

    def _resolve(self, scene: Scene, weather: str, seed: int) -> Weather | None:
        """The physics weather of ``weather`` (``None`` for clear); it draws no particles, so any
        ``seed`` is accepted."""
        if weather == "clear":
            return None
        return resolve_physics(scene, self.physics_spec, seed=seed, draws=False)[weather]

    def physics(self, scene: Scene, weather: str, *, seed: int) -> dict[str, Any] | str:
        """The resolved physics (what a supervision check compares); clear: none."""
        resolved = self._resolve(scene, weather, seed)
        return physics_record(resolved) if resolved is not None else "none: clear is the raw frame"

    def describe(self) -> dict[str, Any]:
        """The appearance parameters, the surfaces' counts and what the scene analysis found (moving
        returns, sky, ego vehicle, sun; the physics: :meth:`physics`)."""
        if self._editor is None:
            return {}
        return {"appearance_parameters": self._editor.params.to_json(), "surfaces": self._editor.surfaces.facts,
                "analysis": self._editor.analysis.record()}

    def setup_timings(self) -> dict[str, float]:
        """``setup_s``: building the lidar surfaces."""
        return {"setup_s": round(self._editor.setup_seconds, 3)} if self._editor is not None else {}

    def render_frame(self, scene: Scene, weather: str, index: int, *, seed: int) -> tuple[np.ndarray, dict[str, Any]]:
        """Raw frame ``index`` edited into ``weather`` (clear: the raw frame at the output size)."""
        assert self._editor is not None, "prepare() runs before render_frame()"
        size = self.output_size(scene)
        raw = raw_frame(scene, index, size)
        if self._weather is None:
            return to_uint8(raw), {}
        image, facts = self._editor.edit(raw, index, scale_camera(scene.frames[index].camera, *size), self._weather)
        return to_uint8(image), facts
