"""The report's tables, built with pandas from the folders' ``results.csv``, and their exports.

Layout as in the paper's tables (``weathercity_paper.tex``, Tab. 1): methods as rows, (weather x
metric) as columns, an arrow for the better direction, the best value of a column in bold and the
second underlined. A cell is the mean over the method's scenes when every scene has a number, else
a dash whose hover text says why. Every number of an output uses the same decimals everywhere (HTML,
CSV, LaTeX), so the three show identical text.
"""

from __future__ import annotations

import io
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from .checks import MARKERS, Flag
from .loading import ResultsFolder

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

DASH = "\u2013"
MEAN = "mean"
#: The row of the scene's raw frames scored against the ground truth (``results.json`` ``raw_frames``).
RAW_FRAMES = "raw frames (no edit)"
#: Methods whose rows are yardsticks, never ranked: they return the raw frames.
BASELINE_METHODS = ("identity",)
_DISPLAY = Path(__file__).with_name("display.toml")


@dataclass(frozen=True)
class Display:
    """Labels, groups and weather order (``display.toml``)."""

    weathers: tuple[str, ...]
    groups: dict[str, dict[str, str]]
    outputs: dict[str, dict[str, str]]
    summary: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def load(cls, path: Path = _DISPLAY) -> Display:
        """Read the display settings."""
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
        return cls(tuple(data["weathers"]), dict(data["groups"]), dict(data["outputs"]), dict(data.get("summary", {})))

    def summary_weathers(self, output: str) -> tuple[str, ...]:
        """The weathers the paper's summary column of ``output`` averages (empty: no such column)."""
        return tuple(self.summary.get("weathers", {}).get(output, ()))

    def label(self, output: str) -> str:
        """Column label of ``output``."""
        return str(self.outputs.get(output, {}).get("label", output))

    def group(self, output: str) -> str:
        """Table group of ``output`` (``"other"`` when unknown)."""
        return str(self.outputs.get(output, {}).get("group", "other"))

    def decimals(self, output: str) -> int | None:
        """Fixed decimals of ``output`` (``None``: chosen from the values)."""
        value = self.outputs.get(output, {}).get("decimals")
        return int(value) if value is not None else None

    def output_key(self, output: str) -> tuple[int, str]:
        """Sort key: the order of ``display.toml``, then by name."""
        names = list(self.outputs)
        return (names.index(output) if output in names else len(names), output)

    def weather_key(self, weather: str) -> tuple[int, str]:
        """Sort key: clear, rain, snow, fog, then others by name."""
        return (self.weathers.index(weather) if weather in self.weathers else len(self.weathers), weather)


@dataclass
class Cell:
    """One table cell (see module docstring)."""

    value: float | None
    text: str
    reason: str = ""
    rank: int = 0  # 1 best, 2 second
    flags: list[Flag] = field(default_factory=list)
    method: str = ""
    scene: str = MEAN
    weather: str = ""
    output: str = ""

    @property
    def title(self) -> str:
        """Hover text: the reason for a dash, then every flag's message."""
        return "\n".join([self.reason] * bool(self.reason) + [f.message for f in self.flags])

    def markers(self) -> list[tuple[str, str, str]]:
        """(kind, HTML marker, LaTeX marker) of the flag kinds on this cell."""
        kinds = sorted({f.kind for f in self.flags}, key=list(MARKERS).index)
        return [(k, *MARKERS[k]) for k in kinds]


@dataclass(frozen=True)
class _Where:
    """Which cell: method, scene (or ``mean``), weather, output."""

    method: str
    scene: str
    weather: str
    output: str

    def cell(self, value: float | None, text: str, reason: str = "") -> Cell:
        """A :class:`Cell` at this place."""
        return Cell(value, text, reason, method=self.method, scene=self.scene, weather=self.weather,
                    output=self.output)


@dataclass(frozen=True)
class Column:
    """A (weather, output) column with its label and better direction."""

    weather: str
    output: str
    label: str
    higher_is_better: bool | None

    @property
    def arrow(self) -> str:
        """``↑``, ``↓`` or nothing."""
        return {True: "\u2191", False: "\u2193", None: ""}[self.higher_is_better]


