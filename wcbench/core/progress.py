"""Progress feedback on stderr: a tqdm bar on a terminal, periodic log lines when stderr is a file or
a pipe, and a one-line summary when a phase of a second or more ends (:func:`progress`); a line as a
phase without a count starts and ends (:func:`phase`); one-off lines (:func:`announce`).

``WCBENCH_PROGRESS=0`` turns all of it off, ``=1`` forces the bar; ``WCBENCH_PROGRESS_INTERVAL``
sets the seconds between log lines (default 10).
"""

from __future__ import annotations

import math
import os
import statistics
import sys
import time
from collections.abc import Iterable, Iterator, Sized
from contextlib import contextmanager
from typing import Any, Generic, TypeVar

T = TypeVar("T")

#: A phase shorter than this (seconds) ends without a summary line (it would only be noise).
SUMMARY_AFTER_S = 1.0
#: Items whose times the estimate of the time left looks at (the most recent).
_RECENT = 100


def _interval() -> float:
    try:
        value = float(os.environ.get("WCBENCH_PROGRESS_INTERVAL", "10"))
    except ValueError:
        value = 10.0
    return value if value > 0 else 10.0


def _seconds(s: float) -> str:
    return f"{s:.1f} s" if s < 120 else f"{int(s // 60)} min {int(s % 60):02d} s"


class Progress(Generic[T]):
    """Iterate ``items`` with feedback (see the module docstring); :func:`progress` makes one.

    ``set_postfix(**values)`` adds values (loss, PSNR...) to the bar, the log lines and the summary.
    """

    def __init__(self, items: Iterable[T], *, desc: str, total: int | None, unit: str, bar: bool):
        self.items, self.desc, self.unit = items, desc, unit
        if total is None and isinstance(items, Sized):
            total = len(items)
        self.total = total
        self.count, self.postfix = 0, ""
        self._item_s: list[float] = []  # seconds per item of the recent advances after the first
        self._start = self._last = self._previous = time.perf_counter()
        self._closed = False
        self._interval = _interval()
        self._bar: Any = None
        if bar:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=self.total, desc=desc, leave=False, unit=unit, disable=False)

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
        if self.count > 0 and n > 0:
            self._item_s.append((now - self._previous) / n)
            del self._item_s[:-_RECENT]
        self._previous = now
        self.count += n
        if self._bar is not None:
            self._bar.update(n)
            return
        if now - self._last >= self._interval:
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
            if self.total and self.count:
                # the first items pay for compiling and warming up (a training's first two steps took
                # 13 s where a steady one takes 0.1 s): the time left comes from the median time of the
                # recent items after the first, once there are a few (3, and 2 % of the total)
                if len(self._item_s) >= max(3, math.ceil(0.02 * self.total)):
                    rate = statistics.median(self._item_s)
                    text += f", about {_seconds(rate * (self.total - self.count))} left"
                else:
                    text += ", time left: estimating"
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
             unit: str = "frame") -> Iterable[T]:
    """``items`` with progress feedback counting ``unit`` (see the module docstring)."""
    env = os.environ.get("WCBENCH_PROGRESS")
    if not enabled or env == "0":
        return items
    bar = env == "1" or sys.stderr.isatty()
    return Progress(items, desc=desc, total=total, unit=unit, bar=bar)
