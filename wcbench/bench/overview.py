"""``wcbench bench --all``: every suite, one table, and a time-versus-error chart per knob.

:func:`run_all` runs the suites one after another (each writes ``OUT/<suite>.json``, as ``wcbench
bench SUITE --out`` does), then :func:`summarize` reads the JSON files alone and writes

``OUT/summary.md``      one table of every case (suite, case, knob, value, time, error) with the
                        defaults marked and whether each default is on the Pareto front of its knob
``OUT/charts/<suite>-<knob>-<subject>.png``
                        time against error of that knob's cases, the default as a star, the
                        Pareto front as a line

Within a (suite, knob) group of different values, a case is on the front when no other case of the
group is at least as fast and at least as good with one of the two strictly better. "Good" is a lower ``error``,
except for ``psnr_db`` (held-out PSNR: higher is better). Cases without a time or an error are
listed, not charted.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from wcbench.bench.code_version import measured_code
from wcbench.bench.schema import BenchReport, validate_benchmark
from wcbench.core.storage import atomic_write_text
from wcbench.reports.media import bench_figure

__all__ = ["HIGHER_IS_BETTER_UNITS", "pareto_flags", "pareto_front", "run_all", "summarize"]

#: Error units where a larger ``error`` is better (the model suite reports quality as PSNR).
HIGHER_IS_BETTER_UNITS = frozenset({"psnr_db"})
#: Suites ``bench --all`` runs, in this order (the slowest last).
ALL_SUITES = ("metrics", "raster", "weather", "report", "scale", "validity", "streets", "model")


def pareto_flags(scores: Sequence[Sequence[float]]) -> list[bool]:
    """For each row of scores (every column: higher is better), whether no other row is at least as
    good in every column and strictly better in one (equal rows do not dominate each other)."""
    rows = [tuple(r) for r in scores]
    return [not any(o != r and all(a >= b for a, b in zip(o, r)) for o in rows) for r in rows]


def pareto_front(points: Sequence[tuple[float, float]], *, higher_is_better: bool = False) -> list[bool]:
    """For each (time, error) point, whether no other point is at least as fast and at least as good,
    one of the two strictly.

    Parameters
    ----------
    points : sequence of (float, float)
        (time, error) pairs.
    higher_is_better : bool
        A larger error value is better (PSNR).
    """
    sign = 1.0 if higher_is_better else -1.0
    return pareto_flags([(-t, sign * e) for t, e in points])


def _usable(case: dict[str, Any]) -> bool:
    t, e = case.get("time_ms"), case.get("error")
    return isinstance(t, (int, float)) and isinstance(e, (int, float)) and math.isfinite(t) and math.isfinite(e) \
        and t > 0


def _groups(reports: list[dict[str, Any]]) -> dict[tuple[str, str, str], list[dict[str, Any]]]:
    """Cases by (suite, knob, subject): the subject is the first word of the case name, so that one
    knob measured on several subjects (the backend of CLIP and of SegFormer) is compared within each."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for rep in reports:
        for case in rep["cases"]:
            subject = str(case["name"]).split("_")[0]
            groups.setdefault((rep["suite"], str(case["knob"]), subject), []).append(case)
    return groups


def _chart(path: Path, suite: str, knob: str, cases: list[dict[str, Any]], front: list[bool]) -> None:
    picture = bench_figure(cases, knob=knob, suite=suite, front=front)
    if picture is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(picture.data)


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "" if v is None else str(v)


