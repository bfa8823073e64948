"""Threads for work that releases the GIL: decoding, resizing and per-frame OpenCV/NumPy metrics.

``WCBENCH_THREADS`` sets how many threads (default: the CPU count, at most 4; ``1`` runs
everything in the calling thread, in order). Results come back in input order and an exception
is raised at its item's place, so parallel code reads like the sequential loop it replaces.
"""

from __future__ import annotations

import os
import queue
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, TypeVar

__all__ = ["THREADS_ENV", "ordered_map", "parallel_map", "prefetch", "thread_count"]

T = TypeVar("T")
R = TypeVar("R")

THREADS_ENV = "WCBENCH_THREADS"
_DEFAULT_MAX = 4


def thread_count() -> int:
    """Worker threads to use: ``$WCBENCH_THREADS``, else the CPU count capped at 4.

    Raises
    ------
    ValueError
        If ``WCBENCH_THREADS`` is not a positive integer.
    """
    env = os.environ.get(THREADS_ENV)
    if env is not None and env.strip():
        try:
            n = int(env)
        except ValueError:
            n = 0
        if n < 1:
            raise ValueError(f"{THREADS_ENV} must be a positive integer, got {env!r}")
        return n
    return max(1, min(os.cpu_count() or 1, _DEFAULT_MAX))


def ordered_map(fn: Callable[[T], R], items: Iterable[T], *, workers: int | None = None,
                depth: int | None = None) -> Iterator[R]:
    """``fn(item)`` for every item, computed by ``workers`` threads at most ``depth`` items ahead
    of the consumer, yielded in input order.

    An exception of ``fn`` is raised when its item's turn comes. A consumer that stops early
    (``close()``, or an exception in its loop) cancels what has not started and waits for what has.
    """
    workers = thread_count() if workers is None else max(1, workers)
    if workers == 1:
        yield from map(fn, items)
        return
    depth = max(workers, depth or 2 * workers)
    it = iter(items)
    pending: deque[Future[R]] = deque()
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="wcbench-map") as pool:
        try:
            for item in it:
                pending.append(pool.submit(fn, item))
                if len(pending) >= depth:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for f in pending:
                f.cancel()


def parallel_map(fn: Callable[[T], R], items: Sequence[T], *, workers: int | None = None) -> list[R]:
    """``[fn(x) for x in items]`` computed by up to ``workers`` threads (see :func:`ordered_map`)."""
    n = thread_count() if workers is None else max(1, workers)
    return list(ordered_map(fn, items, workers=min(n, max(1, len(items))), depth=len(items)))


def prefetch(items: Iterable[Any], depth: int) -> Iterator[Any]:
    """``items`` produced by a background thread, up to ``depth`` ahead, in order (for iterators
    that must run in order, like a video decoder). An exception of the producer is raised here,
    at its place in the sequence; a consumer that stops early stops the producer."""
    q: queue.Queue[tuple[bool, Any]] = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in items:
                while not stop.is_set():
                    try:
                        q.put((True, item), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put((False, None))
        except BaseException as exc:  # handed to the consumer, raised there
            q.put((False, exc))

    thread = threading.Thread(target=produce, name="wcbench-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            ok, item = q.get()
            if not ok:
                if item is not None:
                    raise item
                return
            yield item
    finally:
        stop.set()
        while thread.is_alive():  # unblock a producer waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                thread.join(0.05)
