"""Progress feedback: log lines when stderr is not a terminal, one summary per phase, nothing when off."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

from wcbench.core import progress as progress_module
from wcbench.core.progress import MAX_JUMP, Progress, TimeLeft, progress


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
    step): the first item and a warm-up outlier after it are left out; the first line comes at once."""
    readings = [0.0, 8.6, 13.1, *(13.1 + 0.1 * k for k in range(1, 8))]  # the start, then one per step
    clock = iter(readings)
    monkeypatch.setattr(progress_module.time, "perf_counter", lambda: next(clock))
    monkeypatch.setenv("WCBENCH_PROGRESS_INTERVAL", "1e-9")
    bar = Progress(range(300), desc="training synth_1", total=300, unit="step", bar=False,
                   starting="300 steps; the first compiles")
    for _ in range(9):
        bar.advance()
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[0] == "training synth_1: 300 steps; the first compiles"  # said before any step
    assert lines[1] == "training synth_1: 1/300 steps, 8.6 s, time left: estimating"
    assert all(line.endswith("time left: estimating") for line in lines[1:8])  # fewer than 6 steady steps
    # 8 steps: 6 steady ones of 0.1 s (the 4.5 s second step is warm-up), times the 292 left
    assert lines[8] == "training synth_1: 8/300 steps, 13.7 s, about 29.2 s left"
    assert lines[9] == "training synth_1: 9/300 steps, 13.8 s, about 29.1 s left"


def _replay(times, kinds, *, every):
    """(done, shown estimate, true time left) at every ``every``-th item of a TimeLeft fed ``times``."""
    est = TimeLeft(kinds, total=len(times))
    out = []
    for i, t in enumerate(times):
        est.record(t)
        if (i + 1) % every == 0 and i + 1 < len(times):
            out.append((i + 1, est.shown(), sum(times[i + 1:])))
    return out


def _training_times(n=300, *, seed=0):
    """A quick-profile-like schedule: weather every 2nd step (3x a clear step), the content loss every
    8th (+0.6 s), densification at 60/120/180/240 (+1.5 s), a 60 s first step (kernel compilation),
    a slower second step (the clear variant compiles) and 10 % jitter."""
    rng = np.random.default_rng(seed)
    kinds, times = [], []
    for it in range(n):
        weather, content, densify = it % 2 == 0, it % 8 == 0, (it + 1) % 60 == 0 and 60 <= it + 1 <= 240
        kinds.append("+".join(["weather" if weather else "clear"] + ["content"] * content + ["densify"] * densify))
        times.append((0.3 if weather else 0.1) + 0.6 * content + 1.5 * densify)
    times = [t * rng.uniform(0.9, 1.1) for t in times]
    times[0], times[1] = 60.0, 4.0
    return times, kinds


def test_time_left_weighs_each_kind_of_step_and_is_accurate_after_a_tenth():
    times, kinds = _training_times()
    marks = _replay(times, kinds, every=10)
    at_tenth = next(shown for done, shown, _ in marks if done == 30)
    truth = sum(times[30:])
    assert abs(at_tenth - truth) / truth < 0.1, (at_tenth, truth)
    # one kind for every step (a pooled rate) misses the schedule's mix
    pooled = TimeLeft(None, total=len(times))
    for t in times[:30]:
        pooled.record(t)
    assert pooled.estimate() is not None
    assert all(shown is not None and abs(shown - left) / left < 0.3 for done, shown, left in marks if done >= 30)


def test_successive_estimates_never_jump_by_more_than_2x():
    """Cheap steps, then a kind 50x dearer that shows its cost only once measured (its first item is
    warm-up): the raw estimate leaps, the shown one follows by at most 2x a print, both ways."""
    kinds = ["a"] * 40 + ["b"] * 60 + ["a"] * 100
    times = [20.0] + [0.1] * 39 + [5.0] * 60 + [0.1] * 100
    est = TimeLeft(kinds, total=len(times))
    raw, shown = [], []
    for t in times[:-1]:
        est.record(t)
        raw.append(est.estimate())
        shown.append(est.shown())
    pairs = [(a, b) for a, b in itertools.pairwise(shown) if a is not None and b is not None]
    assert len(pairs) > 150
    assert all(1 / MAX_JUMP - 1e-9 <= b / a <= MAX_JUMP + 1e-9 for a, b in pairs)
    raw_pairs = [(a, b) for a, b in itertools.pairwise(raw) if a is not None and b is not None]
    assert max(b / a for a, b in raw_pairs) > 10  # unclamped, the estimate leaps
    assert shown[-1] == pytest.approx(0.1)  # and the shown one catches up with the truth by the end
    # 4 steady items are needed (2 % of 200); the 20 s first item is left out of the first estimate
    assert shown[3] is None and shown[4] == pytest.approx(0.1 * 195)


def test_time_left_checks_its_inputs():
    with pytest.raises(ValueError, match="kinds has 2 items, total is 3"):
        TimeLeft(["a", "b"], total=3)
    with pytest.raises(ValueError, match="total must be >= 0"):
        TimeLeft(None, total=-1)
    est = TimeLeft(["a", "a", "b", "b"], total=4, min_steady=1)
    est.record(9.0)
    assert est.estimate() is None  # the first item alone is warm-up
    est.record(1.0)
    est.record(5.0)  # the first "b": warm-up of its kind; "b" counts at the steady mean until measured
    assert est.estimate() == pytest.approx(1.0)
