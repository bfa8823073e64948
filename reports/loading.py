"""Read results folders (``results.json`` + ``results.csv``) and the files they point to.

The report is built from these files alone (never from scenes or metrics), so it works for methods
scored separately, on another machine or months apart. The format is the one documented in
``wcbench/results.py`` (docs/guide.md, "Results files"); this module only reads it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from wcbench.core.errors import InputError
from wcbench.core.storage import sha256_bytes

#: The results format this report reads (``wcbench/results.py``: KIND, SCHEMA_VERSION, CSV_COLUMNS).
RESULTS_KIND = "wcbench-results"
RESULTS_SCHEMA_VERSION = 1
RESULTS_JSON = "results.json"
RESULTS_CSV = "results.csv"
CSV_COLUMNS = (
    "scene", "weather", "metric", "output", "value", "status", "reason", "variant", "higher_is_better", "n_frames",
    "missing_frames",
)
INFO_FILE = "info.json"
_REQUIRED = ("created", "config", "inputs", "results", "skipped")


@dataclass
class ResultsFolder:
    """One results folder: its ``results.json``, its tidy ``results.csv`` and a display label.

    Attributes
    ----------
    path : Path
        The folder (absolute).
    doc : dict
        ``results.json`` as read.
    table : pandas.DataFrame
        ``results.csv`` rows (columns :data:`CSV_COLUMNS`), ``value`` as float (NaN when empty).
    label : str
        The method's name in the report (the method, or ``method (folder)`` when two folders hold
        the same method for the same scenes).
    """

    path: Path
    doc: dict[str, Any]
    table: pd.DataFrame
    label: str = ""
    infos: dict[tuple[str, str], dict[str, Any] | None] = field(default_factory=dict)

    @property
    def method(self) -> str:
        """The method name recorded in ``config.method``."""
        return str(self.doc["config"].get("method", "?"))

    @property
    def units(self) -> list[tuple[str, str]]:
        """Sorted (scene, weather) pairs this folder scored."""
        return sorted((s, w) for s, ws in self.doc["results"].items() for w in ws)

    def hashes(self, scene: str, weather: str, kind: str) -> list[str] | None:
        """Recorded sha256 of the ``kind`` files (``predictions``, ``source``, ``reference``)."""
        rec = self.doc["inputs"].get("scenes", {}).get(scene, {}).get(weather, {})
        value = rec.get(kind)
        return list(value) if isinstance(value, list) else None

    def n_frames(self, scene: str, weather: str) -> int | None:
        """Number of scene frames of a (scene, weather) (from the source hashes)."""
        src = self.hashes(scene, weather, "source")
        return len(src) if src is not None else None

    def frame_size(self, scene: str) -> tuple[int, int] | None:
        """The scene's (width, height) as recorded in ``inputs.files`` (``None`` in older files)."""
        size = self.doc["inputs"].get("files", {}).get(scene, {}).get("size")
        return (int(size[0]), int(size[1])) if isinstance(size, list) and len(size) == 2 else None

    def file_paths(self, scene: str, weather: str, kind: str) -> list[Path] | None:
        """Absolute paths of the ``kind`` files (``predictions``, ``source``, ``reference``).

        Taken from ``inputs.files`` (paths relative to the folder are resolved against it); for
        older files without it, predictions are looked for in the canonical layout under
        ``config.predictions``. ``None`` when nothing is recorded.
        """
        files = self.doc["inputs"].get("files", {}).get(scene)
        if isinstance(files, dict):
            rec = files.get("source") if kind == "source" else files.get("weathers", {}).get(weather, {}).get(kind)
            if isinstance(rec, list):
                return [p if p.is_absolute() else self.path / p for p in map(Path, rec)]
        if kind == "predictions" and self.doc["config"].get("predictions"):
            n = self.n_frames(scene, weather) or 0
            root = Path(self.doc["config"]["predictions"])
            for base in (root / scene / weather, root / weather):
                if (base / "000.png").is_file():
                    return [base / f"{k:03d}.png" for k in range(n)]
        return None

    def info(self, scene: str, weather: str) -> dict[str, Any] | None:
        """The method's ``info.json`` for (scene, weather): beside the predictions or up to two
        folders above (weather, scene, method level), as the evaluation looked for it."""
        key = (scene, weather)
        if key not in self.infos:
            self.infos[key] = None
            paths = self.file_paths(scene, weather, "predictions")
            if paths:
                folder = paths[0].parent
                for d in (folder, folder.parent, folder.parent.parent):
                    if (d / INFO_FILE).is_file():
                        try:
                            obj = json.loads((d / INFO_FILE).read_text(encoding="utf-8"))
                        except (OSError, json.JSONDecodeError):
                            break  # the evaluation would have refused it; show no info rather than fail
                        self.infos[key] = obj if isinstance(obj, dict) else None
                        break
        return self.infos[key]


def read_checked_file(path: Path, expected_sha256: str | None) -> tuple[bytes | None, str]:
    """The bytes of ``path`` if it exists and matches ``expected_sha256``.

    Returns
    -------
    (bytes or None, str)
        The content, or ``None`` with the reason it cannot be shown (missing, changed since it
        was scored, no hash recorded).
    """
    try:
        data = path.read_bytes()
    except OSError:
        return None, f"{path} not found (moved or on another machine)"
    if expected_sha256 is None:
        return None, f"{path}: no sha256 recorded, so it cannot be checked"
    if sha256_bytes(data) != expected_sha256:
        return None, f"{path} changed since it was scored (sha256 differs)"
    return data, ""


