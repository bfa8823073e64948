"""A thread-safe least-recently-used cache with a budget in bytes.

Scoring keeps decoded frames (raw frames shared by a scene's weathers and methods, predictions
decoded once when they are checked) and the source sequence's flows in memory; both are
:class:`ByteBudgetCache` instances so that one rule bounds what a process holds.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any, Generic, TypeVar

import numpy as np

__all__ = ["ByteBudgetCache"]

V = TypeVar("V")


def _nbytes(value: Any) -> int:
    return int(value.nbytes)


class ByteBudgetCache(Generic[V]):
    """Values by key; the least recently used leave once their bytes exceed ``budget_bytes``.

    Parameters
    ----------
    budget_bytes : int
        Largest total size kept (a value larger than the budget is never kept).
    size_of : callable, optional
        Bytes of a value (default: its ``nbytes``).

    Notes
    -----
    Arrays are made read-only when kept: several users share them. ``hits`` and ``misses`` count
    :meth:`get` calls since the last :meth:`clear` (benchmarks and tests read them).
    """

    def __init__(self, budget_bytes: int, *, size_of: Callable[[V], int] = _nbytes):
        if budget_bytes < 0:
            raise ValueError(f"budget_bytes must be >= 0, got {budget_bytes}")
        self.budget = int(budget_bytes)
        self._size_of = size_of
        self._items: OrderedDict[Hashable, tuple[V, int]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    @property
    def nbytes(self) -> int:
        """Bytes held now."""
        return self._bytes

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key: Hashable) -> bool:
        with self._lock:
            return key in self._items

    def clear(self) -> None:
        """Forget every value and reset the counters (benchmarks start cold)."""
        with self._lock:
            self._items.clear()
            self._bytes = 0
            self.hits = self.misses = 0

    def get(self, key: Hashable, load: Callable[[], V]) -> V:
        """The value under ``key``; on a miss ``load()`` makes it and it is kept if it fits the
        budget (older values leave to make room). ``load`` runs outside the lock."""
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:
                self._items.move_to_end(key)
                self.hits += 1
                return hit[0]
            self.misses += 1
        value = load()
        self.put(key, value)
        return value

    def put(self, key: Hashable, value: V, *, fill_limit: int | None = None) -> bool:
        """Keep ``value`` under ``key``; whether it was kept.

        Without ``fill_limit`` the least recently used values leave to make room. With it, nothing
        leaves: the value is kept only if the cache then holds at most ``fill_limit`` bytes (values
        decoded ahead of use must not push out values in use).
        """
        size = self._size_of(value)
        if isinstance(value, np.ndarray):
            value.setflags(write=False)  # shared: nobody may change it
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return True
            limit = self.budget if fill_limit is None else min(self.budget, fill_limit)
            if size > limit or (fill_limit is not None and self._bytes + size > limit):
                return False
            self._items[key] = (value, size)
            self._bytes += size
            while self._bytes > self.budget:
                _, (_, old) = self._items.popitem(last=False)
                self._bytes -= old
            return True

    def take(self, key: Hashable) -> V | None:
        """Remove and return the value under ``key`` (``None`` when absent): for values used once."""
        with self._lock:
            item = self._items.pop(key, None)
            if item is None:
                return None
            self._bytes -= item[1]
            return item[0]
