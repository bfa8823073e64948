"""``wcbench bench report``: build time and size of the HTML report of 4 methods x 3 scenes x 4 weathers.

The results folders are synthetic (numbers drawn from a seeded generator, in the results.json /
results.csv format of ``wcbench/results.py``) with real PNG frames on disk: the report's work is
reading, checking and shrinking frames, which does not depend on where the numbers came from.
Source frames are pandaset_002's photos when the data root has them (shrunk to the benchmark's
frame size), else a procedural street.

Cases (``time_ms``: wall time of :func:`wcbench.reports.build_report`; ``error``: table cells
whose text differs from the results at the shown precision, so 0; ``size_mb`` beside it with the
issue's 20 MB target):

report_default      strips, 12-frame animations, curves (the default; ``default: true``)
report_stills       strips and curves, no animations (``--animation-frames 0``)
report_tables_only  no frames at all (``--no-frames``): tables, curves and provenance
"""

from __future__ import annotations

import html.parser
import json
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.bench.schema import BenchCase, BenchReport
from wcbench.core.environment import machine_info, package_versions
from wcbench.core.storage import atomic_write_json, atomic_write_text, sha256_file, sha256_json
from wcbench.results import RESULTS_CSV, RESULTS_JSON, SCHEMA_VERSION, to_csv

METHODS = ("tint", "haze", "grain", "streaks")
SCENES = ("scene_a", "scene_b", "scene_c")
WEATHERS = ("clear", "rain", "snow", "fog")
TARGET_MB = 20.0
#: (metric, output, higher_is_better, low, high, weathers it applies to, per-frame kind)
OUTPUTS: tuple[tuple[str, str, bool, float, float, tuple[str, ...], str], ...] = (
    ("clip_s", "clip_s", True, 0.70, 0.95, ("clear", "rain", "snow"), "frame"),
    ("clip_ds", "clip_ds", True, 0.05, 0.30, ("rain", "snow", "fog"), "frame"),
    ("clip_ds", "clip_ds_directional", True, 0.02, 0.25, ("rain", "snow", "fog"), "frame"),
    ("sem_cs", "sem_cs", True, 0.60, 0.95, ("clear", "rain", "snow"), "frame"),
    ("sem_cs", "sem_cs_pooled", True, 0.60, 0.95, ("clear", "rain", "snow"), "frame"),
    ("psnr", "psnr", True, 18.0, 32.0, ("clear",), "frame"),
    ("ssim", "ssim", True, 0.60, 0.95, ("clear",), "frame"),
    ("lpips", "lpips", False, 0.05, 0.40, ("clear",), "frame"),
    ("temporal_flicker", "temporal_flicker", False, 0.02, 0.08, WEATHERS, "pair"),
    ("temporal_flicker", "temporal_flicker_ratio", False, 0.9, 1.6, WEATHERS, "pair"),
    ("flow_warping_error", "flow_warping_error", False, 0.001, 0.01, WEATHERS, "pair"),
    ("flow_warping_error", "flow_warping_error_ratio", False, 0.9, 2.0, WEATHERS, "pair"),
    ("fps", "fps", True, 0.03, 100.0, WEATHERS, "none"),
)
_SKIP_REASONS = {
    "clip_s": "fog: visibility loss invalidates content metrics (paper's rule)",
    "sem_cs": "fog: visibility loss invalidates content metrics (paper's rule)",
    "clip_ds": "clear: no weather edit, so there is no target text direction to compare with",
    "psnr": "no ground-truth {weather} sequence for this scene",
    "ssim": "no ground-truth {weather} sequence for this scene",
    "lpips": "no ground-truth {weather} sequence for this scene",
}
_WEATHER_RGB = {"clear": (0, 0, 0), "rain": (90, 100, 120), "snow": (235, 235, 245), "fog": (205, 205, 215)}


