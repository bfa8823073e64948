"""``weathercity``: the paper's method, trained on the scene, rendered under physics weather.

For each scene the method (1) gets edited frames of every weather from a supervision method (the
built-in ``physical-editor`` by default: physically based weather from the scene's lidar, without
particles, since particles come from the physics; the ``filter2d`` 2D grade, without its streaks
and flakes; the simulated editor ``sim-editor[:SEVERITY]`` on scenes with ground truth; or another
tool's frames read from a folder, ``READER:DIR``), each checked against the run's one weather spec
(:mod:`wcbench.methods.weather_spec`: the built-in editors edit with the physics' rate and
visibility, a folder that records another is refused), (2) builds the weather Gaussian scene
graph from the lidar and trains it on the raw frames and the edits, each edit's render composed
through the haze its physics weather adds (:mod:`wcbench.reference_model.training`,
:mod:`wcbench.reference_model.model.haze`), caching the trained model under a key over every input
that changes it, (3) renders any frame under any weather at its training resolution: the decoded
colors of that weather, the weather's sky, rain or snow particles rasterized with the scene, and
exact Beer-Lambert fog (:mod:`wcbench.reference_model.weather`), optionally with object edits.

Its frames, rendered at the training resolution, are scored at the scene's working size like every
other method's, resized to it as they are read (:meth:`wcbench.units.WorkUnit.score`).
``info.json`` records the training time, the Gaussian counts per node, what the scene graph
skipped, the supervision, and the whole-frame render FPS.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from wcbench.core.errors import InputError
from wcbench.core.image_io import to_uint8
from wcbench.core.models.store import ModelStore
from wcbench.core.models.vgg16 import load_vgg16_features
from wcbench.core.paths import cache_dir
from wcbench.core.progress import progress
from wcbench.core.storage import sha256_file, sha256_json
from wcbench.core.weathers import WEATHERS
from wcbench.methods import get_method
from wcbench.methods.filter2d import FOG_VISIBILITY_M as FILTER2D_VISIBILITY_M
from wcbench.methods.filter2d import Filter2DMethod
from wcbench.methods.physical_editor import NAME as PHYSICAL_EDITOR
from wcbench.methods.physical_editor import check_lidar, edit_scene
from wcbench.methods.protocol import MethodInfo
from wcbench.methods.runnable import FrameRenderer
from wcbench.methods.sim_editor import supervision_frames as sim_editor_frames
from wcbench.methods.sim_editor import supervision_severity, truth_paths
from wcbench.methods.weather_spec import (
    EDITED,
    WeathersOption,
    check_consistent,
    describe_option,
    has_truth_weather,
    parse_weathers,
    physics_record,
    resolve_physics,
    truth_physics,
)
from wcbench.predictions import INFO_FILE
from wcbench.reference_model.editing.edits import parse_edits, placement_for
from wcbench.reference_model.model.haze import Haze
from wcbench.reference_model.model.scene_model import Placement, WeatherCityModel
from wcbench.reference_model.model.sky import camera_rays
from wcbench.reference_model.training.build import build_model
from wcbench.reference_model.training.checkpoint import load_checkpoint, read_checkpoint_info, save_checkpoint
from wcbench.reference_model.training.config import TrainConfig, make_config
from wcbench.reference_model.training.losses import ContentLoss
from wcbench.reference_model.training.trainer import Trainer, evaluate_views
from wcbench.reference_model.training.views import TrainingView, build_views
from wcbench.reference_model.weather.conditions import Weather
from wcbench.reference_model.weather.fog import visibility_from_density
from wcbench.reference_model.weather.renderer import WeatherRenderer, camera_velocity, scale_camera
from wcbench.scenes.scene import Scene

__all__ = ["VERSION", "TrainingInputs", "WeatherCityMethod", "content_loss_for", "train_scene", "training_hazes",
           "training_inputs", "truth_physics"]

#: Bumped whenever training or rendering changes what a cached model or a frame would be.
VERSION = "1"
#: VGG16 layer of the content loss ("relu4_1-level" features; docs/design.md §6).
CONTENT_LAYERS = ("relu4_1",)


def _check_supervision(spec: str, jitter: float) -> float | None:
    """The sim-editor severity of ``spec`` (``None``: another source); refuses a jitter it would ignore.

    Raises
    ------
    InputError
        A sim-editor severity outside [0, 1], or a ``jitter`` given with sim-editor or physical-editor
        supervision.
    """
    if spec == PHYSICAL_EDITOR and jitter:
        raise InputError(f"--supervision {spec!r}: jitter perturbs the filter2d supervision only (add "
                         "--supervision filter2d)")
    severity = supervision_severity(spec)
    if severity is not None and jitter:
        raise InputError(f"--supervision {spec!r}: jitter perturbs the filter2d supervision; sim-editor's own "
                         "knob is its severity (sim-editor:SEVERITY)")
    return severity


def _supervision_frames(scene: Scene, spec: str, weathers: tuple[str, ...], jitter: float, seed: int, *,
                        physics: Mapping[str, Weather] | None = None, size: tuple[int, int] | None = None
                        ) -> tuple[dict[str, list[np.ndarray]], dict[str, Any]]:
    """Edited frames per weather from ``spec`` (``physical-editor``, ``filter2d``, ``sim-editor[:SEVERITY]``
    or ``READER:DIR``) and a record of them, each weather checked against the run's ``physics``.

    The record's ``weather_check`` says per weather how the supervision's weather relates to the
    physics: ``"consistent"`` (made from the same spec, or recorded and equal), ``"reconciled: ..."``
    (a built-in editor set to the physics' values) or ``"unverified: ..."`` (a folder that records
    no weather). A recorded contradiction is refused.

    Raises
    ------
    InputError
        A malformed ``spec``, a missing folder, or a supervision whose weather contradicts the physics.
    """
    frames: dict[str, list[np.ndarray]] = {}
    physics = physics if physics is not None else resolve_physics(scene, "presets")
    size = size or scene.image_size
    edited = {w: physics[w] for w in weathers if w in physics}
    if spec == PHYSICAL_EDITOR:
        _check_supervision(spec, jitter)
        frames_f, record, timings = edit_scene(scene, edited, size)
        record["weather_check"] = {w: "consistent: edited with the run's physics" for w in edited}
        record["timings"] = timings  # dropped from the training's key (:func:`train_scene`)
        return {w: list(v) for w, v in frames_f.items()}, record
    if spec == "filter2d":
        fog = edited.get("fog")
        beta = fog.haze()[0] if fog is not None else 0.0
        visibility = visibility_from_density(beta) if beta > 0 else None
        f2d = Filter2DMethod(effects=False, jitter=jitter, visibility_m=visibility)
        for w in weathers:
            frames[w] = [f2d.render_frame(scene, w, k, seed=seed) for k in range(len(scene))]
        check = {w: "unverified: filter2d's rain and snow are a 2D grade with no rate" for w in weathers if w != "fog"}
        if "fog" in weathers:
            check["fog"] = (f"reconciled: filter2d fogs at the physics' visibility {visibility:.4g} m (its own "
                            f"default: {FILTER2D_VISIBILITY_M:g} m)" if visibility else "unverified: no fog haze")
        record = {"method": "filter2d", "effects": False, "jitter": jitter, "seed": seed,
                  "parameters": {w: f2d.parameters(w) for w in weathers}, "weather_check": check}
        return frames, record
    severity = _check_supervision(spec, jitter)
    if severity is not None:  # the simulated editor's frames of the scene's truth (synth scenes)
        truth = truth_physics(scene) if has_truth_weather(scene) else {}
        for w in edited:
            if w in truth:
                check_consistent(w, edited[w], physics_record(truth[w]),
                                 source=f"--supervision {spec} ({Path(scene.root) / 'truth' / 'weather.json'})")
        frames, record = sim_editor_frames(scene, severity, weathers, seed)
        record["weather_check"] = {w: "consistent: the truth's weather" if w in truth else
                                   "unverified: the scene records no weather of its truth" for w in weathers}
        return frames, record
    reader_name, sep, folder = spec.partition(":")
    if not sep or not folder:
        raise InputError(f"--supervision {spec!r}: expected {PHYSICAL_EDITOR!r}, 'filter2d', "
                         "sim-editor[:SEVERITY] or READER:DIR (e.g. qwen-image:edits/)")
    reader = get_method(reader_name)
    root = Path(folder).expanduser()
    if not root.is_dir():
        raise InputError(f"--supervision {spec!r}: {root} is not a folder")
    scene_root = root / scene.id if (root / scene.id).is_dir() else root
    hashes: dict[str, list[str]] = {}
    missing: dict[str, str] = {}
    checked: dict[str, str] = {}
    for w in weathers:
        if w not in reader.info.weathers:
            missing[w] = f"{reader_name} does not produce {w}"
            continue
        checked[w] = _check_folder_weather(scene_root / w / INFO_FILE, w, edited.get(w))
        try:
            seq = reader.open_predictions(scene, w, scene_root, resize=True)
        except InputError as exc:
            missing[w] = str(exc).splitlines()[0]
            continue
        if len(seq) != len(scene) or getattr(seq, "missing", None):
            missing[w] = f"{len(seq)} frames for a scene of {len(scene)}"
            continue
        frames[w] = list(seq)
        hashes[w] = seq.sha256s()
    return frames, {"method": reader_name, "folder": str(scene_root.resolve()), "sha256": hashes,
                    "not_supervised": missing, "weather_check": {w: c for w, c in checked.items() if w in frames}}


def _check_folder_weather(info_path: Path, kind: str, physics: Weather | None) -> str:
    """``"consistent"`` when the folder's ``info.json`` records the physics it was made with
    (``parameters.physics``) and it matches; ``"unverified: ..."`` when it records none.

    Raises
    ------
    InputError
        The recorded weather contradicts ``physics`` (both values named).
    """
    if physics is None:
        return "unverified: no physics weather of this kind in the run"
    try:
        doc = json.loads(info_path.read_text(encoding="utf-8")) if info_path.is_file() else {}
    except (OSError, ValueError):
        doc = {}
    record = (doc.get("parameters") or {}).get("physics") if isinstance(doc, dict) else None
    if not isinstance(record, dict):
        return "unverified: the folder records no weather (info.json parameters.physics)"
    check_consistent(kind, physics, record, source=str(info_path))
    return f"consistent: {info_path} records the run's physics"


def content_loss_for(config: TrainConfig, store: ModelStore | None) -> tuple[ContentLoss | None, str]:
    """The content loss on the real VGG16 weights, or ``None`` and why it is skipped."""
    if config.content_weight == 0:
        return None, "off (no-content-loss ablation)"
    store = store if store is not None else ModelStore()
    if not store.available("vgg16"):
        return None, f"skipped: {store.missing_message('vgg16')}"
    features = load_vgg16_features(store=store, layers=CONTENT_LAYERS)
    return ContentLoss(features, size=config.content_size), (
        f"VGG16 {','.join(CONTENT_LAYERS)} at {config.content_size[0]}x{config.content_size[1]}, "
        f"every {config.content_interval * config.weather_interval} steps (sha256 {store.sha256('vgg16')})"
    )


def training_hazes(config: TrainConfig, physics: Mapping[str, Weather], weathers: tuple[str, ...]) -> dict[str, Haze]:
    """The haze each edited weather's training render is composed through (none unless
    ``config.through_haze``): that of its physics weather, or of the kind's default one."""
    if not config.through_haze:
        return {}
    return {w: Haze.of(physics.get(w, Weather(kind=w))) for w in weathers if w != "clear"}


