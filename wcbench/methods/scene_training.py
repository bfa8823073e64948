"""Training the WeatherCity model of a scene: its supervision, its inputs, the cache and the record.

The ``weathercity`` method (:mod:`wcbench.methods.weathercity`) renders a trained model; ``wcbench
train`` trains without rendering. Both train through :func:`train_scene`: (1) the edited frames of
every weather from a supervision method (the built-in ``physical-editor`` by default, ``filter2d``,
``sim-editor[:SEVERITY]`` on scenes with ground truth, or another tool's frames read from a folder,
``READER:DIR``), each checked against the run's one weather spec (:mod:`.weather_spec`); (2) the
training views and the haze each edited weather's render is composed through
(:mod:`wcbench.reference_model.training`, :mod:`wcbench.reference_model.model.haze`); (3) the
scene graph built from the lidar and trained, cached under a key over every input that changes it
and resumed from its last checkpoint.

It lives beside the methods because its supervision is other methods' frames.
"""

from __future__ import annotations

import functools
import json
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.code_digest import source_digest
from wcbench.core.errors import InputError
from wcbench.core.locking import EntryLock
from wcbench.core.models.store import ModelStore
from wcbench.core.models.vgg16 import load_vgg16_features
from wcbench.core.paths import cache_dir
from wcbench.core.progress import progress
from wcbench.core.storage import atomic_write_json, sha256_file, sha256_json
from wcbench.methods import get_method
from wcbench.methods.filter2d import Filter2DMethod
from wcbench.methods.physical_editor import NAME as PHYSICAL_EDITOR
from wcbench.methods.physical_editor import edit_scene
from wcbench.methods.sim_editor import supervision_frames as sim_editor_frames
from wcbench.methods.sim_editor import supervision_severity
from wcbench.methods.weather_spec import (
    check_consistent,
    has_truth_weather,
    physics_record,
    resolve_physics,
    truth_physics,
)
from wcbench.predictions import INFO_FILE
from wcbench.reference_model.devices import device_problem
from wcbench.reference_model.model.haze import Haze
from wcbench.reference_model.model.scene_model import WeatherCityModel
from wcbench.reference_model.training.build import build_model
from wcbench.reference_model.training.checkpoint import (
    load_checkpoint,
    load_model,
    read_checkpoint_info,
    save_checkpoint,
)
from wcbench.reference_model.training.config import TrainConfig
from wcbench.reference_model.training.losses import ContentLoss
from wcbench.reference_model.training.trainer import Trainer, evaluate_views
from wcbench.reference_model.training.views import TrainingView, build_views
from wcbench.reference_model.weather.conditions import Weather
from wcbench.reference_model.weather.fog import visibility_from_density
from wcbench.scenes.scene import Scene

__all__ = ["LOCK_TIMEOUT_S", "VERSION", "TrainingInputs", "check_supervision", "content_loss_for", "supervision_frames",
           "train_scene", "training_hazes", "training_inputs"]

#: Bumped whenever training or rendering changes what a cached model or a frame would be.
VERSION = "1"
#: Seconds a training waits while another process trains the same model (a hung holder, not a long
#: training, is what it guards against: the default profile trains a real scene in minutes).
LOCK_TIMEOUT_S = 6 * 3600.0
#: VGG16 layer of the content loss ("relu4_1-level" features; docs/design.md §6).
CONTENT_LAYERS = ("relu4_1",)


def check_supervision(spec: str, jitter: float) -> float | None:
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


