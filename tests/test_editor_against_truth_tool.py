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


def test_a_step_below_one_is_refused():
    run = run_tool(TOOL, "--every", "0")
    assert run.returncode == 2 and "--every: a positive frame step was expected" in run.stderr
