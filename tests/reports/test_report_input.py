"""Bad input gets an InputError naming the file and what was expected (exit code 2 in the CLI);
the report package reads result files only."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

from wcbench import results
from wcbench.cli import main
from wcbench.core.errors import InputError
from wcbench.reports import build_report, loading

REPORTS = Path(loading.__file__).parent


def test_folder_without_results(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"empty: no results.json \(expected the --out folder"):
        build_report([tmp_path / "empty"], tmp_path / "r.html")
    assert not (tmp_path / "r.html").exists()


@pytest.mark.parametrize(("content", "message"), [
    ("{not json", "not a readable results file"),
    (json.dumps({"kind": "other"}), "not a wcbench results file"),
    (json.dumps({"kind": "wcbench-results", "schema_version": 99}), "results of schema version 99; this report reads"),
    (json.dumps({"kind": "wcbench-results", "schema_version": 1, "results": {}}), "malformed results file: lacks"),
    (json.dumps({"kind": "wcbench-results", "schema_version": 1, "created": "", "config": {}, "inputs": {},
                 "skipped": [], "results": {"s": {"rain": {"clip_s": 0.5}}}}),
     r"malformed results file: results\['s'\]\['rain'\] is not"),
])
def test_corrupt_or_foreign_results_json(tmp_path, content, message):
    (tmp_path / "results.json").write_text(content)
    with pytest.raises(InputError, match=message) as exc:
        build_report([tmp_path], tmp_path / "r.html")
    assert str(tmp_path / "results.json") in str(exc.value)


def test_missing_or_edited_results_csv(small, tmp_path):
    folder = small["tint"]
    text = (folder / "results.csv").read_text()
    (folder / "results.csv").unlink()
    with pytest.raises(InputError, match=r"results\.csv: missing"):
        build_report([folder], tmp_path / "r.html")
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if ",ok," in line)
    row = lines[k].split(",")
    row[4] = "0.5" if row[4] != "0.5" else "0.25"  # a changed number
    lines[k] = ",".join(row)
    (folder / "results.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"results\.csv disagrees with results\.json"):
        build_report([folder], tmp_path / "r.html")


def test_cli_exit_code_2_and_message(tmp_path, capsys):
    assert main(["report", str(tmp_path), "--out", str(tmp_path / "r.html")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("wcbench report: error:") and "no results.json" in err
    assert main(["report", str(tmp_path), "--out", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err


def test_same_folder_twice_and_bad_animation_count(small, tmp_path):
    with pytest.raises(InputError, match="given twice"):
        build_report([small["tint"], small["tint"] / "results.json"], tmp_path / "r.html")
    with pytest.raises(InputError, match=r"animation frames must be in 0\.\.12"):
        build_report([small["tint"]], tmp_path / "r.html", animation_frames=13)


def test_format_constants_match_the_writer():
    assert loading.RESULTS_KIND == results.KIND
    assert loading.RESULTS_SCHEMA_VERSION == results.SCHEMA_VERSION
    assert loading.CSV_COLUMNS == results.CSV_COLUMNS
    from wcbench.bench import schema as benchmark
    from wcbench.reports import builder

    assert (builder.BENCH_SCHEMA, builder.BENCH_SCHEMA_VERSION) == (benchmark.SCHEMA, benchmark.SCHEMA_VERSION)


def test_reports_import_only_core_utilities():
    """The report reads files only: no metrics, models, evaluation, methods, scenes or CLI."""
    allowed = {"wcbench.core.errors", "wcbench.core.storage", "wcbench.core.environment"}  # the core layer
    for path in sorted(REPORTS.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
            for name in names:
                assert not name.startswith("wcbench") or name in allowed, f"{path.name} imports {name}"
    code = ("import sys, wcbench.reports; "
            "print(sorted(m for m in sys.modules if m.startswith('wcbench.') and m.split('.')[1] not in "
            "('reports', 'core')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
