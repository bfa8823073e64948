"""Compile the numba kernels of the rasterizer, the particles, the fog and the editor now, once.

numba compiles each kernel on its first call and caches the machine code (beside the package, or
under ``NUMBA_CACHE_DIR``); without this step the first render of a fresh install waits over a
minute for it (about 80 s on 2 cores). Later processes load the cache in seconds. Safe to run
again: cached kernels only load.

Examples::

    wcbench compile
"""

from __future__ import annotations

import argparse
import sys

HELP = "compile the numba kernels now (first run only; cached for later processes)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """No options."""


def run(args: argparse.Namespace) -> int:
    """Compile (or load) every kernel, one line per step."""
    from wcbench.core.errors import InputError

    try:
        from wcbench.reference_model.kernel_warmup import compile_kernels
    except ImportError as exc:
        raise InputError(f"the kernels need the [model] extra (torch, numba): {exc}") from None
    print("compiling the numba kernels (first run only: numba caches them)", file=sys.stderr, flush=True)
    try:
        seconds = compile_kernels(echo=lambda line: print(line, file=sys.stderr, flush=True))
    except RuntimeError as exc:
        raise InputError(str(exc)) from None
    print(f"kernels ready in {sum(seconds.values()):.1f} s")
    return 0
