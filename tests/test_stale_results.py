"""No stale result is ever served: every input that changes a number is in the keys, and edited
unit or results files are detected by their checksums (design §9)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from scene_fixtures import write_prediction_folder

from wcbench.cli import main


@pytest.fixture
def preds(demo_scene, tmp_path: Path) -> Path:
    return write_prediction_folder(demo_scene, tmp_path / "preds", ["clear", "rain"])


def _args(preds: Path, out: Path, *extra: str) -> list[str]:
    return ["evaluate", "--method", "folder", "--scenes", "demo", "--predictions", str(preds), "--out", str(out),
            "--weathers", "clear,rain", "--metrics", "temporal_flicker", "fps", "--no-progress", *extra]


def _doc(out: Path) -> dict:
    return json.loads((out / "results.json").read_text())


def test_another_fps_is_not_served_from_the_cache(preds, tmp_path):
    out = tmp_path / "out"
    assert main(_args(preds, out, "--fps", "10")) == 0
    assert main(_args(preds, out, "--fps", "25", "--overwrite")) == 0
    assert _doc(out)["results"]["demo"]["rain"]["fps"]["value"] == 25.0


def test_an_edited_info_json_is_not_up_to_date(preds, tmp_path, capsys):
    out = tmp_path / "out"
    (preds / "rain" / "info.json").write_text(json.dumps({"fps": 5.0}))
    assert main(_args(preds, out)) == 0
    (preds / "rain" / "info.json").write_text(json.dumps({"fps": 7.0}))
    capsys.readouterr()
    assert main(_args(preds, out)) == 2  # other inputs: never replaced silently
    assert "other inputs" in capsys.readouterr().err
    assert main(_args(preds, out, "--overwrite")) == 0
    assert _doc(out)["results"]["demo"]["rain"]["fps"]["value"] == 7.0


def test_an_edited_unit_file_is_recomputed(preds, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(_args(preds, out)) == 0
    truth = _doc(out)["results"]["demo"]["rain"]["temporal_flicker"]["value"]
    unit = out / ".work" / "demo" / "rain.json"
    rec = json.loads(unit.read_text())
    rec["result"]["outputs"]["temporal_flicker"]["value"] = 123.0
    unit.write_text(json.dumps(rec))
    (out / "results.json").unlink()
    capsys.readouterr()
    assert main(_args(preds, out)) == 0
    assert "1 computed, 1 reused" in capsys.readouterr().out
    assert _doc(out)["results"]["demo"]["rain"]["temporal_flicker"]["value"] == truth
    unit.write_text("[1, 2, 3]")  # not even a unit file: recomputed as well
    (out / "results.json").unlink()
    assert main(_args(preds, out)) == 0
    assert json.loads(unit.read_text())["result"]["outputs"]["temporal_flicker"]["value"] == truth


def test_an_edited_results_json_is_rebuilt_not_served(preds, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(_args(preds, out)) == 0
    doc = _doc(out)
    truth = doc["results"]["demo"]["rain"]["temporal_flicker"]["value"]
    doc["results"]["demo"]["rain"]["temporal_flicker"]["value"] = 0.0
    (out / "results.json").write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(_args(preds, out)) == 0
    assert "up to date" not in capsys.readouterr().out
    assert _doc(out)["results"]["demo"]["rain"]["temporal_flicker"]["value"] == truth
    assert main(_args(preds, out)) == 0
    assert "up to date" in capsys.readouterr().out  # intact again


def test_the_same_folders_relative_or_absolute_are_the_same_inputs(preds, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    assert main(_args(preds, out)) == 0
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    assert main(_args(Path(os.path.relpath(preds, tmp_path)), Path("out"))) == 0
    assert "up to date" in capsys.readouterr().out


def test_a_second_configuration_into_one_folder_is_refused_not_lost(preds, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(_args(preds, out)) == 0
    first = (out / "results.json").read_bytes()
    args = [a if a != "clear,rain" else "rain" for a in _args(preds, out)]
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err
    # what differs is named (here the weathers), not only the method and scenes that are the same
    assert "finished results of another configuration" in err and "weathers clear,rain there, rain asked" in err
    assert (out / "results.json").read_bytes() == first
