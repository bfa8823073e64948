"""Compile the numba kernels of the rasterizer, the particles, the fog and the editor now, once.

numba compiles each kernel on its first call and caches the machine code (beside the package, or
under ``NUMBA_CACHE_DIR``); without this step the first render of a fresh install waits over a
minute for it (about 80 s on 2 cores). Later processes load the cache in seconds. Safe to run
again: cached kernels only load.

Examples::

    wcbench compile
    wcbench compile --nice 10    # at a lower CPU priority, as a first run starts it beside its own work
"""

from __future__ import annotations

import argparse
import os
import sys

HELP = "compile the numba kernels now (first run only; cached for later processes)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--nice``."""
    parser.add_argument("--nice", type=int, default=0, metavar="N",
                        help="lower this process's CPU priority by N first (0-19; where the OS has it): a "
                             "first `wcbench run` starts `compile --nice 10` beside its own work, so that it "
                             "takes only the cycles the run leaves idle")


def run(args: argparse.Namespace) -> int:
    """Compile (or load) every kernel, one line per step."""
    from wcbench.core.errors import InputError

    if not 0 <= args.nice <= 19:
        raise InputError(f"--nice {args.nice}: a niceness increment from 0 to 19 was expected")
    if args.nice and hasattr(os, "nice"):
        os.nice(args.nice)

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
