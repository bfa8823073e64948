"""Progress feedback: log lines when stderr is not a terminal, one summary per phase, nothing when off."""

from __future__ import annotations

import time

import pytest

from wcbench.core import progress as progress_module
from wcbench.core.progress import Progress, progress


@pytest.fixture
def piped(monkeypatch):
    """stderr as a pipe or file (pytest captures it), progress not forced off."""
    monkeypatch.delenv("WCBENCH_PROGRESS", raising=False)
    monkeypatch.setenv("WCBENCH_PROGRESS_INTERVAL", "0.01")


def _slow(n, seconds):
    for i in range(n):
        time.sleep(seconds)
        yield i


def test_without_a_terminal_progress_goes_out_as_log_lines_and_ends_with_one_summary(piped, monkeypatch, capsys):
    monkeypatch.setattr(progress_module, "SUMMARY_AFTER_S", 0.0)
    bar = progress(_slow(5, 0.02), desc="scoring demo rain", total=5)
    assert isinstance(bar, Progress)
    assert list(bar) == [0, 1, 2, 3, 4]
    bar.close()  # a second close prints nothing more
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith("scoring demo rain: 5 frames in ") and lines[-1].endswith(" s")
    periodic = lines[:-1]
    assert periodic, "a log line every interval"
    assert all(line.startswith("scoring demo rain: ") and "/5 frames" in line and "left" in line for line in periodic)
    assert "\r" not in "".join(lines) and "\x1b" not in "".join(lines)  # no bar drawing in a log


def test_values_set_on_the_way_show_in_the_summary(piped, monkeypatch, capsys):
    monkeypatch.setattr(progress_module, "SUMMARY_AFTER_S", 0.0)
    bar = progress(range(3), desc="training demo", unit="step")
    for _ in bar:
        bar.set_postfix(loss="0.0123", psnr="28.10")  # type: ignore[attr-defined]
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("training demo: 3 steps in ") and last.endswith("(loss 0.0123, psnr 28.10)")


def test_short_phases_leave_no_summary_and_off_means_silent(piped, monkeypatch, capsys):
    assert list(progress(range(3), desc="quick")) == [0, 1, 2]
    assert capsys.readouterr().err == ""  # under SUMMARY_AFTER_S: nothing to say
    monkeypatch.setenv("WCBENCH_PROGRESS", "0")
    items = [1, 2]
    assert progress(items, desc="off") is items
    assert progress(items, desc="off", enabled=True) is items
    monkeypatch.delenv("WCBENCH_PROGRESS")
    assert progress(items, desc="disabled", enabled=False) is items


def test_time_left_comes_from_the_steady_items_not_the_slow_first_ones(piped, monkeypatch, capsys):
    """A training's first steps compile the kernels (seen: 13.1 s for the first two of 300, then 0.1 s a
    step): the estimate waits for a few steps after the first and takes their median."""
    readings = [0.0, 8.6, 13.1, *(13.1 + 0.1 * k for k in range(1, 7))]  # the start, then one per step
    clock = iter(readings)
    monkeypatch.setattr(progress_module.time, "perf_counter", lambda: next(clock))
    monkeypatch.setenv("WCBENCH_PROGRESS_INTERVAL", "1e-9")
    bar = Progress(range(300), desc="training synth_000", total=300, unit="step", bar=False)
    for _ in range(8):
        bar.advance()
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[0] == "training synth_000: 1/300 steps, 8.6 s, time left: estimating"
    assert all(line.endswith("time left: estimating") for line in lines[:6])  # fewer than 6 steady steps
    # 7 steps: the median of the 6 after the first (4.5 s once, then 0.1 s) times the 293 left
    assert lines[6] == "training synth_000: 7/300 steps, 13.6 s, about 29.3 s left"
    assert lines[7] == "training synth_000: 8/300 steps, 13.7 s, about 29.2 s left"