@dataclass
class TrainingInputs:
    """What a training of a scene is made from (see :func:`training_inputs`).

    Attributes
    ----------
    views : list of TrainingView
        Every frame's view at the training size (held-out frames included).
    trained : tuple of str
        ``"clear"`` and the supervised weathers (those the model gets decoders for).
    supervision : dict
        Record of the supervision (method, settings or folder and hashes, weathers missing).
    view_facts : dict
        How the views were made (:func:`build_views`).
    sources : list of str
        sha256 of the scene's frames.
    hazes : dict of str to Haze
        The haze of each trained edited weather (:func:`training_hazes`).
    """

    views: list[TrainingView]
    trained: tuple[str, ...]
    supervision: dict[str, Any]
    view_facts: dict[str, Any]
    sources: list[str]
    hazes: dict[str, Haze] = field(default_factory=dict)


def training_inputs(scene: Scene, config: TrainConfig, *, supervision: str = PHYSICAL_EDITOR, jitter: float = 0.0,
                    weathers: tuple[str, ...] = ("rain", "snow", "fog"),
                    physics: Mapping[str, Weather] | None = None) -> TrainingInputs:
    """The views (raw frames, edits of every supervised weather, lidar depth, sky and object masks)
    of ``scene`` at ``config``'s training size, and the haze of each weather's physics (``physics``;
    the kind's default weather where it has none).

    Raises
    ------
    InputError
        On a malformed ``supervision`` or a folder that does not exist.
    """
    size = config.size_for(scene.image_size)
    physics = dict(physics) if physics is not None else resolve_physics(scene, "presets")
    frames, sup_record = _supervision_frames(scene, supervision, weathers, jitter, config.seed, physics=physics,
                                             size=size)
    trained = ("clear", *[w for w in weathers if w in frames])
    views, view_facts = build_views(scene, size=size, supervision={w: frames[w] for w in trained if w != "clear"})
    return TrainingInputs(views=views, trained=trained, supervision=sup_record, view_facts=view_facts,
                          sources=[sha256_file(f.image_path) for f in scene.frames],
                          hazes=training_hazes(config, physics, trained))