def _results_path(path: Path) -> Path:
    if path.is_dir():
        return path / RESULTS_JSON
    return path


def load_results_folder(path: str | Path) -> ResultsFolder:
    """Read and check one results folder.

    Parameters
    ----------
    path : path-like
        The ``--out`` folder of ``wcbench run`` / ``wcbench evaluate`` (or its ``results.json``).

    Raises
    ------
    InputError
        No ``results.json`` or ``results.csv``; corrupt JSON or CSV; not a wcbench results file;
        another schema version; missing keys; a ``results.csv`` that disagrees with ``results.json``.
    """
    json_path = _results_path(Path(path).expanduser()).absolute()
    folder = json_path.parent
    if not json_path.is_file():
        raise InputError(
            f"{folder}: no {RESULTS_JSON} (expected the --out folder of `wcbench run` or `wcbench evaluate`)"
        )
    try:
        doc = json.loads(json_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{json_path}: not a readable results file ({exc})") from None
    if not isinstance(doc, dict) or doc.get("kind") != RESULTS_KIND:
        raise InputError(f"{json_path}: not a wcbench results file (no \"kind\": \"{RESULTS_KIND}\")")
    if doc.get("schema_version") != RESULTS_SCHEMA_VERSION:
        raise InputError(
            f"{json_path}: results of schema version {doc.get('schema_version')}; this report reads version "
            f"{RESULTS_SCHEMA_VERSION} (re-score with this wcbench, or build the report with the wcbench that "
            "wrote them)"
        )
    problem = _structure_problem(doc)
    if problem:
        raise InputError(f"{json_path}: malformed results file: {problem}")
    table = _read_csv(folder / RESULTS_CSV)
    _check_agreement(json_path, doc, table)
    return ResultsFolder(path=folder, doc=doc, table=table)


def _structure_problem(doc: dict[str, Any]) -> str:
    """What in ``doc`` breaks the results.json layout (empty string: nothing)."""
    missing = [k for k in _REQUIRED if k not in doc]
    if missing:
        return f"lacks {missing}"
    for key, kind in (("config", dict), ("inputs", dict), ("results", dict), ("skipped", list)):
        if not isinstance(doc[key], kind):
            return f"{key!r} is not a JSON {'object' if kind is dict else 'array'}"
    if not all(isinstance(v, dict) for v in doc["config"].get("metric_config", {}).values()):
        return "config.metric_config holds a non-object"
    for scene, weathers in doc["results"].items():
        for weather, outputs in (weathers.items() if isinstance(weathers, dict) else [("?", None)]):
            if not isinstance(outputs, dict) or not all(
                isinstance(r, dict) and {"metric", "value", "higher_is_better"} <= set(r) for r in outputs.values()
            ):
                return f"results[{scene!r}][{weather!r}] is not {{output: {{metric, value, higher_is_better, ...}}}}"
    return ""


def _read_csv(path: Path) -> pd.DataFrame:
    if not path.is_file():
        raise InputError(f"{path}: missing (every results folder holds results.json and results.csv)")
    try:
        # all read as text ("002" is a scene, not 2); values then parsed by Python's float, which
        # inverts the repr() they were written with exactly (pandas' own parser may be 1 ulp off)
        table = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise InputError(f"{path}: not a readable results table ({exc})") from None
    if tuple(table.columns) != CSV_COLUMNS:
        raise InputError(f"{path}: columns {list(table.columns)}, expected {list(CSV_COLUMNS)}")
    try:
        table["value"] = [float(v) if v else math.nan for v in table["value"]]
        table["n_frames"] = [int(v or 0) for v in table["n_frames"]]
    except ValueError as exc:
        raise InputError(f"{path}: not a readable results table ({exc})") from None
    return table


def _check_agreement(json_path: Path, doc: dict[str, Any], table: pd.DataFrame) -> None:
    """results.csv must hold exactly the numbers of results.json (a hand-edited file is refused)."""
    expected: dict[tuple[str, str, str], float | None] = {}
    for scene, weathers in doc["results"].items():
        for weather, outputs in weathers.items():
            for output, r in outputs.items():
                expected[(scene, weather, output)] = r.get("value")
    got = {
        (r.scene, r.weather, r.output): (None if math.isnan(r.value) else float(r.value))
        for r in table.itertuples() if r.status != "skipped"
    }
    if got != expected:
        diff = sorted(set(got.items()) ^ set(expected.items()), key=str)[:3]
        raise InputError(
            f"{json_path.with_name(RESULTS_CSV)} disagrees with {json_path.name} (e.g. {diff}); "
            "both are written together, so one was edited or replaced"
        )


def assign_labels(folders: list[ResultsFolder]) -> None:
    """Give every folder its row label: the method name, made unique with the folder name when
    two folders score the same method on overlapping (scene, weather) units (never averaged)."""
    by_method: dict[str, list[ResultsFolder]] = {}
    for f in folders:
        by_method.setdefault(f.method, []).append(f)
    for method, group in by_method.items():
        overlap = len(group) > 1 and any(
            set(a.units) & set(b.units) for i, a in enumerate(group) for b in group[i + 1:]
        )
        for f in group:
            f.label = f"{method} ({f.path.name})" if overlap else method
    seen: dict[str, int] = {}
    for f in folders:  # same folder names too: number them
        seen[f.label] = seen.get(f.label, 0) + 1
        if seen[f.label] > 1:
            f.label = f"{f.label} #{seen[f.label]}"
