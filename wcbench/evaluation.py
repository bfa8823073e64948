"""Scoring a method's frames from files alone (``wcbench evaluate``), after rendering them (``wcbench run``).

:func:`evaluate` checks names and the output folder, plans one :class:`~wcbench.units.WorkUnit`
per (scene, weather), renders the units of a runnable method when asked (``run``), opens and
checks every prediction before any result is written, scores each unit or reuses its kept result
(through an executor, :mod:`wcbench.execution`: in this process or on a Dask cluster), then
writes ``results.csv`` and ``results.json`` last, atomically. An existing ``results.json`` for
other inputs is never replaced without ``overwrite=True``. Every method of a scene is scored at
one size, the scene's working size, whatever size it rendered at (``config.scored_at``; see
:data:`~wcbench.units.SCORING_RULE`), so the numbers of methods scored separately compare.

Each scene's predictions folder is found by name (:func:`~wcbench.predictions.find_scene_folder`:
the scene id, its data folder's name or an alias, and reader patterns such as ``{scene}_*``), and
the match is recorded. A sequence shorter than the scene (a reader that declares its tool can end
early) is scored on its contiguous run of frames, so temporal metrics only compare neighbours, and
the missing frames are named in ``results.json`` (``partial``) and ``results.csv``. Frames of an
editing tool that all equal their source frames raise a warning (``warnings``, see
:mod:`wcbench.unedited`): the predictions folder is likely the tool's copy of its input.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from wcbench.core.environment import machine_info, package_versions
from wcbench.core.errors import InputError, ResultsExistError, UnknownNameError
from wcbench.core.locking import FolderLock
from wcbench.core.models.fetch import fetch_missing, is_offline
from wcbench.core.storage import (
    atomic_write_json,
    atomic_write_text,
    check_writable_folder,
    json_safe,
    sha256_file,
    sha256_json,
    sweep_temporary_files,
)
from wcbench.core.weathers import WEATHERS
from wcbench.core.working_size import METRIC_RESOLUTION, SizeRequest
from wcbench.execution import Executor
from wcbench.execution.local import LocalExecutor
from wcbench.methods import Method, canonical_method_name, get_method, is_runnable
from wcbench.metrics.base import Metric
from wcbench.metrics.registry import DEFAULT_METRICS, METRICS, create_metric, validate_metric_options
from wcbench.predictions import (
    RESIZE_INTERPOLATION,
    PredictionSequence,
    PredictionsMissingError,
    SceneFolder,
    find_scene_folder,
)
from wcbench.results import (
    RESULTS_CSV,
    RESULTS_JSON,
    SCHEMA_VERSION,
    is_intact,
    read_results,
    results_checksum,
    to_csv,
)
from wcbench.scenes.sets import normalized_scenes, resolve_scenes
from wcbench.units import SCORING_RULE, RenderSettings, Scoring, UnitResult, WorkUnit


@dataclass
class EvaluateConfig:
    """Everything ``wcbench evaluate`` needs.

    Attributes
    ----------
    method : str
        Registered method name (a reader or a runnable method's canonical layout).
    scenes : str
        Scene set name or scene folder path.
    predictions : Path
        Folder with the predictions (``<predictions>/<scene>/...``).
    out : Path
        Where ``results.json`` / ``results.csv`` go.
    weathers, metrics : list of str or None
        ``None``: every weather found in the predictions / :data:`DEFAULT_METRICS`.
    pattern : str or None
        File-name pattern overriding the reader's preset.
    resize : bool
        Resize predictions of another size to the scene's size.
    fps : float or None
        Frame rate to report when the predictions carry no timings.
    data_root : Path or None
        Folder holding the datasets (``--data-root``); ``None``: ``$WCBENCH_DATA``.
    overwrite : bool
        Replace finished results in ``out`` made from other inputs (``--overwrite``); without it
        they are refused.
    show_progress : bool
        Show progress feedback (``--no-progress`` turns it off).
    metric_options : dict
        Per-metric options, ``{metric: {key: value}}`` (``--metric-option METRIC.KEY=VALUE``).
    frame_offset : int
        The method's frame *i* is scene frame ``i + frame_offset``.
    render : RenderSettings or None
        Render the units first with the (runnable) method into ``predictions/<scene>/<weather>/``
        (``wcbench run``); ``None`` reads existing files (``wcbench evaluate``).
    metric_resolution : int or None
        Every unit of a scene is scored at the scene's working size: its frame size, area-downscaled
        so that the longer side is at most this many pixels
        (:func:`~wcbench.core.working_size.working_size`); ``None``: at the scene's own frame size.
        A method's frames of another size are resized to it (:data:`~wcbench.units.SCORING_RULE`).
    score_size : SizeRequest, optional
        Score at this size (``evaluate --scale`` or ``--width/--height``): predictions and scene
        frames are resized to it, and the working resolution does not apply.
    frames : tuple of int, optional
        Score only these scene frames (a contiguous run; ``--frames``); default every frame (a
        runnable method's render of some frames is scored on the frames it lists).
    prefetch_frames, share_frames : bool
        Decode frames in worker threads; keep decoded frames in memory (the raw frames for the
        scene's other units, the predictions from their check to their scoring)
        (:meth:`~wcbench.units.WorkUnit.score`; off only to measure what they save).
    offline : bool
        Fetch no missing weights (also ``$WCBENCH_OFFLINE``); by default the weights the metrics
        and the method need are fetched before the work starts (:mod:`wcbench.core.models.fetch`).
    """

    method: str
    scenes: str
    predictions: Path
    out: Path
    weathers: list[str] | None = None
    metrics: list[str] | None = None
    pattern: str | None = None
    resize: bool = False
    fps: float | None = None
    data_root: Path | None = None
    overwrite: bool = False
    show_progress: bool = True
    metric_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    frame_offset: int = 0
    render: RenderSettings | None = None
    metric_resolution: int | None = METRIC_RESOLUTION
    frames: tuple[int, ...] | None = None
    score_size: SizeRequest | None = None
    prefetch_frames: bool = True
    share_frames: bool = True
    offline: bool = False


@dataclass
class EvaluateOutcome:
    """What :func:`evaluate` did: ``status`` is ``"computed"`` or ``"up-to-date"``."""

    status: str
    results_path: Path
    results: dict[str, Any]
    units_computed: int = 0
    units_reused: int = 0


def _check_weathers(method: Method, weathers: list[str]) -> None:
    for w in weathers:
        if w not in WEATHERS:
            raise UnknownNameError("weather", w, WEATHERS)
        if w not in method.info.weathers:
            raise InputError(f"method {method.info.name!r} does not support weather {w!r} "
                             f"(supports {', '.join(method.info.weathers)})")


def check_metrics(cfg: EvaluateConfig) -> tuple[list[str], dict[str, dict[str, Any]]]:
    """The metrics ``cfg`` computes and their options, checked before anything is created, fetched
    or written: every name is registered, every option is one its metric declares, with a value it
    allows (:func:`~wcbench.metrics.registry.validate_metric_options`), and is given to a metric
    that is computed.

    Returns
    -------
    names : list of str
        ``cfg.metrics`` (default :data:`DEFAULT_METRICS`) without repeats.
    options : dict
        ``{metric: {key: value}}`` as the constructors take them.

    Raises
    ------
    UnknownNameError, OptionError, InputError
        In one line: an unknown metric; an option a metric does not take, or not with that value
        (naming metric, option, value and what is allowed); options for a metric not computed.
    """
    names = list(dict.fromkeys(cfg.metrics or DEFAULT_METRICS))
    for n in names:
        if n not in METRICS:
            raise UnknownNameError("metric", n, METRICS.names())
    stray = sorted(set(cfg.metric_options) - set(names))
    if stray:
        raise InputError(f"options given for metrics that are not computed: {', '.join(stray)} "
                         f"(computed: {', '.join(names)})")
    return names, {n: validate_metric_options(n, opts) for n, opts in cfg.metric_options.items()}


def _metric_config(names: list[str], options: dict[str, dict[str, Any]], *, method: Method,
                   offline: bool) -> tuple[dict[str, Metric], dict, dict[str, Any]]:
    """The metrics, their configs and the record of the weights they and ``method`` need, fetched
    first where missing (the configs carry the weights' sha256, so they come after the fetch)."""
    metrics = {n: create_metric(n, **options.get(n, {})) for n in names}
    needed = {name for m in metrics.values() for name in m.required_models()}
    needed |= set(getattr(method, "required_models", tuple)())
    fetched = fetch_missing(needed, offline=is_offline(offline))
    models = {name: outcome.record() for name, outcome in fetched.items()}
    return metrics, {n: {"class": type(m).__qualname__, "config": m.config()} for n, m in metrics.items()}, models


def scene_folders(cfg: EvaluateConfig, method: Method) -> dict[str, SceneFolder]:
    """The predictions folder of every scene of ``cfg.scenes`` (see :func:`find_scene_folder`).

    Raises
    ------
    InputError
        A scene has no folder or several candidates, or two scenes match one folder.
    """
    refs = resolve_scenes(cfg.scenes, data_root=cfg.data_root)
    folders = {ref.id: find_scene_folder(cfg.predictions, ref, n_scenes=len(refs),
                                         folder_patterns=method.info.scene_folders) for ref in refs}
    claimed: dict[Path, list[str]] = {}
    for f in folders.values():
        claimed.setdefault(f.path, []).append(f.scene_id)
    shared = {p: ids for p, ids in claimed.items() if len(ids) > 1}
    if shared:
        listing = "\n".join(f"  {p}: {', '.join(ids)}" for p, ids in shared.items())
        raise InputError(f"{cfg.predictions}: one folder matches several scenes:\n{listing}")
    return folders


def _plan_units(cfg: EvaluateConfig, method: Method, folders: dict[str, SceneFolder] | None) -> list[list[WorkUnit]]:
    """The units of every scene (scenes loaded, predictions not yet opened), grouped by scene.

    ``folders`` maps scene ids to another tool's prediction folders; ``None`` when wcbench renders
    the predictions itself into the canonical layout (one folder per scene).
    """
    refs = resolve_scenes(cfg.scenes, data_root=cfg.data_root)
    weathers = cfg.weathers or list(method.info.weathers)
    plan = []
    for ref in refs:
        scene = ref.load()
        root = cfg.predictions / scene.id if folders is None else folders[ref.id].path
        source_hashes = [sha256_file(f.image_path) for f in scene.frames]
        plan.append([WorkUnit(method, scene, w, root, source_hashes, scene_ref=ref,
                              check_unedited=method.info.edits_source and w != "clear") for w in weathers])
    return plan


def _open_units(cfg: EvaluateConfig, plan: list[list[WorkUnit]]) -> list[WorkUnit]:
    """Open every unit's predictions; weathers without any predictions are dropped unless asked for.

    Raises
    ------
    InputError
        Naming, per scene, every weather whose predictions do not match the scene.
    """
    units: list[WorkUnit] = []
    single_weather = cfg.weathers is not None and len(cfg.weathers) == 1
    for scene_units in plan:
        scene = scene_units[0].scene
        opened: dict[str, PredictionSequence] = {}
        errors: dict[str, InputError] = {}
        for u in scene_units:
            try:
                opened[u.weather] = u.open(pattern=cfg.pattern, resize=cfg.resize, frame_offset=cfg.frame_offset,
                                           single_weather=single_weather, frames=cfg.frames)
            except PredictionsMissingError as exc:
                if cfg.weathers:  # asked for explicitly: its absence is an error
                    errors[u.weather] = exc
            except InputError as exc:
                errors[u.weather] = exc
        if errors:
            lines = [f"  {w}: {len(p)} frames found" + (f" (missing {p.missing})" if p.missing else "")
                     for w, p in opened.items()]
            lines += [f"  {w}: {e}" for w, e in errors.items()]
            what = "frame counts differ across weathers" if opened else "predictions do not match the scene"
            raise InputError(f"scene {scene.id!r} ({len(scene)} frames): {what}:\n" + "\n".join(lines))
        if not opened:
            root, weathers = scene_units[0].root, [u.weather for u in scene_units]
            raise InputError(
                f"{root}: predictions folder holds no frames for any of the weathers {weathers} of method "
                f"{scene_units[0].method.info.name!r} (expected e.g. {root}/{weathers[0]}/000.png; "
                "see `wcbench methods list -v`)"
            )
        units += [u for u in scene_units if u.weather in opened]
    return units


def _scored_at(cfg: EvaluateConfig, units: list[WorkUnit]) -> dict[str, Any]:
    """The size each scene's frames are scored at and the rule that chose it (``results.json``
    ``config.scored_at``): ``{"rule": SCORING_RULE or "asked", "sizes": {scene: [w, h]}}``.

    Part of the inputs' hash, so results scored under an earlier rule (a method at its own render
    size) are never taken as up to date.
    """
    sizes = {u.scene.id: list(u.scored_size(cfg.metric_resolution, cfg.score_size)) for u in units}
    return {"rule": SCORING_RULE if cfg.score_size is None else "asked", "sizes": dict(sorted(sizes.items()))}


def _config_record(cfg: EvaluateConfig, method: Method, units: list[WorkUnit], metric_cfg: dict,
                   folders: dict[str, SceneFolder] | None) -> dict[str, Any]:
    return {
        "method": method.info.name, "method_kind": method.info.kind, "scenes": cfg.scenes,
        "scene_ids": sorted({u.scene.id for u in units}), "weathers": sorted({u.weather for u in units}),
        "metrics": sorted(metric_cfg), "metric_config": metric_cfg, "predictions": str(cfg.predictions),
        "pattern": cfg.pattern, "resize": cfg.resize, "resize_interpolation": RESIZE_INTERPOLATION,
        "frame_offset": cfg.frame_offset, "fps": cfg.fps, "reader": method.info.defaults,
        "metric_resolution": cfg.metric_resolution, "frames": None if cfg.frames is None else list(cfg.frames),
        "score_size": None if cfg.score_size is None else cfg.score_size.to_json(),
        "scored_at": _scored_at(cfg, units),
        "unedited_check": method.info.edits_source,
        "scene_folders": {sid: f.record() for sid, f in sorted((folders or {}).items())},
    }


def _portable_path(path: Path, out: Path) -> str:
    """``path`` relative to ``out`` when inside it (a results folder stays whole when moved), else absolute."""
    path, out = path.resolve(), out.resolve()
    return path.relative_to(out).as_posix() if path.is_relative_to(out) else str(path)


def _input_files(units: list[WorkUnit], out: Path) -> dict[str, Any]:
    """Paths of the files ``inputs.scenes`` hashes, and each scene's frame size, so that reports can
    show frames from the result files alone: ``{scene: {"root", "size": [w, h], "source": [...],
    "weathers": {weather: {"predictions": [...], "reference": [...] or None}}}}``."""
    files: dict[str, Any] = {}
    for u in units:
        assert u.predictions is not None
        rec = files.setdefault(u.scene.id, {
            "root": str(Path(u.scene.root).resolve()), "size": list(u.scene.image_size),
            "source": [_portable_path(f.image_path, out) for f in u.scene.frames], "weathers": {},
        })
        rec["weathers"][u.weather] = {
            "predictions": [_portable_path(p, out) for p in u.predictions.files],
            "reference": None if u.reference_paths is None else [_portable_path(p, out) for p in u.reference_paths],
        }
    return files


def check_out_folder(
    cfg: EvaluateConfig, *, method: Method | None = None
) -> tuple[Method, list[str], dict[str, Any] | None]:
    """Check names and the output folder before any work.

    Returns the method, the metric names and the finished results already in ``cfg.out`` (if
    any and ``cfg.overwrite`` is false).

    Raises
    ------
    UnknownNameError, InputError
        Unknown method, weather or metric, or a metric option it does not allow (:func:`check_metrics`);
        ``cfg.out`` holds results of another schema version.
    ResultsExistError
        ``cfg.out`` holds finished results for another method, scene set, weathers or metrics.
    """
    method = method if method is not None else get_method(cfg.method)
    metric_names, _ = check_metrics(cfg)
    if cfg.weathers:
        _check_weathers(method, cfg.weathers)
    results_path = cfg.out / RESULTS_JSON
    previous = read_results(results_path) if results_path.is_file() and not cfg.overwrite else None
    if previous is not None:
        old = previous.get("config", {})
        differs = [(what, was, now) for what, was, now in (
            # results written under a method's old name (lidar_init) are that method's
            ("method", canonical_method_name(old["method"]) if isinstance(old.get("method"), str) else None,
             method.info.name),
            ("scenes", old.get("scenes"), cfg.scenes),
            ("metrics", sorted(old.get("metrics", [])), sorted(metric_names)),
            ("weathers", sorted(old.get("weathers", [])), None if cfg.weathers is None else sorted(cfg.weathers)),
        ) if now is not None and was != now]
        if differs:
            def show(v: Any) -> str:
                return ",".join(map(str, v)) if isinstance(v, list) else str(v)

            what = "; ".join(f"{name} {show(was)} there, {show(now)} asked" for name, was, now in differs)
            raise ResultsExistError(
                f"{results_path}: finished results of another configuration ({old.get('method')} on "
                f"{old.get('scenes')}: {what}) are there; pass --overwrite to replace them or choose another --out"
            )
    return method, metric_names, previous


def evaluate(cfg: EvaluateConfig, *, method: Method | None = None, executor: Executor | None = None) -> EvaluateOutcome:
    """Score ``cfg.method``'s predictions (rendering them first when ``cfg.render`` is set) and write
    ``results.json`` and ``results.csv``.

    Parameters
    ----------
    cfg : EvaluateConfig
    method : Method, optional
        The method object to use (e.g. a runnable method configured with options); default
        ``get_method(cfg.method)``.
    executor : Executor, optional
        Where the units render and score (:mod:`wcbench.execution`); default the local executor.
        Every executor gives the same ``results.json`` numbers.

    Raises
    ------
    WcbenchError
        Any bad input (unknown names, missing or extra frames, corrupt images, wrong sizes...),
        before any result is written; :class:`ResultsExistError` when ``cfg.out`` holds finished
        results of other inputs and ``cfg.overwrite`` is false. A distributed executor reports the
        units that failed (:class:`~wcbench.execution.UnitsFailedError`) after the others finish.
    """
    executor = executor or LocalExecutor()
    # the metrics and their options first: a bad one is refused before any folder is made or weight fetched
    _, metric_options = check_metrics(cfg)
    # paths resolved once: the same folder given relative or absolute is the same input
    cfg = replace(cfg, predictions=cfg.predictions.resolve(), out=cfg.out.resolve(),
                  scenes=normalized_scenes(cfg.scenes), metric_options=metric_options)
    check_writable_folder(cfg.out)
    with FolderLock(cfg.out):  # one run per output folder; results are checked under the lock
        sweep_temporary_files(cfg.out)  # what a killed run was writing when it died
        return _evaluate_locked(cfg, method, executor)


def _evaluate_locked(cfg: EvaluateConfig, method: Method | None, executor: Executor) -> EvaluateOutcome:
    method, metric_names, previous = check_out_folder(cfg, method=method)
    results_path = cfg.out / RESULTS_JSON
    metrics, metric_cfg, models = _metric_config(metric_names, cfg.metric_options, method=method,
                                                 offline=cfg.offline)
    folders = None if cfg.render is not None else scene_folders(cfg, method)
    plan = _plan_units(cfg, method, folders)
    if cfg.render is not None:
        for unit in (u for scene_units in plan for u in scene_units):  # every unit can run: nothing written yet
            if is_runnable(unit.method):  # a reader is refused by name when its render is asked for
                unit.method.check_scene(unit.scene, unit.weather)  # type: ignore[attr-defined]
                # the physics it will render, resolved with the run's seed (FrameRenderer.physics): a seed
                # it may not draw with (the truth's own particles) stops the run here, before any training
                physics = getattr(unit.method, "physics", None)
                if callable(physics):
                    physics(unit.scene, unit.weather, seed=cfg.render.seed)
        executor.render(plan, cfg.render)
    units = _open_units(cfg, plan)
    config = _config_record(cfg, method, units, metric_cfg, folders)
    inputs: dict[str, Any] = {"scenes": {}}
    for u in units:
        inputs["scenes"].setdefault(u.scene.id, {})[u.weather] = u.inputs()
    inputs["sha256"] = sha256_json({"inputs": inputs["scenes"], "config": config})
    inputs["files"] = _input_files(units, cfg.out)  # where the hashed files were (not part of the hash)
    if previous is not None:
        if previous.get("inputs", {}).get("sha256") == inputs["sha256"]:
            if is_intact(previous):
                return EvaluateOutcome("up-to-date", results_path, previous, 0, len(units))
            # same inputs, but the file was edited after it was written: rebuilt from the unit files
        else:
            raise ResultsExistError(
                f"{results_path}: finished results of other inputs or settings are there; "
                "pass --overwrite to replace them or choose another --out"
            )
    scoring = Scoring(cfg.out, metrics, metric_cfg, fps=cfg.fps, resolution=cfg.metric_resolution,
                      score_size=cfg.score_size, prefetch_frames=cfg.prefetch_frames, share_frames=cfg.share_frames,
                      show_progress=cfg.show_progress)
    outcomes = executor.score(units, scoring, [scoring.key(u) for u in units])
    computed = sum(o.computed for o in outcomes)
    facts = {u.scene.id: u.scene.facts for u in units if u.scene.facts}
    doc = assemble_results(config, inputs, outcomes, models=models, scene_facts=facts)
    atomic_write_text(cfg.out / RESULTS_CSV, to_csv(doc))
    atomic_write_json(results_path, doc)
    return EvaluateOutcome("computed", results_path, doc, computed, len(units) - computed)


def assemble_results(config: dict[str, Any], inputs: dict[str, Any], outcomes: list[UnitResult], *,
                     models: dict[str, Any] | None = None,
                     scene_facts: dict[str, dict[str, Any]] | None = None) -> dict[str, Any]:
    """The ``results.json`` document from finished units (see :mod:`wcbench.results` for the schema);
    ``models`` records the weights the run needed (sha256, verified, fetched in this run or why not),
    ``scene_facts`` what each scene's source says of it (:attr:`~wcbench.scenes.scene.Scene.facts`);
    a source scene that is not clear adds a ``source_weather`` warning."""
    results: dict[str, Any] = {}
    skipped: list[dict[str, Any]] = []
    partial: list[dict[str, Any]] = []
    warnings: list[dict[str, Any]] = []
    resized: list[dict[str, Any]] = []
    working: list[dict[str, Any]] = []
    raw_frames: dict[str, Any] = {}
    for o in outcomes:
        rec = o.result
        results.setdefault(o.unit.scene.id, {})[o.unit.weather] = rec["outputs"]
        skipped += rec["skipped"]
        warnings += rec.get("warnings", [])
        partial += [rec["partial"]] if "partial" in rec else []
        resized += [rec["resized"]] if "resized" in rec else []
        working += [rec["working_size"]] if "working_size" in rec else []
        if rec.get("raw_frames"):
            raw_frames.setdefault(o.unit.scene.id, {})[o.unit.weather] = rec["raw_frames"]
    doc: dict[str, Any] = json_safe({
        "kind": "wcbench-results", "schema_version": SCHEMA_VERSION,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "versions": package_versions(), "machine": machine_info(), "config": config,
        "inputs": inputs, "results": results, "skipped": skipped, "partial": partial, "resized": resized,
        "warnings": warnings, "working_size": working, "models": models or {}, "scene_facts": scene_facts or {},
        "raw_frames": raw_frames,
    })
    for sid, facts in sorted((scene_facts or {}).items()):
        if facts.get("source_weather_flag"):
            doc["warnings"].append({"scene": sid, "weather": "clear", "kind": "source_weather",
                                    "message": str(facts["source_weather_flag"])})
    doc["checksum"] = results_checksum(doc)
    return doc


def summarize(results: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    """(scene, weather, output, value text) rows for the terminal, of every output computed (the
    skipped metrics are summarised by :func:`skipped_causes`)."""
    rows = []
    for scene, weathers in results["results"].items():
        for weather, outputs in weathers.items():
            for name, r in sorted(outputs.items()):
                text = f"{r['value']:.6g}" if r["value"] is not None else f"null ({r['reason']})"
                rows.append((scene, weather, name, text))
    return sorted(rows)


def skipped_causes(results: dict[str, Any]) -> list[tuple[str, list[str], int]]:
    """The skipped metrics grouped by reason: (reason, metric names, rows skipped for it), most rows
    first. One reason (missing weights, say, naming the command that installs them) is said once,
    not once per scene and weather."""
    groups: dict[str, tuple[set[str], list[int]]] = {}
    for s in results["skipped"]:
        names, count = groups.setdefault(s["reason"], (set(), [0]))
        names.add(s["metric"])
        count[0] += 1
    causes = [(reason, sorted(names), count[0]) for reason, (names, count) in groups.items()]
    return sorted(causes, key=lambda c: (-c[2], c[0]))