def summarize(folder: Path) -> dict[str, Any]:
    """Write ``folder/summary.md`` and ``folder/charts/*.png`` from the suite JSON files in ``folder``.

    Returns
    -------
    dict
        ``{"suites": [...], "charts": [paths], "off_front": [(suite, knob, case)]}``: the defaults
        that are not on their knob's Pareto front.

    Raises
    ------
    ValueError
        When ``folder`` holds no benchmark JSON, or one that does not follow the schema (the file
        is named).
    """
    reports = []
    for path in sorted(folder.glob("*.json")):
        try:
            obj = json.loads(path.read_text(encoding="utf-8"))
            validate_benchmark(obj)
        except (ValueError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: not a wcbench benchmark JSON: {exc}") from None
        reports.append(obj)
    if not reports:
        raise ValueError(f"{folder}: no benchmark JSON files (run `wcbench bench --all --out {folder}` first)")
    lines = ["# wcbench benchmarks", "",
             "Every suite's cases; `default` marks the shipped setting, `front` whether a case is on the",
             "Pareto front of time against error among its knob's cases (PSNR: higher is better).", ""]
    charts, off_front = [], []
    for rep in reports:
        machine = rep.get("machine", {})
        lines += [f"## {rep['suite']}", "", f"{rep['created']}, {machine.get('cores', '?')} cores, "
                  f"{machine.get('cpu', '')} ({machine.get('platform', '')})", ""]
        lines += [f"- stand-in: {s}" for s in rep.get("stand_ins", [])]
        lines += ["| case | knob | value | time (ms) | error | unit | default | front |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        references = [c for c in rep["cases"] if c.get("stands_for_knobs") and c.get("default") and _usable(c)]
        for knob, cases in _groups([rep]).items():
            # a front among alternatives only: rows of one value (the same setting on several
            # weathers or scenes) are listed, not compared
            usable = [c for c in cases if _usable(c)]
            if usable and not any(c.get("default") for c in cases):  # a knob one setting away from a reference
                units = {c["error_unit"] for c in usable}
                usable += [{**r, "value": ""} for r in references if r["error_unit"] in units]  # labelled "(default)"
            if len({str(c["value"]) for c in usable}) < 2:
                usable = []
            front = pareto_front([(c["time_ms"], c["error"]) for c in usable],
                                 higher_is_better=bool(usable) and usable[0]["error_unit"] in HIGHER_IS_BETTER_UNITS)
            on = {id(c): f for c, f in zip(usable, front)}
            for c in cases:
                f = on.get(id(c))
                mark = "" if f is None or len(usable) < 2 else ("yes" if f else "no")
                default = "yes" if c.get("default") else ""
                lines.append(f"| {c['name']} | {c['knob']} | {_cell(c['value'])} | {_cell(c['time_ms'])} | "
                             f"{_cell(c['error'])} | {c['error_unit']} | {default} | {mark} |")
                if c.get("default") and f is False and len(usable) > 1:
                    off_front.append((rep["suite"], knob[1], c["name"]))
            for c in usable:  # a reference borrowed by this knob: its place on this knob's front
                if c not in cases and on.get(id(c)) is False and len(usable) > 1:
                    off_front.append((rep["suite"], knob[1], f"{c['name']} (against {knob[2]})"))
            if len(usable) > 1:
                path = folder / "charts" / f"{rep['suite']}-{_slug(knob[1])}-{_slug(knob[2])}.png"
                _chart(path, rep["suite"], f"{knob[1]} ({knob[2]})", usable, front)
                charts.append(path)
        lines += [""] + [f"- {n}" for n in rep.get("notes", [])] + [""]
    for stale in set((folder / "charts").glob("*.png")) - set(charts):  # of suites or knobs no longer there
        stale.unlink()
    lines += ["## Defaults off their Pareto front", ""]
    lines += [f"- {s} / {k}: {name}" for s, k, name in off_front] or ["- none"]
    lines += ["", "## Charts", ""] + [f"![{p.stem}](charts/{p.name})" for p in charts]
    atomic_write_text(folder / "summary.md", "\n".join(lines) + "\n")
    return {"suites": [r["suite"] for r in reports], "charts": charts, "off_front": off_front}


def _slug(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in text)


def run_all(suites: dict[str, Callable[..., BenchReport]], *, out: Path, data_root: Path | None, quick: bool,
            echo: Callable[[str], None] = print, command: Callable[[str], str] | None = None) -> dict[str, Any]:
    """Run ``suites`` (name -> ``run(data_root=, quick=)``) in turn, writing ``out/<suite>.json`` after
    each, then :func:`summarize` ``out``; what :func:`summarize` returns, plus ``seconds`` per suite.

    Each JSON records the digests of the code it measured (:mod:`.code_version`) and, when given,
    ``command(suite)``: the command that runs that suite alone.
    """
    out.mkdir(parents=True, exist_ok=True)
    seconds = {}
    for name, run in suites.items():
        echo(f"bench --all: {name} ...")
        code = measured_code(name)
        t = time.perf_counter()
        report = run(data_root=data_root, quick=quick)
        seconds[name] = round(time.perf_counter() - t, 1)
        report.code, report.command = code, None if command is None else command(name)
        report.write(out / f"{name}.json")
        echo(f"bench --all: {name} done in {seconds[name]:.0f} s ({len(report.cases)} cases)")
    return {**summarize(out), "seconds": seconds}
