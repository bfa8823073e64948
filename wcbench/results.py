"""The results files: ``results.json`` (versioned, hashed, raw values) and ``results.csv`` (tidy).

``results.json`` (schema_version 1)::

    {
      "kind": "wcbench-results", "schema_version": 1, "created": ISO time,
      "versions": {...}, "machine": {...},
      "config": {"method", "scenes", "scene_ids", "weathers", "metrics", "metric_config",
                 "predictions", "pattern", "resize", "resize_interpolation", "frame_offset", "fps",
                 "reader": the reader's naming settings, "unedited_check",
                 "scene_folders": {scene: {"folder", "matched", "rule"}}},
      "inputs": {"sha256": hash of everything below,
                 "scenes": {scene: {weather: {"predictions": [sha256...], "source": [...],
                                              "reference": [...] or null, "location", "layout",
                                              "frames": [scene frame of each prediction], "ignored",
                                              "outside_scene" {"count", "frames"} and "passed_over"
                                              [folder...] when anything was left out}}}},
                 "files": {scene: {"root", "size": [w, h], "source": [path...],
                                   "weathers": {weather: {"predictions": [path...],
                                                          "reference": [path...] or null}}}}},
      "results": {scene: {weather: {output: {"metric", "value", "variant", "reason",
                                             "higher_is_better", "per_frame", "extra"}}}},
      "skipped": [{"scene", "weather", "metric", "reason"}],
      "partial": [{"scene", "weather", "n_scene_frames", "scored": [first, last], "missing": [...],
                   "reason"}],
      "resized": [{"scene", "weather", "from": [[w, h]...], "to": [w, h], "interpolation"}],
      "warnings": [{"scene", "weather", "kind", "message", ...}],
      "models": {entry: {"status", "sha256", "verified", "fetched", "seconds", "reason"}},
      "scene_facts": {scene: {"source_weather", "source_weather_flag", "undistorted", ...}},
      "raw_frames": {scene: {weather: {output: {"metric", "value", "variant", "reason",
                                                "higher_is_better"}}}},
      "checksum": sha256 of the document without this key (a hand-edited file is detected)
    }

``inputs.files`` (optional: older files lack it; not part of the hash) says where the hashed files
were, as paths relative to the results folder when inside it, else absolute. A ``value`` that is
not a finite number is ``null`` with its ``reason``. A *partial* (scene, weather)
was scored on the contiguous run of frames its tool wrote (a reader declares that its tool can end
early); ``missing`` names the scene frames without a prediction. ``results.csv`` has one row per
(scene, weather, output): ``scene, weather, metric, output, value, status, reason, variant,
higher_is_better, n_frames, missing_frames`` (``n_frames``: the frames scored for that scene and
weather) with status ``ok``, ``null`` or ``skipped`` and
``missing_frames`` the missing scene frames of a partial sequence (``25-29``; empty when complete).
Every method of a scene is scored at one size: ``config.scored_at`` is ``{"rule", "sizes": {scene:
[w, h]}}``, the rule ``"scene working size"`` (the scene's frame size within the metric working
resolution ``config.metric_resolution``: frames whose longer side exceeds it are area-downscaled to
it; ``null`` is the native protocol, the scene's own size) or ``"asked"`` (``evaluate --scale`` /
``--width/--height``). ``working_size`` lists the (scene, weather) units where frames were
resized for scoring: ``{"scene", "weather", "from": scene size, "to": size scored at,
"predictions": the method's own size, "predictions_resized", "metric_resolution", "rule",
"interpolation"}``; each output's ``variant`` ends with ``scored at WxH`` when that size is not the
scene's. ``models`` names the model-store entries the metrics and the method needed, each with its
status (``installed``, ``fetched`` in this run, ``offline``, ``not-fetchable`` or ``failed``;
:mod:`wcbench.core.models.fetch`). ``raw_frames`` holds, for every edited weather with a ground truth, the
reference metrics (PSNR, SSIM, LPIPS) of the scene's raw frames against that truth, scored like the
predictions: the yardstick the report shows beside the methods. The keys ``partial``, ``resized``,
``warnings``, ``working_size``, ``models`` and ``raw_frames`` may be absent from
files of earlier wcbench versions, and so may ``config.scored_at`` and the ``predictions_resized``
and ``rule`` of ``working_size`` (those scored a method at its own render size).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

from wcbench.core.errors import InputError
from wcbench.core.storage import sha256_json
from wcbench.core.validation import expect_dict, read_json

SCHEMA_VERSION = 1
KIND = "wcbench-results"
RESULTS_JSON = "results.json"
RESULTS_CSV = "results.csv"
CSV_COLUMNS = (
    "scene", "weather", "metric", "output", "value", "status", "reason", "variant", "higher_is_better", "n_frames",
    "missing_frames",
)


def read_results(path: Path) -> dict[str, Any]:
    """Read and check a ``results.json``.

    Raises
    ------
    InputError
        If it is not valid JSON, not a wcbench results file, or of another schema version.
    """
    obj = read_json(path, what="results")
    if not isinstance(obj, dict) or obj.get("kind") != KIND:
        raise InputError(f"{path}: not a wcbench results file (no \"kind\": \"{KIND}\")")
    if obj.get("schema_version") != SCHEMA_VERSION:
        raise InputError(
            f"{path}: results of schema version {obj.get('schema_version')!r}, this wcbench reads and writes "
            f"version {SCHEMA_VERSION}; choose another --out or pass --overwrite to replace them"
        )
    for key in ("config", "inputs", "results"):
        expect_dict(obj.get(key), path=path, field=key)
    for scene, weathers in obj["results"].items():
        for weather, outputs in expect_dict(weathers, path=path, field=f"results.{scene}").items():
            for name, rec in expect_dict(outputs, path=path, field=f"results.{scene}.{weather}").items():
                expect_dict(rec, path=path, field=f"results.{scene}.{weather}.{name}")
    return obj


def results_checksum(doc: dict[str, Any]) -> str:
    """sha256 of a results document without its ``checksum`` key."""
    return sha256_json({k: v for k, v in doc.items() if k != "checksum"})


def is_intact(doc: dict[str, Any]) -> bool:
    """Whether ``doc`` still has the checksum it was written with (``False`` once edited)."""
    return doc.get("checksum") == results_checksum(doc)


def frames_text(frames: list[int]) -> str:
    """``[25, 26, 27, 29]`` -> ``"25-27,29"``."""
    out, i = [], 0
    while i < len(frames):
        j = i
        while j + 1 < len(frames) and frames[j + 1] == frames[j] + 1:
            j += 1
        out.append(str(frames[i]) if i == j else f"{frames[i]}-{frames[j]}")
        i = j + 1
    return ",".join(out)


def csv_rows(results: dict[str, Any]) -> list[dict[str, Any]]:
    """Tidy rows (see module docstring) from a results object."""
    rows = []
    missing = {(p["scene"], p["weather"]): frames_text(p["missing"]) for p in results.get("partial", [])}
    # frames scored per (scene, weather), for every row: a ratio or an fps has no per-frame values
    scored = {(s, w): len(rec.get("frames") or []) for s, ws in results.get("inputs", {}).get("scenes", {}).items()
              for w, rec in ws.items() if isinstance(rec, dict)}
    for scene, weathers in results["results"].items():
        for weather, outputs in weathers.items():
            for output, r in outputs.items():
                rows.append({
                    "scene": scene, "weather": weather, "metric": r["metric"], "output": output,
                    "value": r["value"], "status": "ok" if r["value"] is not None else "null",
                    "reason": r.get("reason") or "", "variant": r.get("variant", ""),
                    "higher_is_better": r["higher_is_better"],
                    "n_frames": scored.get((scene, weather), len(r.get("per_frame") or [])),
                    "missing_frames": missing.get((scene, weather), ""),
                })
    for s in results["skipped"]:
        rows.append({
            "scene": s["scene"], "weather": s["weather"], "metric": s["metric"], "output": s["metric"],
            "value": None, "status": "skipped", "reason": s["reason"], "variant": "",
            "higher_is_better": "", "n_frames": scored.get((s["scene"], s["weather"]), 0),
            "missing_frames": missing.get((s["scene"], s["weather"]), ""),
        })
    rows.sort(key=lambda r: (r["scene"], r["weather"], r["metric"], r["output"]))
    return rows


def to_csv(results: dict[str, Any]) -> str:
    """``results.csv`` text: floats in repr form (round-trip exact), empty cell for null."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in csv_rows(results):
        writer.writerow({k: ("" if v is None else repr(v) if isinstance(v, float) else v) for k, v in row.items()})
    return buf.getvalue()
