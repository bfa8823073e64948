"""The one JSON schema every ``wcbench bench <suite>`` writes.

A benchmark file is::

    {
      "schema": "wcbench-benchmark",
      "schema_version": 1,
      "suite": "raster",                 # which `wcbench bench` suite
      "created": "2026-11-22T10:00:00+00:00",
      "machine": {"cpu": ..., "cores": 2, "memory_gb": 23.4, ...},
      "versions": {"python": ..., "numpy": ..., "torch": ...},
      "code": {"wcbench": "0.1.0", "digests": {"wcbench.bench.raster": "3f2a...", ...}},
      "command": "wcbench bench raster --data-root ../shared/data --out bench/raster.json",
      "notes": ["free text: what was substituted, what could not run"],
      "cases": [
        {"name": "b_pandaset_117k",      # unique within the suite
         "knob": "gaussians",            # the parameter this case varies
         "value": 117000,                # its value
         "time_ms": 31.2,                # the headline time of the case
         "error": 3.1e-07,               # the headline error against the suite's reference
         "error_unit": "abs",            # unit of `error` ("abs", "rel", "px", ...)
         ...}                            # any further suite-specific fields (numbers or strings)
      ]
    }

``time_ms`` and ``error`` may be ``null`` when a case measures only one of them. Reports chart any
suite by (knob, value, time_ms, error) without knowing the suite; a case whose value is wcbench's
default for its knob may say so with ``"default": true`` (the report marks it). A default case that
also says ``"stands_for_knobs": true`` stands for the defaults of every knob of its suite that varies one
setting away from it (the knob rows of ``bench model``): the summary puts it in each such knob's
front and chart.

``code`` (the digests of the code the suite measures, :mod:`.code_version`, taken when the suite
starts) and ``command`` (the command line that wrote the file, with the ``WCBENCH_BENCH_*``
variables set) are written by ``wcbench bench``; ``null`` where a suite was run from Python, absent
in files written before they were recorded. The docs test reads ``code`` to call a committed JSON
older than the code it measures (docs/guide.md, "Numbers in the docs").
"""

from __future__ import annotations

import datetime as _dt
import os
import shlex
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from wcbench.core.environment import machine_info, package_versions
from wcbench.core.storage import atomic_write_json

SCHEMA = "wcbench-benchmark"
SCHEMA_VERSION = 1
_REQUIRED = ("name", "knob", "value", "time_ms", "error", "error_unit")


