"""Embedding cache keyed by content hash: memory first, then one ``.npy`` per vector on disk.

A frame is embedded once per (weights, backend, preprocessing): scoring a second method on the
same scene finds the source frames' embeddings here. The namespace (a description of weights,
backend and preprocessing) picks a sub-folder, so changing any of them never reuses stale
vectors. Disk writes are atomic (temp file + rename), so concurrent or killed runs never leave a
torn file; an unreadable file counts as a miss and is rewritten.
"""

from __future__ import annotations

import hashlib
import os
from collections import OrderedDict
from pathlib import Path

import numpy as np

from wcbench.core.storage import atomic_write, atomic_write_text, sha256_bytes


def array_key(a: np.ndarray) -> str:
    """sha256 of an array's dtype, shape and bytes (the content hash of a frame or token row)."""
    a = np.ascontiguousarray(a)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.data)
    return h.hexdigest()


class EmbeddingCache:
    """Vectors keyed by content hash.

    Parameters
    ----------
    directory : path-like, optional
        Root of the disk cache (e.g. ``ModelStore.cache_dir / "clip-embeddings"``); ``None``
        keeps vectors in memory only.
    namespace : str
        Everything that changes the vectors (model, weights hash, backend, preprocessing).
    max_memory : int
        Vectors kept in memory (least recently used are dropped first).

    Attributes
    ----------
    hits, disk_hits, misses : int
        Lookup counts since creation (a disk hit also counts as a hit).
    """

    def __init__(
        self, directory: str | os.PathLike[str] | None = None, *, namespace: str, max_memory: int = 65536
    ):
        self.namespace = namespace
        self.directory = (
            Path(directory) / sha256_bytes(namespace.encode())[:24] if directory is not None else None
        )
        self.max_memory = max_memory
        self._mem: OrderedDict[str, np.ndarray] = OrderedDict()
        self.hits = self.disk_hits = self.misses = 0
        self._described = False

    def _file(self, key: str) -> Path:
        assert self.directory is not None
        return self.directory / key[:2] / f"{key}.npy"

    def _remember(self, key: str, value: np.ndarray) -> None:
        self._mem[key] = value
        self._mem.move_to_end(key)
        while len(self._mem) > self.max_memory:
            self._mem.popitem(last=False)

    def get(self, key: str) -> np.ndarray | None:
        """The cached vector (read-only float32 [E]) or ``None``."""
        value = self._mem.get(key)
        if value is not None:
            self._mem.move_to_end(key)
            self.hits += 1
            return value
        if self.directory is not None:
            path = self._file(key)
            try:
                value = np.load(path, allow_pickle=False)
            except (OSError, ValueError):
                value = None
            if value is not None:
                value.setflags(write=False)
                self._remember(key, value)
                self.hits += 1
                self.disk_hits += 1
                return value
        self.misses += 1
        return None

    def put(self, key: str, value: np.ndarray) -> None:
        """Store ``value`` (a vector [E]) under ``key`` in memory and, if enabled, on disk."""
        value = np.array(value, dtype=np.float32)
        value.setflags(write=False)
        self._remember(key, value)
        if self.directory is None:
            return
        if not self._described:
            # A human-readable note of what the hashed folder name stands for.
            atomic_write_text(self.directory / "namespace.txt", self.namespace + "\n")
            self._described = True
        atomic_write(self._file(key), lambda fh: np.save(fh, value, allow_pickle=False))

    def __len__(self) -> int:
        return len(self._mem)
