"""``weathercity``: the paper's method, trained on the scene, rendered under physics weather.

For each scene the method (1) gets edited frames of every weather from a supervision method (the
built-in ``physical-editor`` by default: physically based weather from the scene's lidar, without
particles, since particles come from the physics; the ``filter2d`` 2D grade, without its streaks
and flakes; the simulated editor ``sim-editor[:SEVERITY]`` on scenes with ground truth; or another
tool's frames read from a folder, ``READER:DIR``), each checked against the run's one weather spec
(:mod:`wcbench.methods.weather_spec`: the built-in editors edit with the physics' rate and
visibility, a folder that records another is refused), (2) builds the weather Gaussian scene
graph from the lidar and trains it on the raw frames and the edits, each edit's render composed
through the haze its physics weather adds, caching the trained model under a key over every input
that changes it (steps 1 and 2 are :func:`wcbench.methods.scene_training.train_scene`, which
``wcbench train`` runs too), (3) renders any frame under any weather at the scene's size: the decoded
colors of that weather, the weather's sky, rain or snow particles rasterized with the scene, and
exact Beer-Lambert fog (:mod:`wcbench.reference_model.weather`), optionally with object edits.

The model trains at its profile's resolution (240 px wide on ``quick``) but renders at the scene's
size, capped at the default working resolution the frames are scored at
(:data:`~wcbench.core.working_size.METRIC_RESOLUTION`: no pixel is rendered that the scores would
average away), so the report's frames stand beside the truth at its sharpness; ``size`` (or
``--scale``, ``--width``/``--height``) asks for another.
``info.json`` records the training time, the Gaussian counts per node, what the scene graph
skipped, the supervision, and the whole-frame render FPS.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any, ClassVar

import cv2
import numpy as np
import torch

from wcbench.core.errors import InputError, UnknownNameError
from wcbench.core.image_io import to_uint8
from wcbench.core.options import Option, Range
from wcbench.core.weathers import WEATHERS
from wcbench.core.working_size import METRIC_RESOLUTION, working_size
from wcbench.methods import METHODS, MethodUnavailableError, get_method
from wcbench.methods.physical_editor import NAME as PHYSICAL_EDITOR
from wcbench.methods.physical_editor import check_lidar, raw_frame
from wcbench.methods.protocol import MethodInfo
from wcbench.methods.runnable import FrameRenderer, size_option
from wcbench.methods.scene_training import VERSION, check_supervision, train_scene
from wcbench.methods.sim_editor import supervision_severity, truth_paths
from wcbench.methods.weather_spec import (
    EDITED,
    PhysicsSpec,
    describe_option,
    has_truth_weather,
    old_physics_option,
    physics_argument,
    physics_option,
    physics_record,
    resolve_physics,
    truth_draw,
    truth_physics,
)
from wcbench.reference_model.appearance.editor import AppearanceParams, masked_ego
from wcbench.reference_model.devices import DEVICES, device_problem, on_device
from wcbench.reference_model.editing.edits import parse_edits, placement_for
from wcbench.reference_model.editing.transfer import ground_axes, ground_point, placed_objects
from wcbench.reference_model.editing.vacated import vacated_background
from wcbench.reference_model.model.scene_model import FrameRows, Placement, WeatherCityModel
from wcbench.reference_model.model.sky import camera_rays
from wcbench.reference_model.scene_analysis.analysis import analyse_scene
from wcbench.reference_model.training.config import (
    ABLATIONS,
    PROFILE_PHYSICS,
    PROFILES,
    make_config,
    settings_options,
)
from wcbench.reference_model.weather.conditions import Weather
from wcbench.reference_model.weather.renderer import GaussianArrays, WeatherRenderer, camera_velocity, scale_camera
from wcbench.scenes.loaders import load_scene
from wcbench.scenes.scene import Scene
from wcbench.scenes.sets import get_scene_set

__all__ = ["WeatherCityMethod", "check_supervision_spec"]

#: What ``supervision`` allows, in words.
SUPERVISION_FORMS = (f"{PHYSICAL_EDITOR!r}, 'filter2d', 'sim-editor[:SEVERITY]' or READER:DIR "
                     "(a reader of `wcbench methods list` and a folder, e.g. qwen-image:edits/)")


def profile_physics(profile: str, physics: Any, weathers: Any = None) -> Any:
    """``physics`` as given, or, when neither it nor its old name ``weathers`` is, the physics presets
    the training ``profile`` names (:data:`~wcbench.reference_model.training.config.PROFILE_PHYSICS`:
    the ``paper`` profile's 40k rain and 16k snow particles)."""
    if physics is not None or weathers is not None or profile not in PROFILE_PHYSICS:
        return physics
    return {kind: {"preset": preset} for kind, preset in PROFILE_PHYSICS[profile].items()}


def check_supervision_spec(spec: Any) -> str:
    """``spec`` if it names a supervision that can be read: a built-in editor, sim-editor with a
    severity in [0, 1], or an output reader's name and an existing folder (checked before any work).

    Raises
    ------
    ValueError
        Saying what is allowed.
    """
    if not isinstance(spec, str):
        raise ValueError(f"expected {SUPERVISION_FORMS}")
    if spec in (PHYSICAL_EDITOR, "filter2d") or supervision_severity(spec) is not None:
        return spec
    reader, sep, folder = spec.partition(":")
    if not (sep and folder and reader in METHODS):
        raise ValueError(f"expected {SUPERVISION_FORMS}")
    try:
        kind = get_method(reader).info.kind
    except MethodUnavailableError:
        kind = "unavailable"
    if kind != "reader":
        raise ValueError(f"{reader!r} is no output reader; expected {SUPERVISION_FORMS}")
    if not Path(folder).expanduser().is_dir():
        raise ValueError(f"{folder} is not a folder; expected {SUPERVISION_FORMS}")
    return spec


def _check_edits(value: Any) -> Any:
    """``value`` if it parses as object edits (:func:`parse_edits`)."""
    if not isinstance(value, (str, list, tuple)):
        raise ValueError("expected an edit such as 'remove class=Car', or a list of them")
    parse_edits(value)
    return value


def _check_content(value: Any) -> Any:
    """``"auto"``, ``None`` or a content loss object (Python only)."""
    if value == "auto" or value is None or callable(value):
        return value
    raise ValueError("expected 'auto' or null (from Python: a ContentLoss)")


class WeatherCityMethod(FrameRenderer):
    """The WeatherCity method (see the module docstring).

    Parameters
    ----------
    supervision : str
        ``"physical-editor"`` (default), ``"filter2d"``, ``"sim-editor[:SEVERITY]"`` (the simulated
        editor on the scene's ground truth, severity in [0, 1]) or ``READER:DIR`` (another tool's
        edited frames).
    jitter : float
        Per-frame perturbation of the ``filter2d`` supervision, in [0, 1].
    profile : str
        Training profile (``"default"``, ``"quick"``).
    ablation : str
        ``""``, ``"no-wgs"`` or ``"no-content-loss"``.
    settings : dict, optional
        Training settings overriding the profile's (see :class:`TrainConfig`).
    holdout : sequence of int
        Frames left out of training (their held-out PSNR goes to info.json).
    physics : "auto", "truth", "presets" or dict, optional
        The physics weather per kind (:func:`~wcbench.methods.weather_spec.parse_physics`). Default
        ``"auto"``: the weather a scene's truth requested where it records one
        (``truth/weather.json`` of the ``synth_*`` scenes: preset, rate, visibility, wind), else
        each kind's default preset; ``"truth"`` requires the record; a dict gives the
        :class:`Weather` fields (``--method-option 'physics={"rain": {"preset": "heavy"}}'``).
        The particle seed is always the run's (``--seed``), never the truth's: a run seed equal to
        it is refused on that scene, and only a dict that names a ``seed`` renders another.
    size : (int, int), optional
        Render size; default the scene's, capped at the default working resolution (see the module
        docstring; scored at the scene's working size, as every method).
    edits : str or list, optional
        Object edits (``"remove class=Car except ids=3,7"``, a JSON list...).
    fill_vacated : bool
        What a removed or moved object hid takes the features of the background seen around it,
        and ground is laid where nothing was learned
        (:func:`~wcbench.reference_model.editing.vacated.vacated_background`); ``False`` renders
        the background as trained.
    content : ContentLoss, None or "auto"
        See :func:`~wcbench.methods.scene_training.train_scene`.
    weathers : optional
        Deprecated name of ``physics`` (one release; a :class:`DeprecationWarning`).
    device : {"cpu", "cuda"}
        Where the model trains and the render rasterizes (:mod:`wcbench.reference_model.devices`):
        ``"cuda"`` needs gsplat and a CUDA device, refused here otherwise (an :class:`InputError`).
    """

    version = VERSION
    OPTIONS: ClassVar[dict[str, Option]] = {
        "supervision": Option("supervision", "custom", "edited frames it learns from", default=PHYSICAL_EDITOR,
                              check=check_supervision_spec, allowed=SUPERVISION_FORMS),
        "jitter": Option("jitter", "float", "per-frame perturbation of the filter2d supervision", default=0.0,
                         range=Range(0, 1)),
        "profile": Option("profile", "str", "training profile", default="default", choices=tuple(PROFILES)),
        "ablation": Option("ablation", "str", "named ablation ('': none)", default="",
                           choices=tuple(ABLATIONS)),
        "settings": Option("settings", "table", "training settings overriding the profile's (settings.KEY=VALUE)",
                           table=settings_options()),
        "holdout": Option("holdout", "ints", "frames left out of training and scored", default=[],
                          range=Range(0)),
        "physics": physics_option(who="weathercity"),
        "size": size_option("render (width, height) in pixels; default the scene's size (the longer side at most "
                            f"{METRIC_RESOLUTION} px)"),
        "edits": Option("edits", "custom", "object edits, e.g. 'remove class=Car except ids=3,7'", nullable=True,
                        check=_check_edits, allowed="an edit such as 'remove class=Car', or a list of them"),
        "fill_vacated": Option("fill_vacated", "bool", "what a removed or moved object hid takes the look of the "
                               "background seen around it, and ground is laid where nothing was learned "
                               "(docs/design.md §7)", default=True),
        "content": Option("content", "custom", "the content loss: 'auto' (VGG16) or null (off)", default="auto",
                          nullable=True, check=_check_content, allowed="'auto' or null"),
        "device": Option("device", "str", "where it trains and rasterizes: 'cpu' or 'cuda' (gsplat; "
                         "docs/workstation.md)", default="cpu", choices=DEVICES),
        "weathers": old_physics_option(who="weathercity"),
    }

    def __init__(
        self,
        *,
        supervision: str = PHYSICAL_EDITOR,
        jitter: float = 0.0,
        profile: str = "default",
        ablation: str = "",
        settings: dict[str, Any] | None = None,
        holdout: tuple[int, ...] | list[int] = (),
        physics: Any = None,
        size: tuple[int, int] | None = None,
        edits: str | list[Any] | None = None,
        fill_vacated: bool = True,
        content: Any = "auto",
        weathers: Any = None,
        device: str = "cpu",
    ):
        try:
            self.config = make_config(profile, ablation=ablation, holdout=tuple(int(h) for h in holdout),
                                      **(settings or {}))
            self.edits = [] if not edits else parse_edits(edits)
        except ValueError as exc:
            raise InputError(f"weathercity: {exc}") from None
        if not 0.0 <= float(jitter) <= 1.0:
            raise InputError(f"weathercity: jitter must be in [0, 1], got {jitter}")
        check_supervision(supervision, float(jitter))  # a bad sim-editor severity fails before training
        problem = device_problem(device)  # no CUDA or no gsplat: one line before any work
        if problem is not None:
            raise InputError(f"weathercity: --device {device}: {problem}")
        self.device = device
        self.fill_vacated = bool(fill_vacated)
        self.supervision, self.jitter, self.content = supervision, float(jitter), content
        self.physics_spec: PhysicsSpec = physics_argument(profile_physics(profile, physics, weathers), weathers,
                                                          who="weathercity")
        self._physics: dict[str, dict[str, Weather]] = {}
        self.size = None if size is None else (int(size[0]), int(size[1]))
        self.info = MethodInfo(
            name="weathercity",
            description="WeatherCity: weather Gaussians trained on raw + edited frames, physics particles and fog",
            kind="runnable",
            weathers=WEATHERS,
            requires=("torch",),
            layout="writes <out>/weathercity/<scene>/<weather>/{frame:03d}.png + info.json (the scene's size)",
        )
        self._model: WeatherCityModel | None = None
        self._scene_key: tuple[str, str] | None = None
        self._facts: dict[str, Any] = {}
        self._renderer: WeatherRenderer | None = None
        self._node_colors: dict[str, torch.Tensor] = {}
        self._activated: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}
        self._rays: dict[tuple[bytes, int, int], torch.Tensor] = {}
        self._ego: tuple[tuple[Any, ...], np.ndarray] | None = None
        self._appearance = AppearanceParams.load()
        self._placement = Placement()
        self._placed_facts: list[dict[str, Any]] = []
        self._vacated_facts: dict[str, Any] = {}
        self._sources: dict[str, WeatherCityModel] = {}
        self._rows: FrameRows | None = None

    def required_models(self) -> tuple[str, ...]:
        """``vgg16`` for the content loss, unless it is off or a loss was passed in."""
        return ("vgg16",) if self.content == "auto" and self.config.content_weight != 0 else ()

    def weather_for(self, kind: str, seed: int, scene: Scene, *, draws: bool = True) -> Weather:
        """The physics weather of ``kind`` for ``scene`` with particle seed ``seed`` (the run's, or
        one the ``physics`` dict names): the scene's requested weather under ``"auto"``/``"truth"``
        where it records one, else the given or preset weather.

        Raises
        ------
        InputError
            With ``draws`` (rendering), a ``seed`` equal to the truth's particle seed
            (:func:`~wcbench.methods.weather_spec.resolve_physics`).
        """
        if kind == "clear":
            return Weather(kind="clear", seed=seed)
        return resolve_physics(scene, self.physics_spec, seed=seed, truth=self._recorded(scene), draws=draws)[kind]

    def _recorded(self, scene: Scene) -> dict[str, Weather] | None:
        """The scene's recorded weather (``truth/weather.json``), read once per scene folder; ``None``
        when it has none (and the option does not require it)."""
        if self.physics_spec == "truth" or has_truth_weather(scene):
            key = str(scene.root)
            if key not in self._physics:
                self._physics[key] = truth_physics(scene)
            return self._physics[key]
        return None

    def training_physics(self, scene: Scene) -> dict[str, Weather]:
        """The physics weather of every edited kind for ``scene``, as training reads it (the haze its
        renders pass through, the built-in supervision): the requested weather, no particles drawn,
        so seed 0 whatever the run's (a model serves every seed)."""
        return {kind: self.weather_for(kind, 0, scene, draws=False) for kind in EDITED}

    def parameters(self, weather: str) -> dict[str, Any]:
        """Training settings, supervision, edits and the weather option (the resolved physics:
        :meth:`physics`; the seed is recorded apart)."""
        return {"training": self.config.to_json(), "supervision": self.supervision, "jitter": self.jitter,
                "edits": [e.to_json() for e in self.edits],
                "weather": describe_option(self.physics_spec, weather) if weather != "clear" else "clear"}

    def check_scene(self, scene: Scene, weather: str) -> None:
        """With ``physics="truth"`` the scene must ship ``truth/weather.json`` describing ``weather``;
        with sim-editor supervision, truth frames of every edited weather; with the physical editor,
        lidar (checked before any render)."""
        if weather != "clear":
            resolve_physics(scene, self.physics_spec, truth=self._recorded(scene), draws=False)
        if supervision_severity(self.supervision) is not None:
            for kind in EDITED:
                truth_paths(scene, kind)
        if self.supervision == PHYSICAL_EDITOR:
            check_lidar(scene)
        if self.edits:  # an edit that selects no track of the scene fails here, not after the training
            try:
                # the scene graph's objects are some of the scene's tracks (those with lidar returns in
                # their box): an edit that selects no track at all can never select one of them
                placement_for([e for e in self.edits if e.at is None], _track_stand_ins(scene))
                for edit in self.edits:
                    if edit.at is not None:
                        other = scene if edit.scene is None else source_scene(scene, edit.scene)
                        if edit.ids[0] not in {str(t.id) for t in other.tracks}:
                            raise ValueError(f"edit {edit.to_json()}: scene {other.id!r} has no track "
                                             f"{edit.ids[0]!r}")
            except ValueError as exc:
                raise InputError(f"weathercity: {exc}") from None

    def native_size(self, scene: Scene) -> tuple[int, int]:
        """``size`` if given, else the scene's size with its longer side at most
        :data:`~wcbench.core.working_size.METRIC_RESOLUTION` (the training size is the profile's)."""
        return self.size or working_size(scene.image_size, METRIC_RESOLUTION)

    def setup_scene(self, scene: Scene, *, show_progress: bool = True) -> None:
        """Train the scene's model, or load it from its checkpoint in the cache folder (once per process)."""
        if self._scene_key != (scene.id, str(scene.root)):
            trained, _, facts = train_scene(
                scene, self.config, supervision=self.supervision, jitter=self.jitter, content=self.content,
                physics=self.training_physics(scene), show_progress=show_progress, device=self.device,
            )
            self.use_model(scene, trained, facts)

    def prepare(self, scene: Scene, weather: str, *, seed: int) -> None:
        """Train (or load) the scene's model once, then set up the renderer of ``weather``."""
        self.setup_scene(scene)
        model = self._model
        assert model is not None
        decoded = weather if weather in model.weathers else "clear"
        self._decoded = decoded
        self._node_colors = self._decode_nodes(model, decoded)
        self._activated = model.activated()
        # every placed node in fixed rows: a frame rewrites only the moving nodes' (render_frame)
        self._rows = FrameRows(model, self._node_colors, placement=self._placement, activated=self._activated)
        first = scene.frames[0].camera
        self._renderer = WeatherRenderer(
            GaussianArrays(**self._rows.arrays), self.weather_for(weather, seed, scene), up=scene.up,
            heading=first.camera_to_world[:3, 2], anchor=first.center, rasterizer=on_device(self.device),
        )

    def use_model(self, scene: Scene, model: WeatherCityModel, facts: dict[str, Any]) -> None:
        """Render ``scene`` with an already trained ``model`` (``facts``: its training record).

        :meth:`prepare` calls it after training; benchmarks hand in a model they trained themselves.
        """
        # the renderer's scene rows, sky and particles are numpy: a model trained on a GPU comes back
        # to the CPU, and only the rasterizer runs on self.device (docs/workstation.md)
        self._model, self._facts = model.to("cpu"), facts
        self._scene_key = (scene.id, str(scene.root))
        self._ego = None
        self._centers = np.stack([f.camera.center for f in scene.frames])
        self._times = np.array([f.timestamp for f in scene.frames], np.float64)
        try:
            placed: dict[int, str] = {}
            self._placed_facts = []
            if any(e.at is not None for e in self.edits):
                objects, placed, self._placed_facts = placed_objects(
                    self.edits, model, n_frames=len(scene), up=np.asarray(scene.up, np.float64),
                    ground=scene_ground(scene), sources=self._source_models(scene))
                self._model = model = model.with_objects(objects)
            self._placement = placement_for(self.edits, model.objects(), placed=placed)
            # what a removed or moved object hid takes the look of the background seen around it;
            # an object an edit set down hid nothing in the frames the model learned from
            vacated = (self._placement.hidden | set(self._placement.offsets)) - set(placed.values())
            self._vacated_facts = {}
            if vacated and self.fill_vacated:
                size = self.native_size(scene)
                cameras = [(k, np.asarray(cam.world_to_camera), np.asarray(cam.K), cam.width, cam.height)
                           for k, cam in ((k, scale_camera(f.camera, *size)) for k, f in enumerate(scene.frames))]
                self._model, self._vacated_facts = vacated_background(self._model, sorted(vacated), cameras,
                                                                          up=np.asarray(scene.up, np.float64))
        except ValueError as exc:
            raise InputError(f"weathercity: {exc}") from None

    def _source_models(self, scene: Scene) -> dict[str, WeatherCityModel]:
        """The trained model of every scene an ``insert scene=...`` names, trained with this method's
        settings (or loaded from the cache, as the scene's own is)."""
        for name in sorted({e.scene for e in self.edits if e.scene is not None}):
            if name not in self._sources:
                other = source_scene(scene, name)
                model, _, _ = train_scene(
                    other, self.config, supervision=self.supervision, jitter=self.jitter, content=self.content,
                    physics=self.training_physics(other), show_progress=True, device=self.device)
                self._sources[name] = model
        return self._sources

    @staticmethod
    def _decode_nodes(model: WeatherCityModel, weather: str) -> dict[str, torch.Tensor]:
        """Each node's colors under ``weather`` (features do not change while rendering: decoded once)."""
        with torch.no_grad():
            return {key: model.decoders(p.features, [weather]) for key, p in model.nodes().items()}

    def describe(self) -> dict[str, Any]:
        """Training facts (time, counts, skips, supervision) and the renderer's settings (the physics:
        :meth:`physics`)."""
        out: dict[str, Any] = {"training": self._facts, "decoded_weather": getattr(self, "_decoded", None)}
        if self._placed_facts:
            out["placed_objects"] = self._placed_facts
        if self._vacated_facts:
            out["vacated"] = self._vacated_facts
        if self._renderer is not None:
            out["renderer"] = self._renderer.info()
        return out

    def physics(self, scene: Scene, weather: str, *, seed: int) -> dict[str, Any] | str:
        """The physics weather its particles and fog are rendered with (clear: none).

        Raises
        ------
        InputError
            ``seed`` is the truth's particle seed (its rain or snow would be the truth's own).
        """
        if weather == "clear":
            return "none: clear renders no weather (the decoded clear colours and sky)"
        return physics_record(self.weather_for(weather, seed, scene))

    def truth_draw(self, scene: Scene, weather: str, *, seed: int) -> dict[str, Any]:
        """Its particle seed against the truth's, and whether its training read the truth frames
        (``sim-editor`` supervision)."""
        reads = None
        if supervision_severity(self.supervision) is not None:  # the truth frames shaped the whole model
            reads = (f"trained on {self.supervision}'s edits of the scene's ground-truth frames (truth/): a "
                     "calibration of the validity bench, not a competitor's input")
        physics = None if weather == "clear" else self.weather_for(weather, seed, scene)
        return truth_draw(scene, physics, option=self.physics_spec, reads=reads)

    def setup_timings(self) -> dict[str, float]:
        """``train_s``: the seconds the model's training took (recorded in its checkpoint, so a model
        loaded from the cache reports the training that made it)."""
        return {"train_s": float(self._facts["train_seconds"])} if self._facts else {}

    def _rays_for(self, K: np.ndarray, width: int, height: int) -> torch.Tensor:
        """The camera's unit rays, made once per intrinsics and size (every frame turns them)."""
        key = (np.asarray(K, np.float64).tobytes(), width, height)
        if key not in self._rays:
            self._rays = {key: camera_rays(K, width, height)}
        return self._rays[key]

    def render_frame(self, scene: Scene, weather: str, index: int, *, seed: int) -> tuple[np.ndarray, dict[str, Any]]:
        """Frame ``index`` under ``weather``: decoded colors, sky, particles and fog.

        The scene's Gaussians stay in the renderer's fixed rows (:class:`FrameRows`): a frame moves
        the objects' rows only. :meth:`render_frame_concat` is its twin.
        """
        renderer, rows = self._renderer, self._rows
        assert renderer is not None and rows is not None, "prepare() runs before render_frame()"
        start = time.perf_counter()
        renderer.refresh_scene(rows.place(index))
        return self._finish_frame(scene, index, None, start)

    def render_frame_concat(self, scene: Scene, weather: str, index: int, *,
                            seed: int) -> tuple[np.ndarray, dict[str, Any]]:
        """:meth:`render_frame` the slow, plain way: the frame's nodes concatenated afresh
        (:meth:`WeatherCityModel.frame_gaussians`) and copied in front of the particles. The tests
        and ``bench model``'s ``render`` group compare the two (the next ``render_frame`` after a
        call copies its whole scene in front of the particles once more)."""
        model = self._model
        assert model is not None, "prepare() runs before render_frame()"
        start = time.perf_counter()
        with torch.no_grad():
            g = model.frame_gaussians(index, self._placement, activated=self._activated)
            colors = torch.cat([self._node_colors[key] for key, _, _ in g.segments]) if g.segments else \
                torch.zeros(len(g), 3)
        return self._finish_frame(scene, index, GaussianArrays(g.means, g.quats, g.scales, g.opacities, colors),
                                  start)

    def _finish_frame(self, scene: Scene, index: int, gaussians: GaussianArrays | None,
                      start: float) -> tuple[np.ndarray, dict[str, Any]]:
        """Sky, particles, fog and the ego mask of frame ``index`` with the scene Gaussians placed
        (``gaussians``, or the renderer's own rows when ``None``)."""
        model, renderer = self._model, self._renderer
        assert model is not None and renderer is not None
        width, height = self.output_size(scene)
        cam = scale_camera(scene.frames[index].camera, width, height)
        sky = None
        if renderer.background_visible:  # under fog or haze the sky is never seen: not looked up
            # looked up at most at the training size: the map's cells between the training views' rays
            # were never trained, and a finer lookup shows them as a lattice (docs/guide.md "WeatherCity")
            trained = self.config.size_for(scene.image_size)
            at = trained if width > trained[0] else (width, height)
            sky_cam = cam if at == (width, height) else scale_camera(scene.frames[index].camera, *at)
            with torch.no_grad():
                grid = model.sky.grid_from_rays(self._rays_for(sky_cam.K, *at), sky_cam.camera_to_world)
                sky = model.sky(grid, [self._decoded]).numpy()
                if at != (width, height):
                    sky = cv2.resize(sky, (width, height), interpolation=cv2.INTER_LINEAR)
        t_graph = time.perf_counter()
        frame = renderer.render(
            cam, float(self._times[index] - self._times[0]),
            camera_velocity=camera_velocity(self._centers, self._times, index),
            gaussians=gaussians, background_image=sky,
        )
        image = frame.image
        ego = self._ego_mask(scene, (width, height))
        if ego is not None:  # the ego vehicle's body is masked, not weathered (as the editor does)
            image = np.array(image, np.float32, copy=True)
            image[ego] = masked_ego(raw_frame(scene, index, (width, height))[ego], renderer.weather.kind,
                                    self._appearance)
        timings = {**frame.timings_ms, "scene_graph": 1e3 * (t_graph - start),
                   "total": 1e3 * (time.perf_counter() - start)}
        return to_uint8(image), {**frame.info, "timings_ms": timings}

    def _ego_mask(self, scene: Scene, size: tuple[int, int]) -> np.ndarray | None:
        """The ego vehicle's body at ``size`` when training found one (the scene analysis, run again
        in a process that loaded the model from its checkpoint), else ``None``."""
        views = (self._facts or {}).get("views", {})
        if not float(views.get("ignored_pixels", 0.0)) > 0:
            return None
        key = (scene.id, str(scene.root), tuple(size))
        if self._ego is None or self._ego[0] != key:
            self._ego = (key, analyse_scene(scene).ego_mask(size))
        return self._ego[1]