def _source_frames(data_root: Path | None, n: int, size: tuple[int, int], out: Path) -> tuple[list[Path], str]:
    """``n`` source frames (JPEG, like pandaset's) at ``size``: real photos when available."""
    from PIL import Image

    out.mkdir(parents=True, exist_ok=True)
    photos = sorted((data_root / "pandaset_002" / "images").glob("*_0.jpg")) if data_root else []
    paths = []
    for k in range(n):
        if photos:
            img = Image.open(photos[k % len(photos)]).convert("RGB").resize(size, Image.Resampling.BILINEAR)
        else:
            from wcbench.scenes.demo import render_frame

            img = Image.fromarray(render_frame(k)[0]).resize(size, Image.Resampling.BILINEAR)
        paths.append(out / f"{k:03d}.jpg")
        img.save(paths[-1], quality=92)
    return paths, ("pandaset_002 photos" if photos else "the procedural demo street")


def _edit(src: np.ndarray, method: int, weather: str, k: int) -> np.ndarray:
    """A synthetic weather edit of uint8 [H, W, 3] (frame ``k``): different per method, flickering."""
    rng = np.random.default_rng(1000 * method + 10 * WEATHERS.index(weather) + k)
    x = src.astype(np.float32)
    tint = np.array(_WEATHER_RGB[weather], np.float32)
    amount = {"clear": 0.0, "rain": 0.25, "snow": 0.35, "fog": 0.55}[weather] * (0.6 + 0.2 * method)
    x = x * (1 - amount) + tint * amount
    if method == 2:  # grain: per-frame noise (visible flicker)
        x += rng.normal(0.0, 8.0, x.shape)
    if method == 3 and weather in ("rain", "snow"):  # streaks / flakes at random places each frame
        h, w = x.shape[:2]
        for _ in range(max(1, h * w // 4000)):
            r, c = int(rng.integers(0, h)), int(rng.integers(0, w))
            x[r : r + (12 if weather == "rain" else 3), c : c + 2] = 235.0
    return np.clip(x, 0, 255).astype(np.uint8)


def _number(rng: np.random.Generator, lo: float, hi: float) -> float:
    if lo > 0 and hi / lo > 50:  # fps: log-uniform
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    return float(rng.uniform(lo, hi))


def _metric_config() -> dict[str, Any]:
    """Recorded metric settings as `wcbench evaluate` writes them (random CLIP/SegFormer as here)."""
    sha = sha256_json("bench-report")
    return {
        "clip_s": {"class": "ClipScore", "config": {"model": "clip-vit-b32-openai", "backend": "onnx",
                                                    "weights_sha256": sha, "weights_verified": False}},
        "clip_ds": {"class": "ClipDirectionalScore", "config": {"model": "clip-vit-b32-openai", "backend": "onnx",
                                                                "weights_sha256": sha, "weights_verified": False}},
        "sem_cs": {"class": "SemanticConsistency", "config": {"segmenter": "segformer-b0-ade", "model": {
            "files": {"model.onnx": sha}, "weights_verified": False}}},
        "lpips": {"class": "LPIPS", "config": {"net": "alex", "weights_sha256": sha, "weights_verified": True}},
        **{m: {"class": m, "config": {}} for m in ("psnr", "ssim", "temporal_flicker", "flow_warping_error", "fps")},
    }


def make_results_folders(
    root: Path,
    *,
    methods: tuple[str, ...] = METHODS,
    scenes: tuple[str, ...] = SCENES,
    weathers: tuple[str, ...] = WEATHERS,
    n_frames: int = 30,
    size: tuple[int, int] = (960, 540),
    data_root: Path | None = None,
    seed: int = 0,
) -> tuple[list[Path], str]:
    """Write one results folder per method (``root/<method>``) with frames in the prediction layout.

    Parameters
    ----------
    root : Path
        Empty folder.
    methods, scenes, weathers : tuple of str
    n_frames : int
        Frames per sequence.
    size : (int, int)
        Frame (width, height) in px.
    data_root : Path, optional
        Where pandaset_002 may be (real source photos).
    seed : int
        Seed of the numbers.

    Returns
    -------
    (list of Path, str)
        The folders, and what the source frames are.
    """
    from PIL import Image

    rng = np.random.default_rng(seed)
    sources, what = {}, ""
    for i, scene in enumerate(scenes):
        paths, what = _source_frames(data_root, n_frames + i, size, root / "data" / scene / "images")
        sources[scene] = paths[i:]  # scenes differ: each starts one photo later
    folders = []
    for mi, method in enumerate(methods):
        out = root / method
        results: dict[str, Any] = {}
        skipped: list[dict[str, Any]] = []
        inputs: dict[str, Any] = {"scenes": {}, "files": {}}
        for scene in scenes:
            src_hashes = [sha256_file(p) for p in sources[scene]]
            inputs["files"][scene] = {"root": str(root / "data" / scene), "size": list(size),
                                      "source": [str(p) for p in sources[scene]], "weathers": {}}
            for weather in weathers:
                folder = out / method / scene / weather
                folder.mkdir(parents=True, exist_ok=True)
                preds = []
                for k, p in enumerate(sources[scene]):
                    edit = _edit(np.asarray(Image.open(p).convert("RGB")), mi, weather, k)
                    preds.append(folder / f"{k:03d}.png")
                    Image.fromarray(edit).save(preds[-1], compress_level=1)
                fps = _number(rng, 0.03, 100.0)
                atomic_write_json(folder / "info.json", {
                    "method": method, "version": "1", "scene": scene, "weather": weather, "seed": seed,
                    "parameters": {"method_index": mi, "synthetic": True},
                    "timings": {"fps": fps, "median_frame_ms": 1e3 / fps, "resolution": list(size),
                                "machine": machine_info(), "train_s": 600.0 + 60 * mi},
                })
                inputs["scenes"].setdefault(scene, {})[weather] = {
                    "predictions": [sha256_file(p) for p in preds], "source": src_hashes,
                    "reference": src_hashes if weather == "clear" else None}
                inputs["files"][scene]["weathers"][weather] = {
                    "predictions": [p.relative_to(out).as_posix() for p in preds],
                    "reference": [str(p) for p in sources[scene]] if weather == "clear" else None}
                outputs: dict[str, Any] = {}
                for metric, output, hib, lo, hi, applies, kind in OUTPUTS:
                    if weather not in applies:
                        if output == metric:
                            skipped.append({"scene": scene, "weather": weather, "metric": metric,
                                            "reason": _SKIP_REASONS[metric].format(weather=weather)})
                        continue
                    n_values = {"frame": n_frames, "pair": n_frames - 1, "none": 0}[kind]
                    value = fps if output == "fps" else _number(rng, lo, hi)
                    per_frame = [float(value * (1 + 0.05 * v)) for v in rng.standard_normal(n_values)]
                    extra = ({"resolution": list(size), "machine": machine_info(), "median_frame_ms": 1e3 / fps}
                             if output == "fps" else {})
                    outputs[output] = {"metric": metric, "value": value, "variant": f"synthetic {output}",
                                       "reason": None, "higher_is_better": hib, "per_frame": per_frame,
                                       "extra": extra}
                results.setdefault(scene, {})[weather] = outputs
        config = {"method": method, "method_kind": "synthetic", "scenes": ",".join(scenes),
                  "scene_ids": list(scenes), "weathers": list(weathers),
                  "metrics": sorted({o[0] for o in OUTPUTS}), "metric_config": _metric_config(),
                  "predictions": str(out / method), "pattern": None, "resize": False, "fps": None}
        inputs["sha256"] = sha256_json({"inputs": inputs["scenes"], "config": config})
        doc = {"kind": "wcbench-results", "schema_version": SCHEMA_VERSION, "created": "2026-01-01T00:00:00+00:00",
               "versions": package_versions(), "machine": machine_info(), "config": config, "inputs": inputs,
               "results": results, "skipped": skipped}
        atomic_write_text(out / RESULTS_CSV, to_csv(doc))
        atomic_write_json(out / RESULTS_JSON, doc)
        folders.append(out)
    return folders, what


class _Cells(html.parser.HTMLParser):
    """Table cells of a report: (data-* attributes, shown text of the value)."""

    def __init__(self) -> None:
        super().__init__()
        self.cells: list[tuple[dict[str, str], str]] = []
        self._attrs: dict[str, str] | None = None
        self._in_value = False
        self._text = ""

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        if tag == "td" and "data-output" in a:
            self._attrs, self._text = a, ""
        elif tag == "span" and self._attrs is not None and a.get("class") == "v":
            self._in_value = True

    def handle_endtag(self, tag: str) -> None:
        if tag == "span":
            self._in_value = False
        elif tag == "td" and self._attrs is not None:
            self.cells.append((self._attrs, self._text))
            self._attrs = None

    def handle_data(self, data: str) -> None:
        if self._in_value:
            self._text += data


def wrong_cells(html_text: str, folders: list[Path]) -> tuple[int, int]:
    """(cells whose number differs from results.json at the shown precision, numeric cells checked).

    Mean cells are compared with the mean over scenes of results.json's values; method labels are
    the folders' method names (distinct here).
    """
    values: dict[tuple[str, str, str, str], float] = {}
    for folder in folders:
        doc = json.loads((folder / RESULTS_JSON).read_text(encoding="utf-8"))
        for scene, ws in doc["results"].items():
            for weather, outs in ws.items():
                for output, r in outs.items():
                    if r["value"] is not None:
                        values[(doc["config"]["method"], scene, weather, output)] = float(r["value"])
    parser = _Cells()
    parser.feed(html_text)
    wrong = checked = 0
    for attrs, text in parser.cells:
        if not text or not text[0].isdigit():
            continue
        key = (attrs["data-method"], attrs["data-scene"], attrs["data-weather"], attrs["data-output"])
        if key[1] == "mean":
            found = [v for (m, _, w, o), v in values.items() if (m, w, o) == (key[0], key[2], key[3])]
            expected = float(np.mean(found)) if found else None
        else:
            expected = values.get(key)
        decimals = len(text.split(".")[1]) if "." in text else 0
        checked += 1
        wrong += expected is None or f"{expected:.{decimals}f}" != text
    return wrong, checked


def run(*, data_root: Path | None, quick: bool = False) -> BenchReport:
    """Build the report of 4 methods x 3 scenes x 4 weathers three ways; time and size each."""
    from wcbench.reports import build_report

    n_frames, size = (4, (192, 108)) if quick else (30, (960, 540))
    report = BenchReport("report")
    with tempfile.TemporaryDirectory(prefix="wcbench-bench-report-") as tmp:
        root = Path(tmp)
        start = time.perf_counter()
        folders, what = make_results_folders(root, n_frames=n_frames, size=size, data_root=data_root)
        setup_s = time.perf_counter() - start
        variants: tuple[tuple[str, str, Any, dict[str, Any]], ...] = (("report_default", "animation_frames", 12, {}),
                    ("report_stills", "animation_frames", 0, {"animation_frames": 0}),
                    ("report_tables_only", "frames", False, {"frames": False}))
        for name, knob, value, options in variants:
            out = root / f"{name}.html"
            outcome = build_report(folders, out, csv=True, latex=True, **options)
            wrong, checked = wrong_cells(out.read_text(encoding="utf-8"), folders)
            size_mb = outcome.size_bytes / 1e6
            report.cases.append(BenchCase(
                name=name, knob=knob, value=value, time_ms=round(outcome.seconds * 1e3, 1), error=wrong,
                error_unit="cells", extra={
                    "default": name == "report_default", "size_mb": round(size_mb, 3), "images": outcome.n_images,
                    "cells_checked": checked, "target_mb": TARGET_MB, "target_met": size_mb <= TARGET_MB,
                    "csv_kb": round(os.path.getsize(out.with_suffix(".csv")) / 1e3, 1),
                }))
    report.notes.append(
        f"{len(METHODS)} methods x {len(SCENES)} scenes x {len(WEATHERS)} weathers, {n_frames} frames per "
        f"sequence at {size[0]}x{size[1]} (PNG predictions, JPEG sources from {what}); synthetic numbers; "
        f"writing the folders took {setup_s:.1f} s (not in time_ms)")
    report.notes.append("error = table cells whose text differs from results.json at the shown precision (means "
                        "recomputed from results.json)")
    if quick:
        report.notes.append("--quick: tiny frames and sequences; a smoke run, not a measurement")
    return report
