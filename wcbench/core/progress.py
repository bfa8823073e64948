"""Progress feedback on stderr: a tqdm bar on a terminal, periodic log lines when stderr is a file or
a pipe, and a one-line summary when a phase of a second or more ends (:func:`progress`); a line as a
phase without a count starts and ends (:func:`phase`); one-off lines (:func:`announce`).

The time left of a log line comes from :class:`TimeLeft`: the measured mean time of each kind of
item (a training's weather, content-loss and densification steps cost differently, and their
schedule is known in advance) times the items of that kind still to come, without the warm-up
items (compilation), and never more than 2x off the estimate printed before it (docs/guide.md,
"Progress").

``WCBENCH_PROGRESS=0`` turns all of it off, ``=1`` forces the bar; ``WCBENCH_PROGRESS_INTERVAL``
sets the seconds between log lines (default 10).
"""

from __future__ import annotations

import math
import os
import statistics
import sys
import time
from collections import Counter
from collections.abc import Hashable, Iterable, Iterator, Mapping, Sequence, Sized
from contextlib import contextmanager
from typing import Any, Generic, TypeVar

T = TypeVar("T")

#: A phase shorter than this (seconds) ends without a summary line (it would only be noise).
SUMMARY_AFTER_S = 1.0
#: Items of each kind whose times the estimate of the time left looks at (the most recent).
_RECENT = 20
#: The first items of a kind that may be warm-up (compiling a kernel variant, filling caches): after the
#: first, which is always left out, one of them is left out when it took over
#: :data:`_WARMUP_FACTOR` x the median of its kind (seen: 60 s for a first step, 0.4 s a steady one).
_WARMUP_ITEMS = 3
_WARMUP_FACTOR = 5.0
#: Largest factor between two successive estimates of the time left (either way).
MAX_JUMP = 2.0


def _interval() -> float:
    try:
        value = float(os.environ.get("WCBENCH_PROGRESS_INTERVAL", "10"))
    except ValueError:
        value = 10.0
    return value if value > 0 else 10.0


def _seconds(s: float) -> str:
    return f"{s:.1f} s" if s < 120 else f"{int(s // 60)} min {int(s % 60):02d} s"