def scene_ground(scene: Scene) -> Callable[[float, float], np.ndarray]:
    """``(x, y) -> [3]`` the ground's world point below world x, y from the scene's lidar
    (:func:`~wcbench.reference_model.editing.transfer.ground_point`), the search starting at the
    height of the frame's camera nearest to x, y."""
    points = scene.all_lidar_points()
    up = np.asarray(scene.up, np.float64)
    centers = np.stack([f.camera.center for f in scene.frames])
    first, second, _ = ground_axes(up)

    def ground(x: float, y: float) -> np.ndarray:
        near = centers[int(np.argmin(np.hypot(centers[:, first] - x, centers[:, second] - y)))]
        return ground_point(points, x, y, up=up, reference=near)

    return ground


def source_scene(scene: Scene, name: str) -> Scene:
    """The scene an ``insert scene=NAME`` names: the folder NAME (a path), else the folder NAME
    beside ``scene``'s, else the built-in scene set NAME of one scene (``synth_1``).

    Raises
    ------
    ValueError
        If none of them is a scene.
    """
    for folder in (Path(name).expanduser(), Path(scene.root).parent / name):
        if folder.is_dir():
            return load_scene(folder)
    try:
        found = get_scene_set(name, data_root=Path(scene.root).parent)
    except (UnknownNameError, InputError):
        found = None
    if found is not None and len(found.scenes) == 1:
        return found.scenes[0].load()
    raise ValueError(f"insert scene={name}: no scene {name!r} (neither a folder, nor a folder beside "
                     f"{Path(scene.root)}, nor a built-in scene set of one scene)")


def _track_stand_ins(scene: Scene) -> dict[str, Any]:
    """The scene's tracks as the objects an edit selects from (id and class)."""
    return {str(t.id): SimpleNamespace(track_id=str(t.id), class_name=t.class_name) for t in scene.tracks}
