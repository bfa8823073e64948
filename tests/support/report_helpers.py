"""Reading a built report back: table cells from the HTML, edits of results folders."""

from __future__ import annotations

import html.parser
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.results import to_csv


class CellParser(html.parser.HTMLParser):
    """Every ``<td data-output=...>``: its attributes, shown value text and markers."""

    def __init__(self) -> None:
        super().__init__()
        self.cells: list[dict[str, Any]] = []
        self.images: list[str] = []
        self._cell: dict[str, Any] | None = None
        self._where = ""

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        if tag == "table" and "id" in a:
            self._table = a["id"]
        if tag == "img":
            self.images.append(a.get("src", ""))
        if tag == "td" and "data-output" in a:
            self._cell = {**a, "table": self._table, "value": "", "markers": ""}
        elif self._cell is not None and tag == "span" and a.get("class") == "v":
            self._where = "value"
        elif self._cell is not None and tag == "sup":
            self._where = "markers"

    def handle_endtag(self, tag: str) -> None:
        if tag in ("span", "sup"):
            self._where = ""
        elif tag == "td" and self._cell is not None:
            self.cells.append(self._cell)
            self._cell = None

    def handle_data(self, data: str) -> None:
        if self._cell is not None and self._where:
            self._cell[self._where] += data


def parse_report(path: Path) -> CellParser:
    """Parse a report file."""
    parser = CellParser()
    parser.feed(path.read_text(encoding="utf-8"))
    return parser


def result_values(folders: list[Path]) -> dict[tuple[str, str, str, str], float | None]:
    """(method, scene, weather, output) -> value as in each folder's results.json."""
    out: dict[tuple[str, str, str, str], float | None] = {}
    for folder in folders:
        doc = json.loads((folder / "results.json").read_text())
        for scene, ws in doc["results"].items():
            for weather, outputs in ws.items():
                for output, r in outputs.items():
                    out[(doc["config"]["method"], scene, weather, output)] = r["value"]
    return out


def expected_text(values: dict[tuple[str, str, str, str], float | None], cell: dict[str, str],
                  decimals: int) -> str | None:
    """The number a cell must show: its value (or the mean over the method's scenes) at ``decimals``."""
    method, scene, weather, output = (cell["data-method"], cell["data-scene"], cell["data-weather"],
                                      cell["data-output"])
    if scene == "mean":  # over every scene the method scored in this weather
        scenes = sorted({s for (m, s, w, _) in values if (m, w) == (method, weather)})
        found = [values.get((method, s, weather, output)) for s in scenes]
        if not found or any(v is None for v in found):
            return None
        value = float(np.mean(found))
    else:
        value = values.get((method, scene, weather, output))
        if value is None:
            return None
    return f"{value:.{decimals}f}"


def rewrite_results(folder: Path, edit: Callable[[dict[str, Any]], None]) -> None:
    """Apply ``edit`` to a folder's results.json and rewrite both results files consistently."""
    doc = json.loads((folder / "results.json").read_text())
    edit(doc)
    (folder / "results.json").write_text(json.dumps(doc))
    (folder / "results.csv").write_text(to_csv(doc))


def skip_output(doc: dict[str, Any], scene: str, weather: str, metric: str, reason: str) -> None:
    """Turn every output of ``metric`` in (scene, weather) into a skipped entry."""
    outputs = doc["results"][scene][weather]
    for name in [o for o, r in outputs.items() if r["metric"] == metric]:
        del outputs[name]
    doc["skipped"].append({"scene": scene, "weather": weather, "metric": metric, "reason": reason})