@dataclass
class Row:
    """A table row: header texts (method, and the scene in breakdown tables) and cells."""

    method: str
    scene: str
    cells: list[Cell]
    scene_rowspan: int = 0  # > 0 on the first row of a scene block
    baseline: bool = False  # a yardstick row (raw frames, identity): shown, never bold or underlined


@dataclass
class Table:
    """One rendered table (HTML template, CSV and LaTeX exports all read this)."""

    id: str
    title: str
    caption: str
    columns: list[Column]
    rows: list[Row]
    per_scene: bool = False
    notes: list[tuple[str, str]] = field(default_factory=list)  # (text, hover text)

    def weather_spans(self) -> list[tuple[str, int]]:
        """(weather, number of columns) for the first header row."""
        spans: list[tuple[str, int]] = []
        for c in self.columns:
            if spans and spans[-1][0] == c.weather:
                spans[-1] = (c.weather, spans[-1][1] + 1)
            else:
                spans.append((c.weather, 1))
        return spans


def tidy_results(folders: list[ResultsFolder]) -> pd.DataFrame:
    """All folders' ``results.csv`` rows in one frame with a ``method`` column (the row label)."""
    parts = [f.table.assign(method=f.label) for f in folders]
    df = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()
    return df.sort_values(["method", "scene", "weather", "output"], kind="stable").reset_index(drop=True)


def outputs_by_metric(df: pd.DataFrame) -> dict[str, set[str]]:
    """metric -> its outputs (a metric skipped everywhere has its own name as only output)."""
    out: dict[str, set[str]] = {}
    for metric, output in df[df.status != "skipped"][["metric", "output"]].itertuples(index=False):
        out.setdefault(metric, set()).add(output)
    for metric in df[df.status == "skipped"]["metric"]:
        out.setdefault(metric, {metric})
    return out


def format_value(value: float, decimals: int) -> str:
    """Fixed-point text (no ``-0.000``)."""
    text = f"{value:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def choose_decimals(values: list[float]) -> int:
    """Decimals that show the smallest magnitude of a column with 3 significant digits (2 to 6)."""
    finite = [abs(v) for v in values if math.isfinite(v) and v != 0]
    if not finite:
        return 3
    return int(min(6, max(2, 2 - math.floor(math.log10(min(finite))))))


