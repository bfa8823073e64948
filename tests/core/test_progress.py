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


def test_time_left_comes_from_the_steady_items_not_the_slow_first_one(piped, monkeypatch, capsys):
    """A training's first step compiles the kernels (~60x a steady one); the estimate must not scale it."""
    clock = iter([0.0, 12.8, 13.0, 13.2])  # the start, then one reading per step
    monkeypatch.setattr(progress_module.time, "perf_counter", lambda: next(clock))
    monkeypatch.setenv("WCBENCH_PROGRESS_INTERVAL", "1e-9")
    bar = Progress(range(300), desc="training synth_000", total=300, unit="step", bar=False)
    bar.advance()  # step 0: 12.8 s with the compile
    bar.advance()  # step 1: 0.2 s
    bar.advance()  # step 2: 0.2 s
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[0] == "training synth_000: 1/300 steps, 12.8 s, time left: estimating"
    assert lines[1] == "training synth_000: 2/300 steps, 13.0 s, about 59.6 s left"  # 298 x 0.2 s
    assert lines[2] == "training synth_000: 3/300 steps, 13.2 s, about 59.4 s left"
