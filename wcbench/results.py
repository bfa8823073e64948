"""The results files: ``results.json`` (versioned, hashed, raw values) and ``results.csv`` (tidy).

``results.json`` (schema_version 1)::

    {
      "kind": "wcbench-results", "schema_version": 1, "created": ISO time,
      "versions": {...}, "machine": {...},
      "config": {"method", "scenes", "scene_ids", "weathers", "metrics", "metric_config",
                 "predictions", "pattern", "resize", "fps"},
      "inputs": {"sha256": hash of "scenes" and "config",
                 "scenes": {scene: {weather: {"predictions": [sha256...], "source": [...],
                                              "reference": [...] or null}}},
                 "files": {scene: {"root", "size": [w, h], "source": [path...],
                                   "weathers": {weather: {"predictions": [path...],
                                                          "reference": [path...] or null}}}}},
      "results": {scene: {weather: {output: {"metric", "value", "variant", "reason",
                                             "higher_is_better", "per_frame", "extra"}}}},
      "skipped": [{"scene", "weather", "metric", "reason"}]
    }

``inputs.files`` (optional: older files lack it; not part of the hash) says where the hashed files
were, as paths relative to the results folder when inside it, else absolute. A ``value`` that is not
a finite number is ``null`` with its ``reason``. ``results.csv`` has one row
per (scene, weather, output): ``scene, weather, metric, output, value, status, reason, variant,
higher_is_better, n_frames`` with status ``ok``, ``null`` or ``skipped``.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

from wcbench.errors import InputError

SCHEMA_VERSION = 1
KIND = "wcbench-results"
RESULTS_JSON = "results.json"
RESULTS_CSV = "results.csv"
CSV_COLUMNS = (
    "scene", "weather", "metric", "output", "value", "status", "reason", "variant", "higher_is_better", "n_frames",
)


def read_results(path: Path) -> dict[str, Any]:
    """Read and check a ``results.json``.

    Raises
    ------
    InputError
        If it is not valid JSON, not a wcbench results file, or of another schema version.
    """
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable results file ({exc})") from None
    if not isinstance(obj, dict) or obj.get("kind") != KIND:
        raise InputError(f"{path}: not a wcbench results file (no \"kind\": \"{KIND}\")")
    if obj.get("schema_version") != SCHEMA_VERSION:
        raise InputError(
            f"{path}: results of schema version {obj.get('schema_version')}, this wcbench reads and writes "
            f"version {SCHEMA_VERSION}; choose another --out or pass --overwrite to replace them"
        )
    return obj


def csv_rows(results: dict[str, Any]) -> list[dict[str, Any]]:
    """Tidy rows (see module docstring) from a results object."""
    rows = []
    for scene, weathers in results["results"].items():
        for weather, outputs in weathers.items():
            for output, r in outputs.items():
                rows.append({
                    "scene": scene, "weather": weather, "metric": r["metric"], "output": output,
                    "value": r["value"], "status": "ok" if r["value"] is not None else "null",
                    "reason": r.get("reason") or "", "variant": r.get("variant", ""),
                    "higher_is_better": r["higher_is_better"], "n_frames": len(r.get("per_frame", [])),
                })
    for s in results["skipped"]:
        rows.append({
            "scene": s["scene"], "weather": s["weather"], "metric": s["metric"], "output": s["metric"],
            "value": None, "status": "skipped", "reason": s["reason"], "variant": "",
            "higher_is_better": "", "n_frames": 0,
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