class TableBuilder:
    """Builds every table of a report from the tidy results and the flags.

    Parameters
    ----------
    folders : list of ResultsFolder
        With labels assigned.
    display : Display
    flags : list of Flag, optional
        Markers for the cells (may be set later: :attr:`outputs_of` helps build them).
    """

    def __init__(self, folders: list[ResultsFolder], display: Display, flags: list[Flag] | None = None):
        self.display = display
        self.flags = list(flags or [])
        self.df = tidy_results(folders)
        self.outputs_of = outputs_by_metric(self.df)
        self.metric_of = {o: m for m, outs in self.outputs_of.items() for o in outs}
        self.methods = sorted(set(self.df["method"])) if len(self.df) else []
        self.scenes = sorted(set(self.df["scene"])) if len(self.df) else []
        present = self.df[self.df.status != "skipped"]
        hib: dict[str, bool | None] = {}
        for output, value in present[["output", "higher_is_better"]].itertuples(index=False):
            hib[output] = str(value).strip().lower() == "true"
        self.higher_is_better = hib
        self._rows = {(r.method, r.scene, r.weather, r.output): r for r in present.itertuples(index=False)}
        self._skips = {(r.method, r.scene, r.weather, r.metric): r.reason
                       for r in self.df[self.df.status == "skipped"].itertuples(index=False)}
        # scenes each method scored per weather: the denominator of its means
        self._scenes_of = self.df.groupby(["method", "weather"])["scene"].agg(lambda s: sorted(set(s))).to_dict()
        ok = present[present.status == "ok"]
        means = ok.groupby(["method", "weather", "output"])["value"].agg(["mean", "count"])
        self._means = {k: (float(m), int(n)) for k, (m, n) in means.iterrows()}
        all_values: dict[str, list[float]] = {}
        for output, value in ok[["output", "value"]].itertuples(index=False):
            all_values.setdefault(output, []).append(float(value))
        for (_, _, output), (m, _) in self._means.items():
            all_values.setdefault(output, []).append(m)
        self.decimals = {o: display.decimals(o) or choose_decimals(v) for o, v in all_values.items()}
        # yardsticks: the identity method's rows, and the raw frames against the truth each folder recorded
        self.baselines = {f.label for f in folders if f.method in BASELINE_METHODS}
        self._raw: dict[tuple[str, str, str], list[float | None]] = {}
        for f in folders:
            for scene, weathers in (f.doc.get("raw_frames") or {}).items():
                for weather, outputs in weathers.items():
                    for output, r in outputs.items():
                        value = r.get("value") if isinstance(r, dict) else None
                        self._raw.setdefault((scene, weather, output), []).append(
                            float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None)

    # -- cells ----------------------------------------------------------------------------------

    def _scene_cell(self, method: str, scene: str, weather: str, output: str) -> Cell:
        r = self._rows.get((method, scene, weather, output))
        base = _Where(method, scene, weather, output)
        if r is None:
            skip = self._skips.get((method, scene, weather, self.metric_of.get(output, output)))
            if skip is not None:
                return base.cell(None, DASH, f"skipped: {skip}")
            if scene not in self._scenes_of.get((method, weather), []):
                return base.cell(None, DASH, f"{method} was not scored on {scene} / {weather}")
            return base.cell(None, DASH, f"{output} was not computed for {method}")
        if r.status != "ok" or math.isnan(r.value):
            return base.cell(None, DASH, f"no value: {r.reason or 'not a finite number'}")
        value = float(r.value)
        return base.cell(value, format_value(value, self.decimals[output]))

    def _mean_cell(self, method: str, weather: str, output: str) -> Cell:
        scenes = self._scenes_of.get((method, weather), [])
        base = _Where(method, MEAN, weather, output)
        if not scenes:
            return base.cell(None, DASH, f"{method} was not scored in {weather}")
        parts = [self._scene_cell(method, s, weather, output) for s in scenes]
        missing = [(s, c.reason) for s, c in zip(scenes, parts) if c.value is None]
        if missing:
            reasons = sorted({r for _, r in missing})
            where = "" if len(missing) == len(scenes) else f" in {', '.join(s for s, _ in missing)}"
            return base.cell(None, DASH, f"{'; '.join(reasons)}{where}")
        value, count = self._means[(method, weather, output)]
        assert count == len(scenes)
        return base.cell(value, format_value(value, self.decimals[output]))

    def _raw_scene_cell(self, scene: str, weather: str, output: str) -> Cell:
        base = _Where(RAW_FRAMES, scene, weather, output)
        if weather == "clear":
            return base.cell(None, DASH, "the ground truth of clear is the raw frames themselves")
        found = self._raw.get((scene, weather, output))
        if not found:
            return base.cell(None, DASH, f"no results folder records the raw frames' {output} on {scene} / {weather} "
                                         "(no ground truth, or scored by an older wcbench)")
        if any(v is None for v in found):
            return base.cell(None, DASH, f"no value: the raw frames' {output} is not a finite number")
        texts = sorted({format_value(v, self.decimals.get(output, 3)) for v in found if v is not None})
        if len(texts) > 1:
            return base.cell(None, DASH, f"the results folders' raw-frames {output} differ ({', '.join(texts)}): "
                                         "scored at other sizes or settings")
        value = float(found[0])  # type: ignore[arg-type]
        return base.cell(value, texts[0])

    def _raw_mean_cell(self, weather: str, output: str) -> Cell:
        base = _Where(RAW_FRAMES, MEAN, weather, output)
        scenes = sorted({s for (_, s, w, o) in self._rows if (w, o) == (weather, output)})
        parts = [self._raw_scene_cell(s, weather, output) for s in scenes]
        missing = [(s, c.reason) for s, c in zip(scenes, parts) if c.value is None]
        if not scenes or missing:
            reasons = sorted({r for _, r in missing}) or [f"no method has {output} in {weather}"]
            return base.cell(None, DASH, "; ".join(reasons))
        value = sum(float(c.value) for c in parts if c.value is not None) / len(parts)
        return base.cell(value, format_value(value, self.decimals.get(output, 3)))

    def _raw_row(self, columns: list[Column], scene: str = MEAN) -> Row | None:
        """The raw frames' row of a ground-truth table (``None`` when every column is clear, whose
        truth is the raw frames)."""
        if all(c.weather == "clear" for c in columns):
            return None
        cells = [self._raw_mean_cell(c.weather, c.output) if scene == MEAN else
                 self._raw_scene_cell(scene, c.weather, c.output) for c in columns]
        return Row(RAW_FRAMES, scene, cells, baseline=True)

    def skipped_metrics(self) -> list[tuple[str, str, str]]:
        """What was not computed: (metric label, reason, where: methods and (scene / weather) units),
        one per metric and reason, in display order."""
        skips = self.df[self.df.status == "skipped"]
        out = []
        for (metric, reason), rows in skips.groupby(["metric", "reason"], sort=False):
            methods = sorted(set(rows["method"]))
            units = sorted({f"{s} / {w}" for s, w in rows[["scene", "weather"]].itertuples(index=False)})
            where = f"{', '.join(methods)}: {', '.join(units)}"
            out.append((self.display.label(str(metric)), str(reason), where, str(metric)))
        out.sort(key=lambda t: (self.display.output_key(t[3]), t[1]))
        return [(label, reason, where) for label, reason, where, _ in out]

    def _flag(self, cell: Cell, scenes: list[str]) -> Cell:
        if cell.value is not None:
            is_mean = cell.scene == MEAN
            cell.flags = [f for f in self.flags
                          if f.applies(method=cell.method, scenes=scenes, output=cell.output, is_mean=is_mean)]
        return cell

    # -- tables ---------------------------------------------------------------------------------

    def _columns(self, outputs: list[str]) -> tuple[list[Column], list[tuple[str, str]]]:
        """Columns of ``outputs`` for every weather. A column with no number for any method is left
        out and named in a note: (text, hover text with the reasons)."""
        weathers = sorted(set(self.df["weather"]), key=self.display.weather_key)
        columns: list[Column] = []
        dropped: dict[str, list[str]] = {}
        reasons: set[str] = set()
        for w in weathers:
            for o in outputs:
                cells = [self._scene_cell(m, s, w, o) for m in self.methods for s in self.scenes]
                if any(c.value is not None for c in cells):
                    columns.append(Column(w, o, self.display.label(o), self.higher_is_better.get(o)))
                else:
                    dropped.setdefault(w, []).append(self.display.label(o))
                    reasons.update(f"{self.display.label(o)} in {w}: {c.reason}" for c in cells if c.reason)
        if not dropped:
            return columns, []
        text = "Columns without a number for any method (hover for the reasons): " + "; ".join(
            f"{w}: {', '.join(labels)}" for w, labels in dropped.items()) + "."
        return columns, [(text, "\n".join(sorted(reasons)))]

    def _rank(self, cells: list[Cell], higher_is_better: bool | None) -> None:
        """Bold the best and underline the second of a column (by the shown text: ties share a rank);
        the yardstick rows (raw frames, identity) are left out: the marks go to the real methods."""
        if higher_is_better is None:
            return
        cells = [c for c in cells if c.method != RAW_FRAMES and c.method not in self.baselines]
        shown = sorted({float(c.text) for c in cells if c.value is not None}, reverse=higher_is_better)
        if len([c for c in cells if c.value is not None]) < 2:
            return
        for c in cells:
            if c.value is not None:
                pos = shown.index(float(c.text))
                c.rank = pos + 1 if pos < 2 else 0

    def groups(self) -> list[tuple[str, list[str]]]:
        """(group, outputs) in display order, runtime excluded."""
        outputs = sorted(set(self.df["output"]), key=self.display.output_key)
        out = []
        for g in self.display.groups:
            if g != "runtime":
                members = [o for o in outputs if self.display.group(o) == g]
                if members:
                    out.append((g, members))
        return out

    def _summary_cell(self, method: str, output: str, weathers: tuple[str, ...]) -> tuple[Cell, list[str]]:
        """The mean over ``weathers`` of the method's mean cells of ``output`` (the paper's summary),
        and the scenes behind it; a dash naming the weathers without a number."""
        base = _Where(method, MEAN, str(self.display.summary.get("label", "summary")), output)
        parts = {w: self._mean_cell(method, w, output) for w in weathers}
        missing = [w for w, c in parts.items() if c.value is None]
        scenes = sorted({s for w in weathers for s in self._scenes_of.get((method, w), [])})
        if missing:
            return base.cell(None, DASH, f"the summary needs {output} in {', '.join(weathers)}; no number in "
                                          f"{', '.join(missing)}"), scenes
        value = sum(float(c.value) for c in parts.values() if c.value is not None) / len(weathers)
        return base.cell(value, format_value(value, self.decimals[output])), scenes

    def main_table(self, group: str, outputs: list[str]) -> Table:
        """Methods x (weather x output), means over each method's scenes; then the paper's summary
        columns (the mean over weathers by its rule, ``display.toml`` ``[summary]``) of the outputs
        that have one, computed from the same cells."""
        columns, notes = self._columns(outputs)
        rows = [Row(m, MEAN, [self._flag(self._mean_cell(m, c.weather, c.output),
                                         self._scenes_of.get((m, c.weather), [])) for c in columns],
                    baseline=m in self.baselines)
                for m in self.methods]
        raw = self._raw_row(columns) if group == "reference" else None
        rows += [raw] if raw is not None else []
        label = str(self.display.summary.get("label", "summary"))
        summarised = [o for o in outputs if self.display.summary_weathers(o)
                      and any(c.output == o for c in columns)]
        for o in summarised:
            columns.append(Column(label, o, self.display.label(o), self.higher_is_better.get(o)))
            for row in rows:
                cell, scenes = self._summary_cell(row.method, o, self.display.summary_weathers(o))
                row.cells.append(self._flag(cell, scenes))
        for j, c in enumerate(columns):
            self._rank([r.cells[j] for r in rows], c.higher_is_better)
        g = self.display.groups[group]
        caption = f"{g['caption']} Scenes: {', '.join(self.scenes)}."
        if raw is not None:
            caption += f" Row '{RAW_FRAMES}': the scene's raw frames scored against the same truth, a yardstick."
        if summarised:
            caption += f" Columns '{label}': the mean over weathers of the cells beside them, by the paper's rule: " \
                       f"{self.display.summary.get('rule', '')}."
        return Table(f"t-{group}", g["title"], caption, columns, rows, notes=notes)

    def scene_table(self, group: str, outputs: list[str]) -> Table:
        """Per-scene breakdown: (scene, method) rows, ranks within each scene."""
        columns, notes = self._columns(outputs)
        rows: list[Row] = []
        for s in self.scenes:
            block = [Row(m, s, [self._flag(self._scene_cell(m, s, c.weather, c.output), [s]) for c in columns],
                         baseline=m in self.baselines)
                     for m in self.methods]
            raw = self._raw_row(columns, s) if group == "reference" else None
            block += [raw] if raw is not None else []
            for j, c in enumerate(columns):
                self._rank([r.cells[j] for r in block], c.higher_is_better)
            block[0].scene_rowspan = len(block)
            rows += block
        g = self.display.groups[group]
        return Table(f"s-{group}", f"{g['title']}: per scene", g["caption"], columns, rows, per_scene=True,
                     notes=notes)

    def runtime_outputs(self) -> list[str]:
        """Outputs shown in the runtime table (FPS)."""
        return sorted({o for o in self.df["output"] if self.display.group(o) == "runtime"}, key=self.display.output_key)

    def runtime_table(self) -> Table:
        """FPS per weather (mean over scenes) for the runtime section."""
        columns, notes = self._columns(self.runtime_outputs())
        rows = [Row(m, MEAN, [self._flag(self._mean_cell(m, c.weather, c.output),
                                         self._scenes_of.get((m, c.weather), [])) for c in columns])
                for m in self.methods]
        for j, c in enumerate(columns):
            self._rank([r.cells[j] for r in rows], c.higher_is_better)
        g = self.display.groups["runtime"]
        return Table("t-runtime", g["title"], g["caption"], columns, rows, notes=notes)

    def all_tables(self) -> list[Table]:
        """Main tables, then their per-scene breakdowns, then the runtime table."""
        groups = self.groups()
        tables = [self.main_table(g, outs) for g, outs in groups]
        tables += [self.scene_table(g, outs) for g, outs in groups]
        if self.runtime_outputs():
            tables.append(self.runtime_table())
        return [t for t in tables if t.columns]


