"""``wcbench evaluate``: score a method's frames from files alone.

Work is split into units, one per (scene, weather). Each unit's result is stored in
``OUT/.work/<scene>/<weather>.json`` under a key made of the sha256 of every input file and the
metric settings, so a killed run resumes where it stopped and gives the same numbers, and a
re-run with unchanged inputs does no work. ``results.csv`` then ``results.json`` are written last,
atomically; an existing ``results.json`` for other inputs is never replaced without
``overwrite=True``.
"""

from __future__ import annotations

import datetime as _dt
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.environment import machine_info, package_versions
from wcbench.errors import InputError, ResultsExistError, UnknownNameError
from wcbench.image_io import read_rgb8, to_float
from wcbench.methods import WEATHERS, Method, get_method
from wcbench.metrics.base import Metric, MetricContext
from wcbench.metrics.registry import DEFAULT_METRICS, METRICS, create_metric
from wcbench.predictions import PredictionSequence, PredictionsMissingError, scene_prediction_root
from wcbench.progress import progress
from wcbench.results import RESULTS_CSV, RESULTS_JSON, SCHEMA_VERSION, read_results, to_csv
from wcbench.scene import Scene
from wcbench.scene_sets import resolve_scenes
from wcbench.storage import atomic_write_json, atomic_write_text, json_safe, sha256_file, sha256_json

WORK_DIR = ".work"
#: Frames handed to metrics per update: model metrics batch their inference; 8 frames of 1080p
#: in three float32 streams stay under 0.6 GB.
FRAME_BATCH = 8


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


@dataclass
class Unit:
    """One (scene, weather) to score, with the hashes of every input."""

    scene: Scene
    weather: str
    predictions: PredictionSequence
    pred_hashes: list[str]
    source_hashes: list[str]
    reference_paths: list[Path] | None
    reference_hashes: list[str] | None

    def key(self, metric_config: dict[str, Any]) -> str:
        """Cache key of this unit's result."""
        return sha256_json({
            "schema_version": SCHEMA_VERSION, "scene": self.scene.id, "weather": self.weather,
            "predictions": self.pred_hashes, "source": self.source_hashes, "reference": self.reference_hashes,
            "metrics": metric_config, "resize": self.predictions.resize,
        })


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


def _metric_config(names: list[str], options: dict[str, dict[str, Any]]) -> tuple[dict[str, Metric], dict]:
    metrics = {n: create_metric(n, **options.get(n, {})) for n in names}
    return metrics, {n: {"class": type(m).__qualname__, "config": m.config()} for n, m in metrics.items()}


def _open_units(cfg: EvaluateConfig, method: Method) -> list[Unit]:
    refs = resolve_scenes(cfg.scenes, data_root=cfg.data_root)
    units: list[Unit] = []
    for ref in refs:
        scene = ref.load()
        root = scene_prediction_root(cfg.predictions, scene.id, n_scenes=len(refs))
        weathers = cfg.weathers or list(method.info.weathers)
        opened: dict[str, PredictionSequence] = {}
        errors: dict[str, InputError] = {}
        for w in weathers:
            try:
                opened[w] = method.open_predictions(scene, w, root, pattern=cfg.pattern, resize=cfg.resize)
            except PredictionsMissingError as exc:
                if cfg.weathers:  # asked for explicitly: its absence is an error
                    errors[w] = exc
            except InputError as exc:
                errors[w] = exc
        if errors:
            lines = [f"  {w}: {len(p)} frames found" for w, p in opened.items()]
            lines += [f"  {w}: {e}" for w, e in errors.items()]
            what = "frame counts differ across weathers" if opened else "predictions do not match the scene"
            raise InputError(f"scene {scene.id!r} ({len(scene)} frames): {what}:\n" + "\n".join(lines))
        if not opened:
            raise InputError(
                f"{root}: predictions folder holds no frames for any of the weathers {weathers} of method "
                f"{method.info.name!r} (expected e.g. {root}/{weathers[0]}/000.png; see `wcbench methods list -v`)"
            )
        source_hashes = [sha256_file(f.image_path) for f in scene.frames]
        for w, preds in opened.items():
            ref_paths = scene.reference_paths(w)
            ref_hashes = None if ref_paths is None else (
                source_hashes if w == "clear" else [sha256_file(p) for p in ref_paths])
            units.append(Unit(scene, w, preds, preds.sha256s(), source_hashes, ref_paths, ref_hashes))
    return units


def _validate_frames(units: list[Unit], show_progress: bool) -> None:
    """Decode every prediction once before any result is written (size, bit depth, video length),
    so bad input fails before work starts and nothing is half-done."""
    for u in units:
        for _ in progress(u.predictions, desc=f"checking {u.scene.id} {u.weather}", total=len(u.predictions),
                          enabled=show_progress):
            pass