class TimeLeft:
    """The time left of a sequence of items whose kinds are known in advance, from their measured times.

    The estimate is the sum over kinds of the mean time of the kind's recent steady items times the
    items of that kind still to come. Warm-up items are left out: the first of each kind (the first
    step of a training compiles its kernels; the first of another kind compiles that kind's variant)
    and, among its next few, any over :data:`_WARMUP_FACTOR` x the kind's median. A kind with no steady
    item yet counts at the mean of every steady item. Each shown estimate stays within
    :data:`MAX_JUMP` x the one shown before it (:meth:`shown`).

    Parameters
    ----------
    kinds : sequence of hashable, optional
        The kind of each item, in order (e.g. ``"clear"``, ``"weather+content"``); ``None``: every
        item is of one kind.
    total : int
        The number of items (``len(kinds)`` when given).
    min_steady : int, optional
        Steady items measured before there is an estimate (default: 3, and 2 % of ``total``).
    weights : mapping of hashable to float, optional
        Relative cost of each kind (e.g. its pixels): a kind with no steady item yet counts at the
        mean of every steady item's time per weight, times its weight, rather than at their mean
        (a progressive-resolution training's later, larger steps). ``None``: every kind weighs 1.

    Raises
    ------
    ValueError
        ``kinds`` of another length than ``total``, or a negative ``total``.
    """

    def __init__(self, kinds: Sequence[Hashable] | None = None, *, total: int, min_steady: int | None = None,
                 weights: Mapping[Any, float] | None = None):
        if total < 0:
            raise ValueError(f"total must be >= 0, got {total}")
        if kinds is not None and len(kinds) != total:
            raise ValueError(f"kinds has {len(kinds)} items, total is {total}")
        self.total = total
        self.kinds: list[Hashable] = list(kinds) if kinds is not None else [None] * total
        self.min_steady = max(3, math.ceil(0.02 * total)) if min_steady is None else max(1, int(min_steady))
        self.weights = dict(weights) if weights is not None else None
        if self.weights is not None and not all(w > 0 for w in self.weights.values()):
            raise ValueError(f"weights must be positive, got {self.weights}")
        self._times: dict[Hashable, list[float]] = {}  # every time of each kind, in order
        self._done = 0
        self._last_shown: float | None = None

    def record(self, seconds: float) -> None:
        """The next item took ``seconds``."""
        kind = self.kinds[self._done] if self._done < self.total else None
        times = self._times.setdefault(kind, [])
        times.append(float(seconds))
        if len(times) > _WARMUP_ITEMS + _RECENT:  # the warm-up items and the recent ones are all it reads
            del times[_WARMUP_ITEMS]
        self._done += 1

    def _steady(self, times: list[float]) -> list[float]:
        """``times`` of one kind without its warm-up items, the most recent :data:`_RECENT`."""
        later = times[1:]
        if not later:
            return []
        typical = statistics.median(later[_WARMUP_ITEMS - 1:] or later)
        head = [t for t in later[:_WARMUP_ITEMS - 1] if t <= _WARMUP_FACTOR * typical]
        return (head + later[_WARMUP_ITEMS - 1:])[-_RECENT:]

    def estimate(self) -> float | None:
        """Seconds left (unsmoothed), or ``None`` before :attr:`min_steady` steady items."""
        steady = {k: self._steady(v) for k, v in self._times.items()}
        pooled = [t for v in steady.values() for t in v]
        if len(pooled) < self.min_steady:
            return None
        to_come = Counter(self.kinds[self._done:])
        if self.weights is None:
            overall = statistics.fmean(pooled)
            return sum(n * (statistics.fmean(steady[k]) if steady.get(k) else overall) for k, n in to_come.items())
        weight = self.weights
        per_weight = statistics.fmean([t / weight.get(k, 1.0) for k, v in steady.items() for t in v])
        return sum(n * (statistics.fmean(steady[k]) if steady.get(k) else per_weight * weight.get(k, 1.0))
                   for k, n in to_come.items())

    def shown(self) -> float | None:
        """:meth:`estimate` held within :data:`MAX_JUMP` x the last value this returned (remembered)."""
        value = self.estimate()
        if value is None:
            return None
        if self._last_shown is not None and self._last_shown > 0:
            value = min(max(value, self._last_shown / MAX_JUMP), self._last_shown * MAX_JUMP)
        self._last_shown = value
        return value


