"""The numba kernels compiled in a second process while a first run works (docs/design.md §8).

A fresh install's first ``wcbench run --method weathercity`` spends most of its time compiling the
reference model's kernels, each on its first call and one after the other: the training's first
step alone waits close to a minute, single-threaded, while the machine's other cores idle. When
the kernels are not compiled yet (no stamp of
:func:`~wcbench.reference_model.kernel_warmup.compile_kernels`), :func:`kernels_compiled_aside`
starts ``wcbench compile --nice 10`` in a child process on the spare core: the run's own work (fetching
weights, generating or analysing the scene, editing its frames) goes on, and the kernels it
reaches later load from numba's cache instead of compiling. A kernel the run reaches first is
compiled by both (numba's cache files are written whole, so either copy serves). The child is
stopped when the block ends; what it compiled stays cached. ``WCBENCH_BACKGROUND_COMPILE=0`` turns
it off.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from wcbench.core.paths import cache_dir

__all__ = ["BACKGROUND_COMPILE_ENV", "kernels_compiled_aside"]

#: Set to ``0`` to compile every kernel in the process that first calls it, as numba does alone.
BACKGROUND_COMPILE_ENV = "WCBENCH_BACKGROUND_COMPILE"
#: The child's niceness increment (``wcbench compile --nice``).
NICENESS = 10


def _wanted() -> bool:
    """Whether a background compile would help here: allowed, a spare core, the kernels importable and
    not compiled yet."""
    if os.environ.get(BACKGROUND_COMPILE_ENV, "1").strip() == "0" or (os.cpu_count() or 1) < 2:
        return False
    try:
        from wcbench.reference_model.kernel_warmup import kernels_compiled
    except ImportError:  # no [model] extra: the run fails with its own message, or needs no kernels
        return False
    return not kernels_compiled()


@contextmanager
def kernels_compiled_aside(*, echo: Callable[[str], None] | None = None) -> Iterator[subprocess.Popen[bytes] | None]:
    """Compile the numba kernels in a child process for the duration of the block, if they are not yet.

    Parameters
    ----------
    echo : callable, optional
        Called with one line when the child starts (default: printed to standard error).

    Yields
    ------
    subprocess.Popen or None
        The child (``wcbench compile``, its output in ``<wcbench cache>/kernels/compile.log``), or
        None when nothing is to be done (kernels compiled, one core, the ``[model]`` extra missing,
        ``WCBENCH_BACKGROUND_COMPILE=0``).
    """
    if not _wanted():
        yield None
        return
    log_path = cache_dir() / "kernels" / "compile.log"
    try:
        log_path.parent.mkdir(parents=True, exist_ok=True)
        log = open(log_path, "wb")
    except OSError:
        yield None  # an unwritable cache folder: the run compiles as it goes
        return
    with log:
        # at a lower priority: it takes the cycles the run leaves idle, and never slows the run's own work
        child = subprocess.Popen([sys.executable, "-m", "wcbench", "compile", "--nice", str(NICENESS)],
                                 stdin=subprocess.DEVNULL,
                                 stdout=log, stderr=subprocess.STDOUT)
        say = echo if echo is not None else (lambda line: print(line, file=sys.stderr, flush=True))
        say(f"compiling the numba kernels in a second process while this one works (first run only; "
            f"{BACKGROUND_COMPILE_ENV}=0 turns it off)")
        try:
            yield child
        finally:
            if child.poll() is None:
                child.terminate()
                try:
                    child.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    child.kill()
                    child.wait()