def _score_unit(unit: Unit, metrics: dict[str, Metric], ctx_extra: dict[str, Any], show_progress: bool) -> dict:
    scene = unit.scene
    ctx = MetricContext(
        weather=unit.weather, n_frames=len(scene), has_reference=unit.reference_paths is not None,
        has_source=True, method_info=unit.predictions.info, fps_override=ctx_extra.get("fps"),
    )
    active, skipped = {}, []
    for name, m in metrics.items():
        m.bind(ctx)
        reason = m.skip_reason(ctx)
        if reason:
            skipped.append({"scene": scene.id, "weather": unit.weather, "metric": name, "reason": reason})
        else:
            m.reset()
            active[name] = m
    needs_ref = unit.reference_paths is not None and any(m.needs_reference for m in active.values())
    frames = progress(enumerate(unit.predictions), desc=f"{scene.id} {unit.weather}", total=len(scene),
                      enabled=show_progress)
    # frames are converted straight into reused float32 batch buffers (no per-batch stacking)
    w, h = scene.image_size
    streams = ("pred", "source", "reference") if needs_ref else ("pred", "source")
    buffers = {name: np.empty((FRAME_BATCH, h, w, 3), np.float32) for name in streams}
    filled = 0

    def flush(n: int) -> None:
        if n == 0:
            return
        reference = buffers["reference"][:n] if needs_ref else None
        for m in active.values():
            m.update(buffers["pred"][:n], source=buffers["source"][:n], reference=reference)

    for k, pred8 in frames:
        to_float(pred8, out=buffers["pred"][filled])
        to_float(read_rgb8(scene.frames[k].image_path), out=buffers["source"][filled])
        if needs_ref:
            assert unit.reference_paths is not None
            if unit.weather == "clear":
                buffers["reference"][filled] = buffers["source"][filled]
            else:
                to_float(read_rgb8(unit.reference_paths[k]), out=buffers["reference"][filled])
        filled += 1
        if filled == FRAME_BATCH:
            flush(filled)
            filled = 0
    flush(filled)
    outputs: dict[str, Any] = {}
    for name, m in active.items():
        for out_name, value in m.compute().items():
            outputs[out_name] = {
                "metric": name, "value": value.value, "variant": value.variant, "reason": value.reason,
                "higher_is_better": m.higher_is_better, "per_frame": value.per_frame, "extra": value.extra,
            }
    return {"outputs": outputs, "skipped": skipped}


def _config_record(cfg: EvaluateConfig, method: Method, units: list[Unit], metric_cfg: dict) -> dict[str, Any]:
    return {
        "method": method.info.name, "method_kind": method.info.kind, "scenes": cfg.scenes,
        "scene_ids": sorted({u.scene.id for u in units}), "weathers": sorted({u.weather for u in units}),
        "metrics": sorted(metric_cfg), "metric_config": metric_cfg, "predictions": str(cfg.predictions),
        "pattern": cfg.pattern, "resize": cfg.resize, "fps": cfg.fps,
    }


def _portable_path(path: Path, out: Path) -> str:
    """``path`` relative to ``out`` when inside it (a results folder stays whole when moved), else absolute."""
    path, out = path.resolve(), out.resolve()
    return path.relative_to(out).as_posix() if path.is_relative_to(out) else str(path)


def _input_files(units: list[Unit], out: Path) -> dict[str, Any]:
    """Paths of the files ``inputs.scenes`` hashes, and each scene's frame size, so that reports can
    show frames from the result files alone: ``{scene: {"root", "size": [w, h], "source": [...],
    "weathers": {weather: {"predictions": [...], "reference": [...] or None}}}}``."""
    files: dict[str, Any] = {}
    for u in units:
        rec = files.setdefault(u.scene.id, {
            "root": str(Path(u.scene.root).resolve()), "size": list(u.scene.image_size),
            "source": [_portable_path(f.image_path, out) for f in u.scene.frames], "weathers": {},
        })
        rec["weathers"][u.weather] = {
            "predictions": [_portable_path(p, out) for p in u.predictions.files],
            "reference": None if u.reference_paths is None else [_portable_path(p, out) for p in u.reference_paths],
        }
    return files


def check_out_folder(cfg: EvaluateConfig) -> tuple[Method, list[str], dict[str, Any] | None]:
    """Check names and the output folder before any work.

    Returns the method, the metric names and the finished results already in ``cfg.out`` (if
    any and ``cfg.overwrite`` is false).

    Raises
    ------
    UnknownNameError, InputError
        Unknown method, weather or metric; ``cfg.out`` holds results of another schema version.
    ResultsExistError
        ``cfg.out`` holds finished results for another method, scene set, weathers or metrics.
    """
    method = get_method(cfg.method)
    metric_names = list(dict.fromkeys(cfg.metrics or DEFAULT_METRICS))
    for n in metric_names:
        if n not in METRICS:
            raise UnknownNameError("metric", n, METRICS.names())
    if cfg.weathers:
        _check_weathers(method, cfg.weathers)
    stray = sorted(set(cfg.metric_options) - set(metric_names))
    if stray:
        raise InputError(f"options given for metrics that are not computed: {', '.join(stray)} "
                         f"(computed: {', '.join(metric_names)})")
    results_path = cfg.out / RESULTS_JSON
    previous = read_results(results_path) if results_path.is_file() and not cfg.overwrite else None
    if previous is not None:
        old = previous.get("config", {})
        same = (old.get("method") == method.info.name and old.get("scenes") == cfg.scenes
                and sorted(old.get("metrics", [])) == sorted(metric_names)
                and (cfg.weathers is None or sorted(old.get("weathers", [])) == sorted(cfg.weathers)))
        if not same:
            raise ResultsExistError(
                f"{results_path}: finished results of another configuration ({old.get('method')} on "
                f"{old.get('scenes')}) are there; pass --overwrite to replace them or choose another --out"
            )
    return method, metric_names, previous


