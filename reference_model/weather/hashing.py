"""Counter-based random numbers: the same value for the same (seed, index, counter, stream).

A particle's horizontal re-draw on its n-th vertical wrap must not depend on which frames were
rendered before (docs/design.md §7): a counter-based generator (splitmix64 chained over the
keys) gives it as a pure function of its keys. :mod:`.particle_kernels` has the numba twin.
"""

from __future__ import annotations

import numpy as np

__all__ = ["hash_uniform", "splitmix64"]


def hash_uniform(seed: int, index: np.ndarray, counter: np.ndarray, stream: int) -> np.ndarray:
    """Counter-based uniform numbers in [0, 1): splitmix64 of (seed, index, counter, stream).

    Used for the horizontal re-draw on wrap, so that the value for wrap n of particle i never
    depends on which frames were rendered before.
    """
    with np.errstate(over="ignore"):
        x = np.uint64(seed & 0xFFFFFFFFFFFFFFFF) * np.uint64(0x9E3779B97F4A7C15)
        x = splitmix64(x ^ np.asarray(index).astype(np.uint64))
        x = splitmix64(x ^ np.asarray(counter).astype(np.int64).astype(np.uint64))
        x = splitmix64(x ^ np.uint64(stream))
    return (x >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def splitmix64(x: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        x = np.asarray(x, np.uint64) + np.uint64(0x9E3779B97F4A7C15)
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return x ^ (x >> np.uint64(31))

