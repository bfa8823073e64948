"""tools/editor_against_truth.py: the findings' quick editor-against-truth numbers come from a tool
that runs, names what it measured, and measures the editor above the raw frames in fog."""

from __future__ import annotations

import re

import pytest
from tool_runs import run_tool

pytest.importorskip("torch")

TOOL = "editor_against_truth.py"


@pytest.mark.slow
@pytest.mark.model
def test_the_tool_scores_the_editor_above_the_raw_frames_in_fog():
    run = run_tool(TOOL, "--scenes", "synth_1", "--weathers", "fog", "--every", "10", timeout=600)
    assert run.returncode == 0, run.stderr
    assert "synth_1 (3 frames, every 10):" in run.stdout
    scores = {m[0]: float(m[1]) for m in re.findall(r"^\s+(\w+ fog)\s+([\d.]+) dB$", run.stdout, re.M)}
    assert set(scores) == {"editor fog", "raw fog"}
    assert scores["editor fog"] > scores["raw fog"] + 5.0


@pytest.mark.slow
@pytest.mark.model
def test_the_tool_splits_the_cast_shadows_by_the_editors_surfaces_where_a_scene_ships_them():
    run = run_tool(TOOL, "--scenes", "synth_hard_1", "--weathers", "fog", "--every", "10", timeout=600)
    assert run.returncode == 0, run.stderr
    scores = {m[0]: float(m[1]) for m in re.findall(r"^\s+(editor fog[\w ,]*?)\s+([\d.]+) dB$", run.stdout, re.M)}
    assert set(scores) == {"editor fog", "editor fog in shadow", "editor fog in shadow, facing up",
                           "editor fog in shadow, not facing up"}, run.stdout
    # the whole shadow lies between its two parts
    parts = sorted((scores["editor fog in shadow, facing up"], scores["editor fog in shadow, not facing up"]))
    assert parts[0] - 0.5 <= scores["editor fog in shadow"] <= parts[1] + 0.5


def test_a_step_below_one_is_refused():
    run = run_tool(TOOL, "--every", "0")
    assert run.returncode == 2 and "--every: a positive frame step was expected" in run.stderr