# -- exports ------------------------------------------------------------------------------------

EXPORT_COLUMNS = ("table", "method", "scene", "weather", "output", "label", "value", "status", "rank", "flags",
                  "note")


def tables_frame(tables: list[Table]) -> pd.DataFrame:
    """Every cell of ``tables`` as one tidy frame, values as the shown text."""
    rows = []
    for t in tables:
        for r in t.rows:
            for c, cell in zip(t.columns, r.cells):
                rows.append({
                    "table": t.id, "method": cell.method, "scene": cell.scene, "weather": c.weather,
                    "output": c.output, "label": c.label, "value": cell.text if cell.value is not None else "",
                    "status": "ok" if cell.value is not None else "dash",
                    "rank": {1: "best", 2: "second"}.get(cell.rank, ""),
                    "flags": ";".join(sorted({f.topic for f in cell.flags})),
                    "note": cell.title,
                })
    return pd.DataFrame(rows, columns=list(EXPORT_COLUMNS))


def to_csv(tables: list[Table]) -> str:
    """CSV text of :func:`tables_frame` (the shown text of every cell, so the numbers equal the HTML)."""
    buf = io.StringIO()
    tables_frame(tables).to_csv(buf, index=False, lineterminator="\n")
    return buf.getvalue()


def _tex(text: str) -> str:
    out = []
    for ch in text:
        out.append({"_": r"\_", "%": r"\%", "&": r"\&", "#": r"\#", "$": r"\$", "{": r"\{", "}": r"\}",
                    "~": r"\textasciitilde{}", "^": r"\textasciicircum{}", "\\": r"\textbackslash{}"}.get(ch, ch))
    return "".join(out)