@dataclass
class BenchCase:
    """One measured case of a benchmark suite.

    Attributes
    ----------
    name : str
        Unique name of the case within its suite.
    knob, value
        The parameter this case varies and its value (e.g. ``"gaussians"``, ``117000``).
    time_ms : float or None
        Headline wall time in milliseconds.
    error : float or None
        Headline error against the suite's reference, in ``error_unit``.
    error_unit : str
        Unit of ``error``: ``"abs"``, ``"rel"``, ``"px"``...
    extra : dict
        Further suite-specific fields, flattened into the case's JSON object.
    """

    name: str
    knob: str
    value: Any
    time_ms: float | None
    error: float | None
    error_unit: str
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The case as a flat JSON object."""
        clash = set(self.extra) & set(_REQUIRED)
        if clash:
            raise ValueError(f"case {self.name!r}: extra fields {sorted(clash)} shadow required fields")
        return {
            "name": self.name, "knob": self.knob, "value": self.value, "time_ms": self.time_ms,
            "error": self.error, "error_unit": self.error_unit, **self.extra,
        }


@dataclass
class BenchReport:
    """A suite's cases plus free-text notes (substitutions, skipped cases).

    ``stand_ins`` says what data was missing and what stood in for it (the CLI prints each as a
    warning: numbers on stand-in data are not the documented ones). ``code`` and ``command`` are
    what ``wcbench bench`` records of the code measured and of its own invocation (module docstring).
    """

    suite: str
    cases: list[BenchCase] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    stand_ins: list[str] = field(default_factory=list)
    code: dict[str, Any] | None = None
    command: str | None = None

    def to_json(self) -> dict[str, Any]:
        """The whole report in the benchmark schema (see module docstring)."""
        names = [c.name for c in self.cases]
        if len(set(names)) != len(names):
            raise ValueError(f"suite {self.suite!r}: duplicate case names in {names}")
        return {
            "schema": SCHEMA,
            "schema_version": SCHEMA_VERSION,
            "suite": self.suite,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "machine": machine_info(),
            "versions": package_versions(),
            "code": self.code,
            "command": self.command,
            "notes": list(self.notes),
            "stand_ins": list(self.stand_ins),
            "cases": [c.to_json() for c in self.cases],
        }

    def write(self, path: str | os.PathLike[str]) -> None:
        """Write the report atomically as JSON."""
        atomic_write_json(path, self.to_json())

    def format_table(self, *, width: int | None = 120) -> str:
        """A plain-text table of the cases for the terminal, at most ``width`` characters wide.

        The required fields come first, then the suite's own fields that most cases fill, as many
        as fit; a last line says how many more the JSON holds. ``width=None``: every field.
        """
        keys: list[str] = list(_REQUIRED)
        extra: list[str] = []
        for case in self.cases:
            extra += [k for k in case.extra if k not in extra]
        filled = {k: sum(c.extra.get(k) is not None for c in self.cases) for k in extra}
        objs = [c.to_json() for c in self.cases]

        def column_width(k: str) -> int:
            return max(len(k), *(len(_fmt(o.get(k))) for o in objs)) if objs else len(k)

        used = sum(column_width(k) + 2 for k in keys)
        left_out = 0
        for k in sorted(extra, key=lambda k: (-filled[k], extra.index(k))):
            if width is None or used + column_width(k) + 2 <= width:
                keys.append(k)
                used += column_width(k) + 2
            else:
                left_out += 1
        rows = [[_fmt(o.get(k)) for k in keys] for o in objs]
        widths = [column_width(k) for k in keys]
        lines = ["  ".join(k.ljust(w) for k, w in zip(keys, widths)).rstrip()]
        lines += ["  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip() for r in rows]
        if left_out:
            lines.append(f"({left_out} more field{'' if left_out == 1 else 's'} per case in the JSON: --out FILE)")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


def bench_command(args: Sequence[str], *, environ: Mapping[str, str] = os.environ) -> str:
    """The shell command ``wcbench ARGS`` as a benchmark JSON records it (``command``).

    The ``WCBENCH_BENCH_*`` variables set in ``environ`` (they choose what a suite runs, e.g.
    ``WCBENCH_BENCH_MODEL_GROUPS``) come first, as ``NAME=value``.
    """
    env = [f"{k}={shlex.quote(v)}" for k, v in sorted(environ.items()) if k.startswith("WCBENCH_BENCH_")]
    return " ".join([*env, shlex.join(["wcbench", *args])])


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def validate_benchmark(obj: dict[str, Any]) -> None:
    """Raise ``ValueError`` if ``obj`` is not a benchmark file of this schema version."""
    if obj.get("schema") != SCHEMA or obj.get("schema_version") != SCHEMA_VERSION:
        raise ValueError(f"not a {SCHEMA} v{SCHEMA_VERSION} file")
    for key in ("suite", "created", "machine", "versions", "notes", "cases"):
        if key not in obj:
            raise ValueError(f"benchmark file lacks {key!r}")
    code = obj.get("code")
    if code is not None and not (isinstance(code, dict) and isinstance(code.get("digests"), dict)):
        raise ValueError(f"benchmark file's 'code' is not a record of digests: {code!r}")
    for case in obj["cases"]:
        missing = [k for k in _REQUIRED if k not in case]
        if missing:
            raise ValueError(f"case {case.get('name')!r} lacks {missing}")
