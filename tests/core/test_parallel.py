"""Worker threads: order, exceptions in place, early stop, the thread count."""

from __future__ import annotations

import threading
import time

import pytest

from wcbench.core.parallel import THREADS_ENV, ordered_map, parallel_map, prefetch, thread_count


def test_ordered_map_keeps_order_whatever_finishes_first() -> None:
    def slow_for_small(x: int) -> int:
        time.sleep(0.002 * (10 - x % 10))  # early items finish last
        return x * x

    assert list(ordered_map(slow_for_small, range(40), workers=3, depth=5)) == [x * x for x in range(40)]
    assert parallel_map(slow_for_small, list(range(7)), workers=4) == [x * x for x in range(7)]
    assert parallel_map(slow_for_small, [], workers=4) == []


def test_ordered_map_raises_at_the_failing_item() -> None:
    def f(x: int) -> int:
        if x == 5:
            raise OSError("frame 5 unreadable")
        return x

    got = []
    with pytest.raises(OSError, match="frame 5 unreadable"):
        for x in ordered_map(f, range(20), workers=2):
            got.append(x)
    assert got == [0, 1, 2, 3, 4]


def test_ordered_map_abandoned_runs_at_most_depth_ahead_and_leaves_no_thread() -> None:
    started = []
    before = threading.active_count()

    def f(x: int) -> int:
        started.append(x)
        return x

    gen = ordered_map(f, range(1000), workers=2, depth=4)
    assert next(gen) == 0
    gen.close()
    assert len(started) <= 6
    assert threading.active_count() == before


def test_one_thread_runs_in_the_calling_thread() -> None:
    names = parallel_map(lambda _: threading.current_thread().name, [0, 1, 2], workers=1)
    assert set(names) == {threading.current_thread().name}


def test_thread_count_reads_the_environment(monkeypatch) -> None:
    monkeypatch.setenv(THREADS_ENV, "3")
    assert thread_count() == 3
    monkeypatch.delenv(THREADS_ENV)
    assert 1 <= thread_count() <= 4
    for bad in ("0", "-2", "two"):
        monkeypatch.setenv(THREADS_ENV, bad)
        with pytest.raises(ValueError, match="WCBENCH_THREADS must be a positive integer"):
            thread_count()


def test_prefetch_keeps_order_and_raises_in_place() -> None:
    assert list(prefetch(iter(range(100)), 3)) == list(range(100))

    def failing():
        yield 1
        yield 2
        raise OSError("disk gone")

    got = []
    with pytest.raises(OSError, match="disk gone"):
        for x in prefetch(failing(), 2):
            got.append(x)
    assert got == [1, 2]


def test_prefetch_stops_its_thread_when_abandoned() -> None:
    produced = []

    def endless():
        k = 0
        while True:
            produced.append(k)
            yield k
            k += 1

    before = threading.active_count()
    gen = prefetch(endless(), 2)
    assert next(gen) == 0
    gen.close()  # the consumer leaves early (an error in a metric)
    assert threading.active_count() == before
    assert len(produced) <= 5  # it ran at most a queue's length ahead