def _tex_cell(cell: Cell) -> str:
    if cell.value is None:
        return "--"
    text = {1: rf"\textbf{{{cell.text}}}", 2: rf"\underline{{{cell.text}}}"}.get(cell.rank, cell.text)
    marks = "".join(tex for _, _, tex in cell.markers())
    return text + (rf"\textsuperscript{{{marks}}}" if marks else "")


def table_to_latex(table: Table) -> str:
    """One booktabs ``tabular`` (needs ``\\usepackage{booktabs}``), as in the paper's Tab. 1."""
    lead = 2 if table.per_scene else 1
    spans = table.weather_spans()
    lines = [f"% {table.title}", rf"\begin{{tabular}}{{{'l' * lead}{'c' * len(table.columns)}}}", r"\toprule"]
    head = ["Scene", "Method"] if table.per_scene else ["Method"]
    lines.append(" & ".join([""] * (lead - 1) + [head[-1]] + [rf"\multicolumn{{{n}}}{{c}}{{{_tex(w)}}}"
                                                             for w, n in spans]) + r" \\")
    rules, col = [], lead + 1
    for _, n in spans:
        rules.append(rf"\cmidrule(lr){{{col}-{col + n - 1}}}")
        col += n
    lines.append("".join(rules))
    arrow = {True: r"$\uparrow$", False: r"$\downarrow$", None: ""}
    lines.append(" & ".join(head[:-1] + [""] + [_tex(c.label) + arrow[c.higher_is_better] for c in table.columns])
                 + r" \\")
    lines.append(r"\midrule")
    for i, r in enumerate(table.rows):
        if table.per_scene and r.scene_rowspan and i:
            lines.append(r"\midrule")
        lead_cells = ([_tex(r.scene) if r.scene_rowspan else ""] if table.per_scene else []) + [_tex(r.method)]
        lines.append(" & ".join(lead_cells + [_tex_cell(c) for c in r.cells]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines)


def to_latex(tables: list[Table], *, source: str) -> str:
    """All tables as booktabs LaTeX, with a header comment on markers and where they came from."""
    head = [
        f"% wcbench report tables from {source}",
        r"% \usepackage{booktabs}. Bold: best of a column; underlined: second; -- : no number (see the HTML",
        r"% report for the reason). \dag: computed with weights not verified as the published ones;",
        r"% \ddag: inputs or definitions differ across the merged results (see the report's checks).",
    ]
    return "\n".join(head) + "\n\n" + "\n\n".join(table_to_latex(t) for t in tables) + "\n"
