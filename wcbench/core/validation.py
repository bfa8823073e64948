"""Checks at the boundary: JSON files and numbers read from disk, before anything uses them.

Every reader of a file a user hands in (scene files, a tool's ``info.json``, results and unit
files) goes through these, so a damaged or hostile file ends as one
:class:`~wcbench.core.errors.InputError` naming the file, the field and what was expected, never
as a traceback or a silently wrong number (docs/design.md §9). Numbers are checked in float64,
before any cast to float32 could turn 1e-300 into 0 or 1e300 into inf.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from wcbench.core.errors import InputError

__all__ = ["MAX_JSON_BYTES", "expect_dict", "expect_list", "finite_number", "read_json"]

#: The largest JSON file read (a scene's instances file is a few MB; results of a big run ~50 MB).
MAX_JSON_BYTES = 512 * 1024 * 1024


def _no_constants(name: str) -> float:
    raise ValueError(f"{name} is not a JSON number")


def read_json(path: str | Path, *, what: str = "JSON") -> Any:
    """The JSON value in ``path``: UTF-8 text, standard JSON only (no NaN or Infinity literals).

    Raises
    ------
    InputError
        The file is missing, a folder, larger than :data:`MAX_JSON_BYTES`, not UTF-8 or not JSON.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} file not found" + (" (it is a folder)" if path.is_dir() else ""))
    size = path.stat().st_size
    if size > MAX_JSON_BYTES:
        raise InputError(f"{path}: {what} file of {size:,} bytes; at most {MAX_JSON_BYTES:,} are read")
    data = path.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        bad = data[exc.start:exc.start + 1]
        raise InputError(f"{path}: {what} is not UTF-8 text (byte {exc.start}: {bad!r})") from None
    try:
        return json.loads(text, parse_constant=_no_constants)
    except (json.JSONDecodeError, ValueError, RecursionError) as exc:
        raise InputError(f"{path}: {what} is not valid JSON ({exc})") from None


def expect_dict(value: Any, *, path: str | Path, field: str = "", what: str = "a JSON object") -> dict[str, Any]:
    """``value`` if it is a JSON object, else an :class:`InputError` naming ``path`` and ``field``."""
    if not isinstance(value, dict):
        raise InputError(f"{path}: {field or 'the file'} must be {what}, got {_kind(value)}")
    return value


def expect_list(value: Any, *, path: str | Path, field: str = "", what: str = "a JSON list") -> list[Any]:
    """``value`` if it is a JSON list, else an :class:`InputError` naming ``path`` and ``field``."""
    if not isinstance(value, list):
        raise InputError(f"{path}: {field or 'the file'} must be {what}, got {_kind(value)}")
    return value


def finite_number(value: Any, *, path: str | Path, field: str, low: float | None = None,
                  high: float | None = None, positive: bool = False) -> float:
    """``value`` as a finite float64 in ``[low, high]`` (``positive``: also > 0).

    Booleans and strings are refused (``true`` is not a frame rate).

    Raises
    ------
    InputError
        Naming ``path``, ``field``, the value and the range expected.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{path}: {field} must be a number, got {_kind(value)}")
    x = float(value)
    expected = "a finite number" + (" > 0" if positive else "")
    if low is not None or high is not None:
        expected += f" in [{'-inf' if low is None else f'{low:g}'}, {'inf' if high is None else f'{high:g}'}]"
    if (not math.isfinite(x) or (positive and x <= 0) or (low is not None and x < low)
            or (high is not None and x > high)):
        raise InputError(f"{path}: {field} = {x!r}; expected {expected}")
    return x


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, (int, float)):
        return f"a number ({value!r})"
    if isinstance(value, str):
        return f"a string ({value[:40]!r})"
    if isinstance(value, dict):
        return "a JSON object"
    if isinstance(value, list):
        return "a JSON list"
    return type(value).__name__
