"""The metric working resolution, the frame prefetcher and the shared source frames."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from wcbench.core.errors import InputError
from wcbench.core.working_size import METRIC_RESOLUTION, parse_metric_resolution, working_size
from wcbench.units import _SourceCache, prefetch


@pytest.mark.parametrize(("size", "res", "expected"), [
    ((1920, 1080), 960, (960, 540)),
    ((1080, 1920), 960, (540, 960)),  # the longer side, whichever it is
    ((1920, 1080), None, (1920, 1080)),
    ((480, 270), 960, (480, 270)),  # never enlarged
    ((1920, 1086), 960, (960, 543)),
    ((5000, 3), 100, (100, 1)),  # at least one pixel
])
def test_working_size(size, res, expected) -> None:
    assert working_size(size, res) == expected


def test_parse_metric_resolution() -> None:
    assert parse_metric_resolution("native") is None
    assert parse_metric_resolution(None) == METRIC_RESOLUTION
    assert parse_metric_resolution("720") == 720
    for bad in ("0", "31", "-5", "big", "9.5"):
        with pytest.raises(InputError, match="'native' or the longer side"):
            parse_metric_resolution(bad)


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


def test_source_cache_loads_once_and_keeps_its_budget() -> None:
    cache = _SourceCache(budget_bytes=3 * 100)
    loads = []

    def loader(k):
        def load():
            loads.append(k)
            return np.full(100, len(loads), np.uint8)
        return load

    a = cache.get(("a", (10, 10)), loader("a"))
    assert cache.get(("a", (10, 10)), loader("a")) is a and loads == ["a"]
    assert not a.flags.writeable  # shared by units: read only
    for k in "bcd":
        cache.get((k, (10, 10)), loader(k))
    cache.get(("a", (10, 10)), loader("a"))  # "a" was the least recently used: dropped, loaded again
    assert loads == ["a", "b", "c", "d", "a"]
    cache.get(("a", (5, 5)), loader("a5"))  # another size is another frame
    assert loads[-1] == "a5"
    cache.clear()
    cache.get(("d", (10, 10)), loader("d"))
    assert loads[-1] == "d"
