"""Build the HTML report (and its CSV / LaTeX tables) from results folders alone.

``build_report(["runs/a", "runs/b"], "report.html", csv=True, latex=True)`` reads each folder's
``results.json`` and ``results.csv``, merges the methods, flags what must not be mixed, and writes
one self-contained HTML file: inline CSS, images as ``data:`` URIs, no request to any network.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from wcbench.core.environment import package_versions
from wcbench.core.errors import InputError
from wcbench.core.storage import atomic_write_text

from .checks import MARKERS, Flag, mismatch_flags, weight_flags, weights_status
from .loading import ResultsFolder, assign_labels, load_results_folder
from .media import (
    ANIMATION_FRAMES,
    ANIMATION_SIZE,
    STRIP_SIZE,
    FrameRef,
    Picture,
    animation,
    animation_indices,
    bench_figure,
    jpeg,
    load_frames,
    method_color,
    per_frame_figure,
)
from .tables import Display, Table, TableBuilder, to_csv, to_latex

_TEMPLATES = Path(__file__).with_name("templates")
BENCH_SCHEMA = "wcbench-benchmark"  # wcbench/bench/schema.py SCHEMA / SCHEMA_VERSION
BENCH_SCHEMA_VERSION = 1
#: Packages whose versions are listed under provenance besides those the results recorded.
_REPORT_PACKAGES = ("jinja2", "matplotlib")


@dataclass
class Shot:
    """One picture slot of a strip or animation row: a picture or the reason there is none."""

    label: str
    picture: Picture | None
    reason: str = ""
    note: str = ""


@dataclass
class SceneWeather:
    """Frames and curves of one (scene, weather)."""

    scene: str
    weather: str
    frame_index: int | None
    strip: list[Shot] = field(default_factory=list)
    animations: list[Shot] = field(default_factory=list)
    curves: Picture | None = None


@dataclass
class ReportOutcome:
    """What :func:`build_report` wrote.

    Attributes
    ----------
    html : Path
    csv, latex : Path or None
    size_bytes : int
        Size of the HTML file.
    n_images : int
        Inlined pictures.
    seconds : float
        Build time (wall clock).
    tables : list of Table
    flags : list of Flag
    """

    html: Path
    csv: Path | None
    latex: Path | None
    size_bytes: int
    n_images: int
    seconds: float
    tables: list[Table]
    flags: list[Flag]


def _load_folders(results_dirs: Sequence[str | os.PathLike[str]]) -> list[ResultsFolder]:
    if not results_dirs:
        raise InputError("no results folder given (pass one or more --out folders of `wcbench run`/`evaluate`)")
    folders = [load_results_folder(Path(p)) for p in results_dirs]
    seen: dict[Path, int] = {}
    for f in folders:
        real = f.path.resolve()
        if real in seen:
            raise InputError(f"{f.path}: the same results folder was given twice")
        seen[real] = 1
    assign_labels(folders)
    return folders


def _folders_for(folders: list[ResultsFolder], label: str, scene: str, weather: str) -> ResultsFolder | None:
    for f in folders:
        if f.label == label and weather in f.doc["results"].get(scene, {}):
            return f
    return None


def _refs(folder: ResultsFolder, scene: str, weather: str, kind: str, indices: list[int]) -> list[FrameRef] | str:
    """Frame references of ``indices`` or why there are none."""
    paths = folder.file_paths(scene, weather, kind)
    hashes = folder.hashes(scene, weather, kind)
    if paths is None:
        return f"{folder.path}: results do not record where the {kind} frames are (older wcbench)"
    if len(paths) == 1 and hashes and len(hashes) == 1 and max(indices, default=0) > 0:
        return f"{paths[0].name}: frames inside a video are not shown"
    if any(k >= len(paths) for k in indices):
        return f"{kind} has {len(paths)} frames, fewer than frame {max(indices)}"
    return [FrameRef(paths[k], hashes[k] if hashes and k < len(hashes) else None) for k in indices]


class _MediaBuilder:
    """Strips, animations and curves per (scene, weather)."""

    def __init__(self, folders: list[ResultsFolder], methods: list[str], display: Display, *,
                 animation_frames: int, frames: bool):
        self.folders, self.methods, self.display = folders, methods, display
        self.animation_frames, self.frames = animation_frames, frames
        self.colors = {m: method_color(i) for i, m in enumerate(methods)}
        self.count = 0

    def _shot(self, label: str, refs: list[FrameRef] | str, size: tuple[int, int], *, animate: bool) -> Shot:
        if isinstance(refs, str):
            return Shot(label, None, refs)
        if not refs:
            return Shot(label, None, "no frames")
        loaded = load_frames(refs, size)
        bad = next((why for img, why in loaded if img is None), None)
        if bad is not None:
            return Shot(label, None, bad)
        imgs = [img for img, _ in loaded if img is not None]
        pic = animation(imgs) if animate else jpeg(imgs[0])
        self.count += 1
        note = f"frames {refs and refs[0].path.stem}..{refs[-1].path.stem}" if animate else refs[0].path.name
        return Shot(label, pic, note=note)

    def scene_weather(self, scene: str, weather: str) -> SceneWeather:
        have = [f for f in self.folders if weather in f.doc["results"].get(scene, {})]
        n = next((f.n_frames(scene, weather) for f in have if f.n_frames(scene, weather)), None) or 0
        mid = n // 2 if n else None
        item = SceneWeather(scene, weather, mid)
        if self.frames and mid is not None:
            anim_idx = animation_indices(n, self.animation_frames)
            for size, indices, target, animate in ((STRIP_SIZE, [mid], item.strip, False),
                                                   (ANIMATION_SIZE, anim_idx, item.animations, True)):
                if not indices:
                    continue
                source = Shot("raw", None, "no results folder records the raw frames' paths")
                for f in have:  # the first folder whose recorded raw frames are still there
                    source = self._shot("raw", _refs(f, scene, weather, "source", indices), size, animate=animate)
                    if source.picture is not None:
                        break
                target.append(source)
                for m in self.methods:
                    owner = _folders_for(self.folders, m, scene, weather)
                    if owner is None:
                        target.append(Shot(m, None, f"{m} was not scored on {scene} / {weather}"))
                    else:
                        target.append(self._shot(m, _refs(owner, scene, weather, "predictions", indices), size,
                                                 animate=animate))
                if not animate and weather != "clear":  # clear's ground truth is the raw frame itself
                    ref_folder = next((f for f in have if f.hashes(scene, weather, "reference")), None)
                    if ref_folder is not None:
                        target.append(self._shot("ground truth", _refs(ref_folder, scene, weather, "reference",
                                                                       indices), size, animate=False))
        item.curves = self._curves(scene, weather)
        return item

    def _curves(self, scene: str, weather: str) -> Picture | None:
        series: dict[str, dict[str, list[float | None]]] = {}
        hib: dict[str, bool] = {}
        for m in self.methods:
            f = _folders_for(self.folders, m, scene, weather)
            if f is None:
                continue
            for output, r in f.doc["results"][scene][weather].items():
                values = r.get("per_frame") or []
                if (len(values) >= 2 and self.display.group(output) != "runtime"
                        and any(v is not None for v in values)):
                    series.setdefault(output, {})[m] = values
                    hib[output] = bool(r.get("higher_is_better"))
        if not series:
            return None
        ordered = {o: series[o] for o in sorted(series, key=self.display.output_key)}
        labels = {o: f"{self.display.label(o)} {'↑' if hib[o] else '↓'}" for o in ordered}
        self.count += 1
        return per_frame_figure(ordered, labels=labels, colors=self.colors)


def _read_bench(path: Path) -> dict[str, Any]:
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable benchmark file ({exc})") from None
    if not isinstance(obj, dict) or (obj.get("schema"), obj.get("schema_version")) != (BENCH_SCHEMA,
                                                                                       BENCH_SCHEMA_VERSION):
        raise InputError(f"{path}: not a {BENCH_SCHEMA} v{BENCH_SCHEMA_VERSION} file (written by `wcbench bench SUITE "
                         "--out FILE`)")
    cases = obj.get("cases")
    if not isinstance(cases, list) or not all(isinstance(c, dict) and "knob" in c for c in cases):
        raise InputError(f"{path}: benchmark file without a list of cases with a knob")
    return obj


def _bench_sections(paths: Sequence[str | os.PathLike[str]]) -> list[dict[str, Any]]:
    sections = []
    for p in paths:
        obj = _read_bench(Path(p))
        knobs: dict[str, list[dict[str, Any]]] = {}
        for c in obj["cases"]:
            knobs.setdefault(str(c["knob"]), []).append(c)
        charts = []
        for knob, cases in knobs.items():
            pic = bench_figure(cases, knob=knob, suite=str(obj.get("suite")))
            charts.append({"knob": knob, "picture": pic, "cases": cases,
                           "defaults": [c.get("value") for c in cases if c.get("default") is True]})
        sections.append({"path": str(p), "suite": obj.get("suite"), "created": obj.get("created"),
                         "machine": obj.get("machine", {}), "notes": obj.get("notes", []), "charts": charts})
    return sections


def _train_seconds(info: dict[str, Any] | None) -> float | None:
    """Training time an ``info.json`` reports (``timings.train_s`` or ``train_s``, seconds)."""
    if not info:
        return None
    for value in ((info.get("timings") or {}).get("train_s"), info.get("train_s")):
        if isinstance(value, (int, float)):
            return float(value)
    return None


def _scoring_notes(folders: list[ResultsFolder]) -> list[str]:
    """Per scene where a method rendered at another size than the scene's frames: the size scored
    at and those methods' own sizes (``results.json`` ``working_size``), e.g. ``pandaset_002
    (1920x1080 frames) scored at 960x540; lidar-init's 480x270 frames resized to it``. Facts, not
    flags: every method of a scene is scored at one size by default (docs/design.md §8, "Scoring");
    sizes that differ are flagged by the checks."""
    frames: dict[str, str] = {}
    at: dict[str, set[str]] = {}
    resized: dict[str, dict[str, set[str]]] = {}
    for f in folders:
        for rec in f.doc.get("working_size") or []:
            if not (isinstance(rec, dict) and isinstance(rec.get("scene"), str)
                    and all(isinstance(rec.get(k), list) for k in ("from", "to", "predictions"))):
                continue
            scene, own = rec["scene"], "x".join(map(str, rec["predictions"]))
            frames.setdefault(scene, "x".join(map(str, rec["from"])))
            at.setdefault(scene, set()).add("x".join(map(str, rec["to"])))
            if rec.get("predictions_resized") and own != frames[scene]:
                resized.setdefault(scene, {}).setdefault(f.label, set()).add(own)
    notes = []
    for scene in sorted(resized):
        methods = ", ".join(f"{label}'s {'/'.join(sorted(v))}" for label, v in sorted(resized[scene].items()))
        notes.append(f"{scene} ({frames[scene]} frames) scored at {', '.join(sorted(at[scene]))}; {methods} "
                     "frames resized to it")
    return notes


def _runtime_facts(folders: list[ResultsFolder], methods: list[str]) -> list[dict[str, Any]]:
    rows = []
    for m in methods:
        res, machines, sources = set(), set(), set()
        frame_ms: list[float] = []
        train: list[float] = []
        for f in (f for f in folders if f.label == m):
            trained: dict[str, set[float]] = {}
            for scene, weathers in sorted(f.doc["results"].items()):
                for weather, outputs in sorted(weathers.items()):
                    fps = outputs.get("fps")
                    if fps and fps.get("value") is not None:
                        extra = fps.get("extra") or {}
                        if extra.get("resolution"):
                            res.add("x".join(str(v) for v in extra["resolution"]))
                        mach = extra.get("machine") or {}
                        if mach:
                            machines.add(f"{mach.get('cpu', '?')} ({mach.get('cores', '?')} cores)")
                        if isinstance(extra.get("median_frame_ms"), (int, float)):
                            frame_ms.append(float(extra["median_frame_ms"]))
                        sources.add(str(fps.get("variant", "")))
                    t = _train_seconds(f.info(scene, weather))
                    if t is not None:
                        trained.setdefault(scene, set()).add(t)
            # one model serves every weather of a scene: each distinct training time counts once
            train.extend(t for times in trained.values() for t in times)
        rows.append({
            "method": m,
            "frame_ms": f"{sorted(frame_ms)[len(frame_ms) // 2]:.1f}" if frame_ms else "",
            "resolution": ", ".join(sorted(res)),
            "train": f"{sum(train):.1f} s" if train else "",
            "machine": "; ".join(sorted(machines)),
            "source": "; ".join(sorted(s for s in sources if s)),
        })
    return rows


def _provenance(folders: list[ResultsFolder]) -> list[dict[str, Any]]:
    out = []
    for f in folders:
        doc = f.doc
        cfg = doc["config"]
        weights = []
        for metric, mcfg in sorted(cfg.get("metric_config", {}).items()):
            for w in weights_status(mcfg):
                weights.append({"metric": metric, **w})
        infos = []
        for scene, weather in f.units:
            info = f.info(scene, weather)
            if info:
                infos.append({
                    "unit": f"{scene} / {weather}", "version": info.get("version"), "seed": info.get("seed"),
                    "parameters": json.dumps(info.get("parameters", {}), indent=1, sort_keys=True),
                })
        hashes = []
        for scene, weathers in sorted(doc["inputs"].get("scenes", {}).items()):
            for weather, rec in sorted(weathers.items()):
                for kind in ("predictions", "source", "reference"):
                    for k, h in enumerate(rec.get(kind) or []):
                        hashes.append(f"{scene} {weather} {kind} {k:03d} {h}")
        out.append({
            "label": f.label, "path": str(f.path), "method": f.method, "created": doc.get("created"),
            "versions": doc.get("versions", {}), "machine": doc.get("machine", {}),
            "config": {k: v for k, v in cfg.items() if k != "metric_config"},
            "metric_config": json.dumps(cfg.get("metric_config", {}), indent=1, sort_keys=True),
            "variants": sorted({(o, str(r.get("variant", ""))) for ws in doc["results"].values()
                                for outs in ws.values() for o, r in outs.items()}),
            "weights": weights, "infos": infos, "inputs_sha256": doc["inputs"].get("sha256"), "hashes": hashes,
        })
    return out


def _environment() -> dict[str, Any]:
    versions: dict[str, Any] = dict(package_versions())
    for name in _REPORT_PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {"versions": versions, "host": platform.node()}


def build_report(
    results_dirs: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    title: str | None = None,
    bench: Sequence[str | os.PathLike[str]] = (),
    csv: bool = False,
    latex: bool = False,
    animation_frames: int = ANIMATION_FRAMES,
    frames: bool = True,
) -> ReportOutcome:
    """Build one self-contained HTML report from results folders.

    Parameters
    ----------
    results_dirs : sequence of path-like
        ``--out`` folders of ``wcbench run`` / ``wcbench evaluate`` (methods scored separately
        are merged; mismatches are flagged, never mixed silently).
    out : path-like
        The HTML file to write (atomically).
    title : str, optional
        Heading (default: the methods and scenes).
    bench : sequence of path-like
        Benchmark JSON files (``wcbench bench SUITE --out FILE``) charted as time vs error per knob.
    csv, latex : bool
        Also write ``out`` with suffix ``.csv`` / ``.tex``: every table cell as shown.
    animation_frames : int
        Frames per animated sequence (0 to 12; 0: no animations).
    frames : bool
        Include frame strips and animations (False: tables, curves and provenance only).

    Returns
    -------
    ReportOutcome

    Raises
    ------
    InputError
        A folder without results, a corrupt or foreign results file, a benchmark file of another
        schema, an out path that is a folder.
    """
    start = time.perf_counter()
    if not 0 <= animation_frames <= ANIMATION_FRAMES:
        raise InputError(f"animation frames must be in 0..{ANIMATION_FRAMES}, got {animation_frames}")
    out_path = Path(out)
    if out_path.is_dir():
        raise InputError(f"{out_path}: is a folder; give the report's file name, e.g. {out_path / 'report.html'}")
    folders = _load_folders(results_dirs)
    display = Display.load()
    tb = TableBuilder(folders, display)
    flags = weight_flags(folders, tb.outputs_of) + mismatch_flags(folders, tb.outputs_of)
    tb.flags = flags
    tables = tb.all_tables()
    bench_sections = _bench_sections(bench)
    media = _MediaBuilder(folders, tb.methods, display, animation_frames=animation_frames, frames=frames)
    weathers = sorted(set(tb.df["weather"]), key=display.weather_key)
    scenes = [(s, [media.scene_weather(s, w) for w in weathers
                   if any(w in f.doc["results"].get(s, {}) for f in folders)]) for s in tb.scenes]
    n_images = media.count + sum(1 for s in bench_sections for c in s["charts"] if c["picture"] is not None)

    import jinja2

    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(_TEMPLATES)), autoescape=True,
                             # a field older or foreign results lack renders empty instead of failing
                             undefined=jinja2.ChainableUndefined, trim_blocks=True, lstrip_blocks=True)
    env.filters["json"] = lambda v: json.dumps(v, sort_keys=True, default=str)
    html = env.get_template("report.html.j2").render(
        title=title or f"wcbench report: {', '.join(tb.methods)} on {', '.join(tb.scenes)}",
        built=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        environment=_environment(),
        css=(_TEMPLATES / "report.css").read_text(encoding="utf-8"),
        script=(_TEMPLATES / "report.js").read_text(encoding="utf-8"),
        folders=folders, methods=tb.methods, scenes_list=tb.scenes, weathers=weathers,
        colors=media.colors, flags=flags, markers=MARKERS, tables=tables, scoring=_scoring_notes(folders),
        skipped=tb.skipped_metrics(),
        runtime=_runtime_facts(folders, tb.methods), scenes=scenes, bench=bench_sections,
        provenance=_provenance(folders), display=display, frames=frames, animation_frames=animation_frames,
    )
    atomic_write_text(out_path, html)
    csv_path = latex_path = None
    if csv:
        csv_path = out_path.with_suffix(".csv")
        atomic_write_text(csv_path, to_csv(tables))
    if latex:
        latex_path = out_path.with_suffix(".tex")
        atomic_write_text(latex_path, to_latex(tables, source=", ".join(str(f.path) for f in folders)))
    return ReportOutcome(out_path, csv_path, latex_path, out_path.stat().st_size, n_images,
                         time.perf_counter() - start, tables, flags)