def train_scene(
    scene: Scene,
    config: TrainConfig,
    *,
    supervision: str = PHYSICAL_EDITOR,
    jitter: float = 0.0,
    weathers: tuple[str, ...] = ("rain", "snow", "fog"),
    physics: Mapping[str, Weather] | None = None,
    folder: Path | None = None,
    store: ModelStore | None = None,
    content: ContentLoss | str | None = "auto",
    show_progress: bool = True,
    log: Any = print,
) -> tuple[WeatherCityModel, list[TrainingView], dict[str, Any]]:
    """Train (or load the cached) WeatherCity model of ``scene``.

    Parameters
    ----------
    scene : Scene
    config : TrainConfig
    supervision : str
        ``"physical-editor"`` (default), ``"filter2d"``, ``"sim-editor"`` / ``"sim-editor:SEVERITY"``
        (the simulated editor's frames of the scene's ground truth) or ``READER:DIR``.
    jitter : float
        Per-frame perturbation strength of the ``filter2d`` supervision (refused with sim-editor's).
    weathers : tuple of str
        Edited weathers to train (clear is always trained); those without supervision are not.
    physics : mapping of str to Weather, optional
        The physics weathers the model will be rendered under: the built-in supervision edits with
        them and their haze is composed into the training renders (``config.through_haze``).
        Default: each kind's default preset.
    folder : Path, optional
        Where the checkpoint goes; default the cache folder ``weathercity/<scene>-<key>``.
    store : ModelStore, optional
        Where the VGG16 weights of the content loss come from.
    content : ContentLoss, None or "auto"
        The content loss to use (tests inject a small network); ``"auto"``: the real VGG16 when
        installed, else the term is skipped and the reason recorded.
    show_progress : bool
    log : callable
        Where one-line phase messages go.

    Returns
    -------
    model : WeatherCityModel
    views : list of TrainingView
        Every frame's view (held-out frames included).
    facts : dict
        What was built, skipped and measured (``info.json``).
    """
    start = time.perf_counter()
    size = config.size_for(scene.image_size)
    log(f"weathercity {scene.id}: {size[0]}x{size[1]} views, supervision from {supervision}")
    inputs = training_inputs(scene, config, supervision=supervision, jitter=jitter, weathers=weathers,
                             physics=physics)
    views, trained = inputs.views, inputs.trained
    content_loss: ContentLoss | None
    if isinstance(content, str):
        if content != "auto":
            raise ValueError(f"content must be a ContentLoss, None or 'auto', got {content!r}")
        content_loss, content_note = content_loss_for(config, store)
    else:
        content_loss, content_note = content, "injected" if content is not None else "off"
    made = {k: v for k, v in inputs.supervision.items() if k != "timings"}  # what makes the frames, not how fast
    key = sha256_json({"version": VERSION, "scene": scene.id, "sources": inputs.sources, "config": config.to_json(),
                       "supervision": made, "trained": trained, "content": content_note,
                       "hazes": {w: h.to_json() for w, h in inputs.hazes.items()},
                       "lidar": [str(f.lidar_path) for f in scene.frames]})
    folder = folder or cache_dir() / "weathercity" / f"{scene.id}-{key[:16]}"
    log(f"weathercity {scene.id}: building the scene graph")
    train_views = [v for v in views if v.frame not in config.holdout]
    model, graph_facts = build_model(scene, train_views, config, weathers=trained)

    def make_trainer(m: WeatherCityModel) -> Trainer:
        return Trainer(m, views, config, content=content_loss, hazes=inputs.hazes)

    info = read_checkpoint_info(folder)
    if info is not None and info.get("key") == key:
        trainer = load_checkpoint(folder, model=model, views=views, make_trainer=make_trainer)
        resumed = trainer.step_index
    else:
        trainer, resumed = make_trainer(model), 0
    prep_s = time.perf_counter() - start
    if trainer.step_index < config.iterations:
        if resumed:
            log(f"weathercity {scene.id}: resuming at step {resumed} of {config.iterations}")
        bar = progress(range(trainer.step_index, config.iterations), desc=f"training {scene.id}",
                       total=config.iterations - trainer.step_index, enabled=show_progress, unit="step")
        steps = iter(bar)
        next(steps, None)  # the bar counts a step each time the next one is asked for

        def on_step(s: Any) -> None:
            next(steps, None)
            if hasattr(bar, "set_postfix") and s.step % 10 == 0:
                bar.set_postfix(loss=f"{s.loss:.4f}", psnr=f"{s.psnr_clear:.2f}", gaussians=s.gaussians)

        trainer.train(callback=on_step, checkpoint=lambda t: save_checkpoint(t, folder, extra={"key": key}))
        if hasattr(bar, "close"):
            bar.close()
    held = [v for v in views if v.frame in config.holdout]
    facts: dict[str, Any] = {
        "version": VERSION,
        "config": config.to_json(),
        "key": key,
        "checkpoint": str(folder),
        "supervision": inputs.supervision,
        "trained_weathers": list(trained),
        "not_trained": sorted(set(weathers) - set(trained)),
        "content_loss": content_note,
        "training_hazes": {w: h.to_json() for w, h in inputs.hazes.items()},
        "views": inputs.view_facts,
        "scene_graph": graph_facts,
        "gaussians": model.counts(),
        "iterations": trainer.step_index,
        "resumed_at": resumed,
        "train_seconds": round(trainer.train_seconds, 3),
        "prepare_seconds": round(prep_s, 3),
        "densify": trainer.densify_log[-1] if trainer.densify_log else None,
    }
    if held:
        facts["holdout"] = evaluate_views(model, held)
    return model, views, facts


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
    weathers : "auto", "truth", "presets" or dict, optional
        The physics weather per kind (:func:`~wcbench.methods.weather_spec.parse_weathers`). Default
        ``"auto"``: a scene's recorded weather where it ships one (``truth/weather.json`` of the
        ``synth_*`` scenes, particle seed included, so that a comparison with the truth measures
        the learned scene, not the draw of the particles), else each kind's default preset;
        ``"truth"`` requires the record; a dict gives the :class:`Weather` fields
        (``--method-option 'weathers={"rain": {"preset": "heavy"}}'``).
    size : (int, int), optional
        Render size; default the training size (scored at the scene's working size, as every method).
    edits : str or list, optional
        Object edits (``"remove class=Car except ids=3,7"``, a JSON list...).
    content : ContentLoss, None or "auto"
        See :func:`train_scene`.
    """

    version = VERSION

    def __init__(
        self,
        *,
        supervision: str = PHYSICAL_EDITOR,
        jitter: float = 0.0,
        profile: str = "default",
        ablation: str = "",
        settings: dict[str, Any] | None = None,
        holdout: tuple[int, ...] | list[int] = (),
        weathers: Any = None,
        size: tuple[int, int] | None = None,
        edits: str | list[Any] | None = None,
        content: Any = "auto",
    ):
        try:
            self.config = make_config(profile, ablation=ablation, holdout=tuple(int(h) for h in holdout),
                                      **(settings or {}))
            self.edits = [] if not edits else parse_edits(edits)
        except ValueError as exc:
            raise InputError(f"weathercity: {exc}") from None
        if not 0.0 <= float(jitter) <= 1.0:
            raise InputError(f"weathercity: jitter must be in [0, 1], got {jitter}")
        _check_supervision(supervision, float(jitter))  # a bad sim-editor severity fails before training
        self.supervision, self.jitter, self.content = supervision, float(jitter), content
        self.weathers: WeathersOption = parse_weathers(weathers, who="weathercity")
        self._physics: dict[str, dict[str, Weather]] = {}
        self.size = None if size is None else (int(size[0]), int(size[1]))
        self.info = MethodInfo(
            name="weathercity",
            description="WeatherCity: weather Gaussians trained on raw + edited frames, physics particles and fog",
            kind="runnable",
            weathers=WEATHERS,
            requires=("torch",),
            layout="writes <out>/weathercity/<scene>/<weather>/{frame:03d}.png + info.json (training resolution)",
        )
        self._model: WeatherCityModel | None = None
        self._scene_key: tuple[str, str] | None = None
        self._facts: dict[str, Any] = {}
        self._renderer: WeatherRenderer | None = None
        self._node_colors: dict[str, torch.Tensor] = {}
        self._activated: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}
        self._rays: dict[tuple[bytes, int, int], torch.Tensor] = {}
        self._placement = Placement()

    def required_models(self) -> tuple[str, ...]:
        """``vgg16`` for the content loss, unless it is off or a loss was passed in."""
        return ("vgg16",) if self.content == "auto" and self.config.content_weight != 0 else ()

    def weather_for(self, kind: str, seed: int, scene: Scene) -> Weather:
        """The physics weather of ``kind`` for ``scene``: its recorded one (seed included) under
        ``"auto"``/``"truth"`` where it ships one, else the given or preset weather with ``seed``."""
        if kind == "clear":
            return Weather(kind="clear", seed=seed)
        return resolve_physics(scene, self.weathers, seed=seed, truth=self._recorded(scene))[kind]

    def _recorded(self, scene: Scene) -> dict[str, Weather] | None:
        """The scene's recorded weather (``truth/weather.json``), read once per scene folder; ``None``
        when the option does not use it."""
        if self.weathers == "truth" or (self.weathers == "auto" and has_truth_weather(scene)):
            key = str(scene.root)
            if key not in self._physics:
                self._physics[key] = truth_physics(scene)
            return self._physics[key]
        return None

    def physics(self, scene: Scene) -> dict[str, Weather]:
        """The physics weather of every edited kind for ``scene``: the training hazes and the
        built-in supervision read it."""
        return {kind: self.weather_for(kind, 0, scene) for kind in EDITED}

    def parameters(self, weather: str) -> dict[str, Any]:
        """Training settings, supervision, edits and the weather option (the resolved physics goes to
        ``describe``; the seed is recorded apart)."""
        return {"training": self.config.to_json(), "supervision": self.supervision, "jitter": self.jitter,
                "edits": [e.to_json() for e in self.edits],
                "weather": describe_option(self.weathers, weather) if weather != "clear" else "clear"}

    def check_scene(self, scene: Scene, weather: str) -> None:
        """With ``weathers="truth"`` the scene must ship ``truth/weather.json`` describing ``weather``;
        with sim-editor supervision, truth frames of every edited weather; with the physical editor,
        lidar (checked before any render)."""
        if weather != "clear":
            resolve_physics(scene, self.weathers, truth=self._recorded(scene))
        if supervision_severity(self.supervision) is not None:
            for kind in EDITED:
                truth_paths(scene, kind)
        if self.supervision == PHYSICAL_EDITOR:
            check_lidar(scene)

    def native_size(self, scene: Scene) -> tuple[int, int]:
        """``size`` if given, else the training resolution."""
        return self.size or self.config.size_for(scene.image_size)

    def setup_scene(self, scene: Scene, *, show_progress: bool = True) -> None:
        """Train the scene's model, or load it from its checkpoint in the cache folder (once per process)."""
        if self._scene_key != (scene.id, str(scene.root)):
            trained, _, facts = train_scene(
                scene, self.config, supervision=self.supervision, jitter=self.jitter, content=self.content,
                physics=self.physics(scene), show_progress=show_progress,
            )
            self.use_model(scene, trained, facts)

    def prepare(self, scene: Scene, weather: str, *, seed: int) -> None:
        """Train (or load) the scene's model once, then set up the renderer of ``weather``."""
        self.setup_scene(scene)
        model = self._model
        assert model is not None
        decoded = weather if weather in model.weathers else "clear"
        self._decoded = decoded
        with torch.no_grad():
            g = model.frame_gaussians(0, self._placement)
        # geometry placeholder; every frame passes its own Gaussians
        first = scene.frames[0].camera
        self._renderer = WeatherRenderer(
            _FrameSet(g.means, g.quats, g.scales, g.opacities, torch.zeros(len(g), 3)),
            self.weather_for(weather, seed, scene), up=scene.up, heading=first.camera_to_world[:3, 2],
            anchor=first.center,
        )
        self._node_colors = self._decode_nodes(model, decoded)
        self._activated = model.activated()

    def use_model(self, scene: Scene, model: WeatherCityModel, facts: dict[str, Any]) -> None:
        """Render ``scene`` with an already trained ``model`` (``facts``: its training record).

        :meth:`prepare` calls it after training; benchmarks hand in a model they trained themselves.
        """
        self._model, self._facts = model, facts
        self._scene_key = (scene.id, str(scene.root))
        self._centers = np.stack([f.camera.center for f in scene.frames])
        self._times = np.array([f.timestamp for f in scene.frames], np.float64)
        try:
            self._placement = placement_for(self.edits, model.objects())
        except ValueError as exc:
            raise InputError(f"weathercity: {exc}") from None

    @staticmethod
    def _decode_nodes(model: WeatherCityModel, weather: str) -> dict[str, torch.Tensor]:
        """Each node's colors under ``weather`` (features do not change while rendering: decoded once)."""
        with torch.no_grad():
            return {key: model.decoders(p.features, [weather]) for key, p in model.nodes().items()}

    def describe(self) -> dict[str, Any]:
        """Training facts (time, counts, skips, supervision) and the renderer's settings."""
        out: dict[str, Any] = {"training": self._facts, "decoded_weather": getattr(self, "_decoded", None)}
        if self._renderer is not None:
            out["renderer"] = self._renderer.info()
            if self._renderer.weather.kind != "clear":
                out["physics"] = physics_record(self._renderer.weather)
        return out

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
        """Frame ``index`` under ``weather``: decoded colors, sky, particles and fog."""
        model, renderer = self._model, self._renderer
        assert model is not None and renderer is not None, "prepare() runs before render_frame()"
        start = time.perf_counter()
        width, height = self.output_size(scene)
        cam = scale_camera(scene.frames[index].camera, width, height)
        with torch.no_grad():
            g = model.frame_gaussians(index, self._placement, activated=self._activated)
            colors = torch.cat([self._node_colors[key] for key, _, _ in g.segments]) if g.segments else \
                torch.zeros(len(g), 3)
            sky = None
            if renderer.background_visible:  # under fog the sky is never seen: not looked up
                grid = model.sky.grid_from_rays(self._rays_for(cam.K, width, height), cam.camera_to_world)
                sky = model.sky(grid, [self._decoded]).numpy()
        t_graph = time.perf_counter()
        frame = renderer.render(
            cam, float(self._times[index] - self._times[0]),
            camera_velocity=camera_velocity(self._centers, self._times, index),
            gaussians=_FrameSet(g.means, g.quats, g.scales, g.opacities, colors), background_image=sky,
        )
        timings = {**frame.timings_ms, "scene_graph": 1e3 * (t_graph - start),
                   "total": 1e3 * (time.perf_counter() - start)}
        return to_uint8(frame.image), {**frame.info, "timings_ms": timings}


class _FrameSet:
    """The five Gaussian arrays of a frame, as the weather renderer takes them."""

    def __init__(self, means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                 colors: torch.Tensor):
        self.means, self.quats, self.scales, self.opacities, self.colors = means, quats, scales, opacities, colors
