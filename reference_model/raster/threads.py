"""One thread count for every pool the rasterizer and the training step use: numba, torch, BLAS.

A rasterizer call runs numba kernels (numba's own pool), then torch ops (ATen's OpenMP pool, which
also sizes MKL), and NumPy calls BLAS (OpenBLAS's pool). Setting only one of them leaves the others
at the CPU count, so a "1-thread" measurement would still use every core in the torch glue, and
the per-phase speed-ups of ``wcbench bench raster`` / ``bench model`` (docs/design.md §8) would be
wrong. :func:`set_threads` sets all three; :func:`threads` does so for a block and restores.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Iterator
from contextlib import contextmanager

import torch

__all__ = ["get_threads", "max_threads", "set_threads", "threads"]

#: Symbols of OpenBLAS builds (NumPy's wheels bundle ``scipy_openblas64_``) that set its pool size.
_BLAS_SETTERS = ("scipy_openblas_set_num_threads64_", "openblas_set_num_threads64_", "openblas_set_num_threads",
                 "scipy_openblas_set_num_threads")
_BLAS_GETTERS = ("scipy_openblas_get_num_threads64_", "openblas_get_num_threads64_", "openblas_get_num_threads",
                 "scipy_openblas_get_num_threads")


_BLAS: list[ctypes.CDLL | None] = []  # found once per process


def _openblas() -> ctypes.CDLL | None:
    """The OpenBLAS library this process loaded (through NumPy), or ``None``."""
    if _BLAS:
        return _BLAS[0]
    import numpy  # noqa: F401  (loads NumPy's BLAS, so that it is in the process's maps)

    found = None
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as fh:
            paths = {line.split()[-1] for line in fh if "openblas" in line.lower() and "/" in line}
    except OSError:  # not Linux: BLAS keeps its pool (torch and numba are still set)
        paths = set()
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path, mode=getattr(os, "RTLD_NOLOAD", 0) | ctypes.RTLD_GLOBAL)
        except OSError:
            continue
        if any(hasattr(lib, name) for name in _BLAS_SETTERS):
            found = lib
            break
    _BLAS.append(found)
    return found


def _blas_threads(n: int | None = None) -> int | None:
    """OpenBLAS's pool size, after setting it to ``n`` when given; ``None`` without OpenBLAS."""
    lib = _openblas()
    if lib is None:
        return None
    if n is not None:
        for name in _BLAS_SETTERS:
            if hasattr(lib, name):
                getattr(lib, name)(ctypes.c_int(n))
                break
    for name in _BLAS_GETTERS:
        if hasattr(lib, name):
            return int(getattr(lib, name)())
    return None


def max_threads() -> int:
    """The most threads numba can run (``NUMBA_NUM_THREADS``, fixed when numba starts: the CPU count)."""
    import numba

    return int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # set at import from the environment


def get_threads() -> dict[str, int | None]:
    """Current pool sizes: ``{"numba": n, "torch": n, "blas": n or None when not found}``."""
    import numba

    return {"numba": int(numba.get_num_threads()), "torch": int(torch.get_num_threads()),
            "blas": _blas_threads()}


def set_threads(n: int) -> int:
    """Size numba's, torch's (OpenMP and MKL) and OpenBLAS's pools to ``n`` threads.

    Parameters
    ----------
    n : int
        Threads wanted, >= 1. numba cannot exceed the count it started with (:func:`max_threads`),
        so ``n`` is clamped there for every pool: all three then run the same count.

    Returns
    -------
    int
        The count set (``min(n, max_threads())``).

    Raises
    ------
    ValueError
        If ``n`` < 1.
    """
    import numba

    if int(n) < 1:
        raise ValueError(f"thread count must be >= 1, got {n}")
    k = min(int(n), max_threads())
    numba.set_num_threads(k)
    torch.set_num_threads(k)
    _blas_threads(k)
    return k


@contextmanager
def threads(n: int | None) -> Iterator[int]:
    """Run a block with :func:`set_threads` ``(n)``, restoring the previous sizes after it.

    ``None`` leaves the pools as they are (the block gets the current numba count).
    """
    before = get_threads()
    if n is None:
        yield int(before["numba"] or 1)
        return
    k = set_threads(n)
    try:
        yield k
    finally:
        import numba

        numba.set_num_threads(int(before["numba"] or 1))
        torch.set_num_threads(int(before["torch"] or 1))
        if before["blas"]:
            _blas_threads(int(before["blas"]))
