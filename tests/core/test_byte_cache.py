"""The byte-budget LRU cache behind the shared frames and flows."""

from __future__ import annotations

import numpy as np
import pytest

from wcbench.core.byte_cache import ByteBudgetCache


def test_cache_loads_once_and_keeps_its_budget() -> None:
    cache = ByteBudgetCache(budget_bytes=3 * 100)
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
    assert (cache.hits, cache.misses) == (0, 1)  # clear() resets the counters


def test_fill_limit_never_pushes_out_and_take_frees() -> None:
    cache: ByteBudgetCache[np.ndarray] = ByteBudgetCache(budget_bytes=400)
    assert cache.put("a", np.zeros(100, np.uint8))
    assert cache.put("b", np.zeros(100, np.uint8), fill_limit=200)
    assert not cache.put("c", np.zeros(100, np.uint8), fill_limit=200)  # would exceed the limit: refused
    assert "a" in cache and "b" in cache and "c" not in cache and cache.nbytes == 200
    taken = cache.take("b")
    assert taken is not None and "b" not in cache and cache.nbytes == 100
    assert cache.take("b") is None
    assert not cache.put("big", np.zeros(500, np.uint8))  # larger than the budget: never kept
    assert cache.nbytes == 100


def test_values_without_nbytes_use_size_of() -> None:
    cache: ByteBudgetCache[str] = ByteBudgetCache(budget_bytes=10, size_of=len)
    cache.put("x", "12345")
    cache.put("y", "123456")  # 11 bytes: "x" leaves
    assert "x" not in cache and "y" in cache
    with pytest.raises(ValueError, match="budget_bytes must be >= 0"):
        ByteBudgetCache(-1)