class Progress(Generic[T]):
    """Iterate ``items`` with feedback (see the module docstring); :func:`progress` makes one.

    ``set_postfix(**values)`` adds values (loss, PSNR...) to the bar, the log lines and the summary.
    ``kinds`` (one per item, optional) are the items' kinds for the time left (:class:`TimeLeft`);
    ``starting`` is said at once as a log line (a first item that compiles may take a minute).
    """

    def __init__(self, items: Iterable[T], *, desc: str, total: int | None, unit: str, bar: bool,
                 kinds: Sequence[Hashable] | None = None, starting: str | None = None,
                 min_steady: int | None = None, weights: Mapping[Any, float] | None = None):
        self.items, self.desc, self.unit = items, desc, unit
        if total is None and isinstance(items, Sized):
            total = len(items)
        if total is None and kinds is not None:
            total = len(kinds)
        self.total = total
        self.count, self.postfix = 0, ""
        self._left = TimeLeft(kinds, total=total, min_steady=min_steady, weights=weights) if total else None
        self._start = self._last = self._previous = time.perf_counter()
        self._closed = False
        self._interval = _interval()
        self._bar: Any = None
        if bar:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=self.total, desc=desc, leave=False, unit=unit, disable=False)
        elif starting:
            print(f"{desc}: {starting}", file=sys.stderr, flush=True)

    def __iter__(self) -> Iterator[T]:
        try:
            for item in self.items:
                yield item
                self.advance()
        finally:
            self.close()

    def advance(self, n: int = 1) -> None:
        """Count ``n`` more items done (iteration does it; a caller stepping by hand may too)."""
        now = time.perf_counter()
        if self._left is not None:
            for _ in range(max(n, 0)):
                self._left.record((now - self._previous) / n)
        self._previous = now
        first = self.count == 0
        self.count += n
        if self._bar is not None:
            self._bar.update(n)
            return
        # a slow first item's line comes at once: it says how long set-up and compilation took
        if (first and now - self._start >= SUMMARY_AFTER_S) or now - self._last >= self._interval:
            self._last = now
            print(self._line(now, done=False), file=sys.stderr, flush=True)

    def set_postfix(self, **values: Any) -> None:
        """Show ``values`` beside the count."""
        self.postfix = ", ".join(f"{k} {v}" for k, v in values.items())
        if self._bar is not None:
            self._bar.set_postfix(**values)

    def close(self) -> None:
        """End the phase: clear the bar and print the summary (once)."""
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()
        now = time.perf_counter()
        if now - self._start >= SUMMARY_AFTER_S:
            print(self._line(now, done=True), file=sys.stderr, flush=True)

    def _line(self, now: float, *, done: bool) -> str:
        spent = now - self._start
        count = f"{self.count}/{self.total}" if self.total and not done else str(self.count)
        text = f"{self.desc}: {count} {self.unit}{'' if count == '1' else 's'}"
        if done:
            text += f" in {_seconds(spent)}"
        else:
            text += f", {_seconds(spent)}"
            if self._left is not None and self.count:
                left = self._left.shown()
                text += ", time left: estimating" if left is None else f", about {_seconds(left)} left"
        return text + (f" ({self.postfix})" if self.postfix else "")


def announce(message: str) -> None:
    """One line of feedback on stderr (silent under ``WCBENCH_PROGRESS=0``)."""
    if os.environ.get("WCBENCH_PROGRESS") != "0":
        print(message, file=sys.stderr, flush=True)


@contextmanager
def phase(desc: str, *, enabled: bool = True) -> Iterator[None]:
    """Say ``desc`` as a phase without a natural count starts (loading, initialising...) and, when it
    took :data:`SUMMARY_AFTER_S` or more, how long it took as it ends."""
    on = enabled and os.environ.get("WCBENCH_PROGRESS") != "0"
    if on:
        print(f"{desc} ...", file=sys.stderr, flush=True)
    start = time.perf_counter()
    yield
    spent = time.perf_counter() - start
    if on and spent >= SUMMARY_AFTER_S:
        print(f"{desc}: done in {_seconds(spent)}", file=sys.stderr, flush=True)


def progress(items: Iterable[T], *, desc: str, total: int | None = None, enabled: bool = True,
             unit: str = "frame", kinds: Sequence[Hashable] | None = None,
             starting: str | None = None, min_steady: int | None = None,
             weights: Mapping[Any, float] | None = None) -> Iterable[T]:
    """``items`` with progress feedback counting ``unit`` (see the module docstring).

    Parameters
    ----------
    items : iterable
    desc : str
        What is counted, the start of every line (``"training demo_street"``).
    total : int, optional
        The number of items (default ``len(items)`` when it has one).
    enabled : bool
        False: ``items`` as they are, silently.
    unit : str
        The counted noun (``"frame"``, ``"step"``).
    kinds : sequence of hashable, optional
        The kind of each item, for the time left (:class:`TimeLeft`).
    starting : str, optional
        A line said at once when the feedback is log lines (what the first item prepares).
    min_steady, weights : optional
        As :class:`TimeLeft`.

    Returns
    -------
    iterable
        ``items``, or a :class:`Progress` over them.
    """
    env = os.environ.get("WCBENCH_PROGRESS")
    if not enabled or env == "0":
        return items
    bar = env == "1" or sys.stderr.isatty()
    return Progress(items, desc=desc, total=total, unit=unit, bar=bar, kinds=kinds, starting=starting,
                    min_steady=min_steady, weights=weights)