def supervision_frames(scene: Scene, spec: str, weathers: tuple[str, ...], jitter: float, seed: int, *,
                        physics: Mapping[str, Weather] | None = None, size: tuple[int, int] | None = None,
                        show_progress: bool = True) -> tuple[dict[str, list[np.ndarray]], dict[str, Any]]:
    """Edited frames per weather from ``spec`` (``physical-editor``, ``filter2d``, ``sim-editor[:SEVERITY]``
    or ``READER:DIR``) and a record of them, each weather checked against the run's ``physics``.

    The record's ``weather_check`` says per weather how the supervision's weather relates to the
    physics: ``"consistent"`` (made from the same spec, or recorded and equal) or
    ``"unverified: ..."`` (``filter2d``'s rain and snow, which have no rate; a folder that records
    no weather). A recorded contradiction is refused. ``show_progress``: count the physical editor's
    frames on stderr.

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
        check_supervision(spec, jitter)
        frames_f, record, timings = edit_scene(scene, edited, size, show_progress=show_progress)
        record["weather_check"] = {w: "consistent: edited with the run's physics" for w in edited}
        record["timings"] = timings  # dropped from the training's key (:func:`train_scene`)
        return {w: list(v) for w, v in frames_f.items()}, record
    if spec == "filter2d":
        fog = edited.get("fog")
        beta = fog.haze()[0] if fog is not None else 0.0
        # the run's physics visibility, which a physics option may have set apart from the scene's
        f2d = Filter2DMethod(effects=False, jitter=jitter,
                             visibility_m=visibility_from_density(beta) if beta > 0 else None)
        for w in weathers:
            frames[w] = [f2d.render_frame(scene, w, k, seed=seed) for k in range(len(scene))]
        check = {w: "unverified: filter2d's rain and snow are a 2D grade with no rate" for w in weathers if w != "fog"}
        if "fog" in weathers:
            _, visibility, _ = f2d.fog_weather(scene)
            check["fog"] = (f"consistent: filter2d fogs at the run's physics visibility {visibility:.4g} m"
                            if beta > 0 else f"unverified: the run's physics fog has no haze; filter2d fogs at "
                                             f"the scene's requested {visibility:.4g} m")
        record = {"method": "filter2d", "effects": False, "jitter": jitter, "seed": seed,
                  "parameters": {w: f2d.parameters(w) for w in weathers},
                  "physics": {w: f2d.physics(scene, w, seed=seed) for w in weathers}, "weather_check": check}
        return frames, record
    severity = check_supervision(spec, jitter)
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
    # the scene's folder of edits, named like the scene or its data folder (an older run's layout)
    scene_root = next((root / n for n in (scene.id, Path(scene.root).name) if (root / n).is_dir()), root)
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
    if isinstance(record, dict) and "unverified" in record:  # e.g. filter2d's rain: a grade with no rate
        return f"unverified: {info_path} says {record['unverified']}"
    if not isinstance(record, dict):
        return "unverified: the folder records no weather (info.json parameters.physics)"
    check_consistent(kind, physics, record, source=str(info_path))
    return f"consistent: {info_path} records the run's physics"


def content_loss_for(config: TrainConfig, store: ModelStore | None) -> tuple[ContentLoss | None, str]:
    """The content loss on the real VGG16 weights, or ``None`` and why it is skipped."""
    store = store if store is not None else ModelStore()
    note = _content_note(config, store)
    if config.content_weight == 0 or not store.available("vgg16"):
        return None, note
    features = load_vgg16_features(store=store, layers=CONTENT_LAYERS)
    return ContentLoss(features, size=config.content_size), note


def _content_note(config: TrainConfig, store: ModelStore | None) -> str:
    """What :func:`content_loss_for` would use, without loading the weights (a key's part)."""
    if config.content_weight == 0:
        return "off (no-content-loss ablation)"
    store = store if store is not None else ModelStore()
    if not store.available("vgg16"):
        return f"skipped: {store.missing_message('vgg16')}"
    return (f"VGG16 {','.join(CONTENT_LAYERS)} at {config.content_size[0]}x{config.content_size[1]}, "
            f"every {config.content_interval * config.weather_interval} steps (sha256 {store.sha256('vgg16')})")


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
                    physics: Mapping[str, Weather] | None = None, show_progress: bool = True) -> TrainingInputs:
    """The views (raw frames, edits of every supervised weather, lidar depth, sky and object masks)
    of ``scene`` at ``config``'s training size, and the haze of each weather's physics (``physics``;
    the kind's default weather where it has none); ``show_progress``: count the edited frames (the
    physical editor's) on stderr.

    Raises
    ------
    InputError
        On a malformed ``supervision`` or a folder that does not exist.
    """
    size = config.size_for(scene.image_size)
    physics = dict(physics) if physics is not None else resolve_physics(scene, "presets")
    frames, sup_record = supervision_frames(scene, supervision, weathers, jitter, config.seed, physics=physics,
                                             size=size, show_progress=show_progress)
    trained = ("clear", *[w for w in weathers if w in frames])
    views, view_facts = build_views(scene, size=size, supervision={w: frames[w] for w in trained if w != "clear"},
                                    solid=config.opacity_lidar > 0 or config.lidar_fill,
                                    anchors=config.lidar_fill)
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
    log: Any = None,
    lock_timeout_s: float | None = LOCK_TIMEOUT_S,
    device: str = "cpu",
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
        Where the checkpoint goes; default the cache folder ``weathercity/<data folder>-<key>``, keyed by
        the scene's data, not by its name in the run.
    store : ModelStore, optional
        Where the VGG16 weights of the content loss come from.
    content : ContentLoss, None or "auto"
        The content loss to use (tests inject a small network); ``"auto"``: the real VGG16 when
        installed, else the term is skipped and the reason recorded.
    show_progress : bool
    log : callable, optional
        Where one-line phase messages go (default: printed to stdout at once, flushed, since a pipe
        or a file would otherwise hold them back until the training ends).
    lock_timeout_s : float or None
        Seconds to wait while another process trains the same model (the same request, then the
        same checkpoint folder: each wait apart) before giving up; ``None``: no limit. The waiting
        process then loads that model.
    device : {"cpu", "cuda"}
        Where the training step runs (:mod:`wcbench.reference_model.devices`); checked before any
        work. A model trained elsewhere than the CPU is keyed apart (gsplat's float rounding differs)
        and returned on the CPU, where the renderer's particles and fog are.

    Returns
    -------
    model : WeatherCityModel
    views : list of TrainingView
        Every frame's view (held-out frames included). When the model was loaded by its request
        (see below), the views carry the raw frames only, not the supervision's.
    facts : dict
        What was built, skipped and measured (``info.json``).

    Raises
    ------
    LockTimeoutError
        When another process still trains the same model after ``lock_timeout_s``.
    InputError
        ``device`` cannot be used here (no CUDA device, gsplat missing).

    Notes
    -----
    Two keys (docs/design.md §9, "One training per model"). The *model key* is over everything that
    makes the model, the supervision's record and the code's source included, so it is known only
    once the supervision is made (a minute of editing on the quick profile). The *request key* is
    over what the caller asks for, known at once: every file of the scene's folder, the settings,
    the supervision's spec, the physics, the content loss and the code's source. The request is
    locked first, so a second process asking for the same model waits before any work; a finished
    training leaves a record of its request (model key, checkpoint, facts), and a request made
    again, by the waiting process or a later run, loads that checkpoint without editing again. Only
    supervision the code makes from the scene is taken from a record; a folder of frames
    (``READER:DIR``) can change under the same spec, so its frames are read and the model key
    computed each time.
    """
    problem = device_problem(device)
    if problem is not None:
        raise InputError(f"--device {device}: {problem}")
    start = time.perf_counter()
    if log is None:
        log = functools.partial(print, flush=True)
    size = config.size_for(scene.image_size)
    log(f"weathercity {scene.id}: {size[0]}x{size[1]} views, supervision from {supervision}")
    physics = dict(physics) if physics is not None else resolve_physics(scene, "presets")
    if isinstance(content, str):
        if content != "auto":
            raise ValueError(f"content must be a ContentLoss, None or 'auto', got {content!r}")
        content_note = _content_note(config, store)
    else:
        content_note = "injected" if content is not None else "off"
    data = Path(scene.root).resolve().name
    request = sha256_json({"version": VERSION, "scene": data, "files": _folder_digest(Path(scene.root)),
                           "config": config.to_json(), "supervision": supervision, "jitter": jitter,
                           "weathers": list(weathers), "physics": {w: p.to_json() for w, p in physics.items()},
                           "content": content_note, "code": _source_digest(),
                           "folder": None if folder is None else str(Path(folder).resolve()),
                           **({"device": device} if device != "cpu" else {})})
    requests = cache_dir() / "weathercity" / "requests"
    record_path = requests / f"{data}-{request[:16]}.json"
    say = functools.partial(_prefixed, log, f"weathercity {scene.id}: ")
    with EntryLock(requests / f"{data}-{request[:16]}.lock", what=f"training {scene.id}",
                   timeout_s=lock_timeout_s, log=say) as asked:
        loaded = _load_requested(scene, config, record_path) if _made_by_code(supervision) else None
        if loaded is not None:
            model, views, facts = loaded
            log(f"weathercity {scene.id}: loaded the model trained for this request ({facts['checkpoint']})")
            prep_s = time.perf_counter() - start - asked.waited_s
            facts.update(resumed_at=facts["iterations"], prepare_seconds=round(prep_s, 3),
                         lock_wait_seconds=round(asked.waited_s, 3))
            return model, views, facts
        if isinstance(content, str):
            content_loss, content_note = content_loss_for(config, store)
        else:
            content_loss = content
        model, views, facts = _train(scene, config, supervision=supervision, jitter=jitter, weathers=weathers,
                                     physics=physics, folder=folder, content=(content_loss, content_note),
                                     show_progress=show_progress, log=log, say=say, lock_timeout_s=lock_timeout_s,
                                     start=start, waited_s=asked.waited_s, device=device)
        facts["request"] = request
        if _made_by_code(supervision) and facts["iterations"] >= config.iterations:
            atomic_write_json(record_path, {"request": request, "key": facts["key"], "facts": facts})
    return model, views, facts


def _prefixed(log: Any, prefix: str, message: str) -> None:
    log(prefix + message)


def _made_by_code(spec: str) -> bool:
    """Whether the supervision ``spec`` names frames this code makes from the scene (its request
    determines them), not a folder of another tool's frames (``READER:DIR``)."""
    return spec in (PHYSICAL_EDITOR, "filter2d") or supervision_severity(spec) is not None


def _folder_digest(root: Path) -> list[list[str]]:
    """[relative path, sha256] of every file under ``root``, sorted: the scene's data by content."""
    return sorted([p.relative_to(root).as_posix(), sha256_file(p)] for p in root.rglob("*") if p.is_file())


@functools.cache
def _source_digest() -> str:
    """sha256 over the code of the harness and the reference model (not its comments or docstrings,
    :func:`~wcbench.core.code_digest.source_digest`): a request made again by other code may edit
    otherwise, and a model of other code trains otherwise, so neither its record nor its checkpoint
    is reused; a change of prose alone reuses both."""
    return sha256_json({pkg: source_digest(pkg) for pkg in ("wcbench", "wcbench.reference_model")})


def _load_requested(scene: Scene, config: TrainConfig, record_path: Path
                    ) -> tuple[WeatherCityModel, list[TrainingView], dict[str, Any]] | None:
    """The model a finished training left for this request (:func:`train_scene`'s Notes), or
    ``None`` when there is no record, or its checkpoint is gone, unfinished or of another key."""
    try:
        record = json.loads(record_path.read_text(encoding="utf-8"))
        facts = dict(record["facts"])
        folder = Path(facts["checkpoint"])
        info = read_checkpoint_info(folder)
    except (OSError, ValueError, KeyError, TypeError, InputError):  # no record, or one not to trust: train
        return None
    if info is None or info.get("key") != record["key"] or int(info["step"]) < config.iterations:
        return None
    # the views' raw frames, lidar and shipped sky masks build the model's structure; what the
    # supervision and a derived sky add to the build (the sky maps' warm start) the checkpoint replaces
    size = config.size_for(scene.image_size)
    views, _ = build_views(scene, size=size, derive_sky=False)
    train_views = [v for v in views if v.frame not in config.holdout]
    model, _ = build_model(scene, train_views, config, weathers=tuple(facts["trained_weathers"]))
    try:
        load_model(folder, model=model)
    except InputError:
        return None
    return model, views, facts


def _train(scene: Scene, config: TrainConfig, *, supervision: str, jitter: float, weathers: tuple[str, ...],
           physics: Mapping[str, Weather], folder: Path | None, content: tuple[ContentLoss | None, str],
           show_progress: bool, log: Any, say: Any, lock_timeout_s: float | None, start: float, waited_s: float,
           device: str) -> tuple[WeatherCityModel, list[TrainingView], dict[str, Any]]:
    """The supervision, views and scene graph of ``scene``, its model trained (or resumed, or loaded
    from the checkpoint of its model key): :func:`train_scene` without the request's record.
    ``start``: when the call began (``time.perf_counter``); ``waited_s``: seconds it waited before."""
    inputs = training_inputs(scene, config, supervision=supervision, jitter=jitter, weathers=weathers,
                             physics=physics, show_progress=show_progress)
    views, trained = inputs.views, inputs.trained
    content_loss, content_note = content
    made = {k: v for k, v in inputs.supervision.items() if k != "timings"}  # what makes the frames, not how fast
    # keyed by the scene's data (its folder's name, its files' content), not by the name a run gives it:
    # synth_1's scene is synth_3's first, one street trained once (docs/design.md §3, "Scene names")
    data = Path(scene.root).resolve().name
    key = sha256_json({"version": VERSION, "scene": data, "sources": inputs.sources, "config": config.to_json(),
                       "supervision": made, "trained": trained, "content": content_note,
                       "hazes": {w: h.to_json() for w, h in inputs.hazes.items()},
                       # by content, as the images: one scene reached by two spellings of its path trains once
                       "lidar": [sha256_file(f.lidar_path) if f.lidar_path is not None else None
                                 for f in scene.frames],
                       # the code that builds and trains it: a checkpoint of other code is neither loaded nor
                       # resumed, so a model trained before an update is never taken for today's
                       "code": _source_digest(),
                       # only off the CPU, so that every CPU key stays what it was
                       **({"device": device} if device != "cpu" else {})})
    folder = folder or cache_dir() / "weathercity" / f"{data}-{key[:16]}"
    log(f"weathercity {scene.id}: building the scene graph")
    train_views = [v for v in views if v.frame not in config.holdout]
    model, graph_facts = build_model(scene, train_views, config, weathers=trained)

    def make_trainer(m: WeatherCityModel) -> Trainer:
        return Trainer(m, views, config, content=content_loss, hazes=inputs.hazes, device=device)

    # One training per checkpoint, also between two requests that make the same model (the request's
    # lock is taken first, always in that order): a second process waits here, then loads what the
    # first saved (docs/guide.md "WeatherCity"; a killed holder's lock is taken over at once)
    entry = folder.resolve()
    lock = EntryLock(entry.with_name(f"{entry.name}.lock"), what=f"training {scene.id}", timeout_s=lock_timeout_s,
                     log=say)
    with lock:
        info = read_checkpoint_info(folder)
        if info is not None and info.get("key") == key:
            trainer = load_checkpoint(folder, model=model, views=views, make_trainer=make_trainer)
            resumed = trainer.step_index
        else:
            trainer, resumed = make_trainer(model), 0
        prep_s = time.perf_counter() - start - waited_s - lock.waited_s
        if trainer.step_index < config.iterations:
            if resumed:
                log(f"weathercity {scene.id}: resuming at step {resumed} of {config.iterations}")
            # each kind of step (clear, weather, content loss, densification, checkpoint) is timed apart for
            # the time left; the first step compiles the kernels (up to a minute), hence the line before it
            bar = progress(range(trainer.step_index, config.iterations), desc=f"training {scene.id}",
                           total=config.iterations - trainer.step_index, enabled=show_progress, unit="step",
                           kinds=trainer.step_kinds(trainer.step_index, config.iterations),
                           weights=trainer.kind_weights(trainer.step_index, config.iterations),
                           # a long training (the paper's 30,000 steps: 2 % would be 600 steps) shows its time
                           # left after a handful of steps; the shorter profiles keep their 2 %
                           min_steady=5 if config.iterations - trainer.step_index > 10_000 else None,
                           starting=f"{config.iterations - trainer.step_index} steps; the first sets up and "
                                    "compiles the kernels (the time left comes once a few steps are measured)")
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
    if device != "cpu":
        model.to("cpu")  # the renderer's particles and fog are numpy; it rasterizes on the device itself
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
        "lock_wait_seconds": round(waited_s + lock.waited_s, 3),  # while another process trained this model
        "densify": trainer.densify_log[-1] if trainer.densify_log else None,
    }
    if device != "cpu":
        facts["device"] = device
    if held:
        facts["holdout"] = evaluate_views(model, held)
    return model, views, facts