def evaluate(cfg: EvaluateConfig) -> EvaluateOutcome:
    """Score ``cfg.method``'s predictions and write ``results.json`` and ``results.csv``.

    Raises
    ------
    WcbenchError
        Any bad input (unknown names, missing or extra frames, corrupt images, wrong sizes...),
        before anything is written; :class:`ResultsExistError` when ``cfg.out`` holds finished
        results of other inputs and ``cfg.overwrite`` is false.
    """
    method, metric_names, previous = check_out_folder(cfg)
    results_path = cfg.out / RESULTS_JSON
    metrics, metric_cfg = _metric_config(metric_names, cfg.metric_options)
    units = _open_units(cfg, method)
    config = _config_record(cfg, method, units, metric_cfg)
    inputs: dict[str, Any] = {"scenes": {}}
    for u in units:
        inputs["scenes"].setdefault(u.scene.id, {})[u.weather] = {
            "predictions": u.pred_hashes, "source": u.source_hashes, "reference": u.reference_hashes}
    inputs["sha256"] = sha256_json({"inputs": inputs["scenes"], "config": config})
    inputs["files"] = _input_files(units, cfg.out)  # where the hashed files were (not part of the hash)
    if previous is not None:
        if previous.get("inputs", {}).get("sha256") == inputs["sha256"]:
            return EvaluateOutcome("up-to-date", results_path, previous, 0, len(units))
        raise ResultsExistError(
            f"{results_path}: finished results of other inputs or settings are there; "
            "pass --overwrite to replace them or choose another --out"
        )
    keys = {(u.scene.id, u.weather): u.key(metric_cfg) for u in units}
    cached: dict[tuple[str, str], dict] = {}
    for u in units:
        path = cfg.out / WORK_DIR / u.scene.id / f"{u.weather}.json"
        if path.is_file():
            try:
                rec = json.loads(path.read_text(encoding="utf-8"))
            except json.JSONDecodeError:
                continue  # never torn (atomic writes); a hand-edited file is simply recomputed
            if rec.get("key") == keys[(u.scene.id, u.weather)]:
                cached[(u.scene.id, u.weather)] = rec["result"]
    todo = [u for u in units if (u.scene.id, u.weather) not in cached]
    _validate_frames(todo, cfg.show_progress)
    computed = 0
    for u in todo:
        result = json_safe(_score_unit(u, metrics, {"fps": cfg.fps}, cfg.show_progress))
        atomic_write_json(cfg.out / WORK_DIR / u.scene.id / f"{u.weather}.json",
                          {"key": keys[(u.scene.id, u.weather)], "result": result})
        cached[(u.scene.id, u.weather)] = result
        computed += 1
    results: dict[str, Any] = {}
    skipped: list[dict[str, Any]] = []
    for u in units:
        rec = cached[(u.scene.id, u.weather)]
        results.setdefault(u.scene.id, {})[u.weather] = rec["outputs"]
        skipped += rec["skipped"]
    doc = {
        "kind": "wcbench-results", "schema_version": SCHEMA_VERSION,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "versions": package_versions(), "machine": machine_info(), "config": config,
        "inputs": inputs, "results": results, "skipped": skipped,
    }
    doc = json_safe(doc)
    atomic_write_text(cfg.out / RESULTS_CSV, to_csv(doc))
    atomic_write_json(results_path, doc)
    return EvaluateOutcome("computed", results_path, doc, computed, len(units) - computed)


def summarize(results: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    """(scene, weather, output, value text) rows for the terminal, skipped ones with their reason."""
    rows = []
    for scene, weathers in results["results"].items():
        for weather, outputs in weathers.items():
            for name, r in sorted(outputs.items()):
                text = f"{r['value']:.6g}" if r["value"] is not None else f"null ({r['reason']})"
                rows.append((scene, weather, name, text))
    for s in results["skipped"]:
        rows.append((s["scene"], s["weather"], s["metric"], f"skipped: {s['reason']}"))
    return sorted(rows)


def frames_as_array(seq: PredictionSequence) -> np.ndarray:
    """All frames of a sequence as float32 [T, H, W, 3] in [0, 1] (for small scenes and tests)."""
    return np.stack([to_float(f) for f in seq])
