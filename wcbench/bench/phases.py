"""Per-phase thread scaling shared by ``bench raster`` and ``bench model`` (docs/design.md §8).

A workload is run at several thread counts, rounds interleaving the counts so that a change of
machine load hits every count alike; each run returns the wall time of each of its phases. Per
phase: the median time at each count, the speed-up from the first count to the second, the serial
fraction that speed-up implies by Amdahl's law, and the speed-up that fraction allows at 16
threads. The 16-thread figure is a **projection** from two measured counts, not a measurement: it
assumes the parallel part keeps scaling (no memory-bandwidth limit, no extra synchronisation).

Amdahl (1967): with a serial fraction ``f`` of the one-thread time, ``n`` threads give
``S(n) = 1 / (f + (1 - f) / n)``; a measured ``S`` at ``n`` gives ``f = (n / S - 1) / (n - 1)``.
"""

from __future__ import annotations

import os
import statistics
from collections.abc import Callable, Sequence
from typing import Any

import numba

from wcbench.reference_model.raster.threads import max_threads, threads

__all__ = ["PROJECT_TO", "amdahl_serial", "amdahl_speedup", "parse_threads", "phase_table", "run_interleaved"]

#: The thread count of the projection (the 16-core machine of issue 24).
PROJECT_TO = 16


def amdahl_serial(speedup: float, n: int) -> float:
    """Serial fraction in [0, 1] implied by ``speedup`` measured at ``n`` threads against one.

    A speed-up above ``n`` (cache effects, noise) gives 0; at or below 1 gives 1.
    """
    if n <= 1 or not speedup > 0:
        return float("nan")
    return min(1.0, max(0.0, (n / speedup - 1.0) / (n - 1.0)))


def amdahl_speedup(serial: float, n: int) -> float:
    """Speed-up at ``n`` threads of a workload with serial fraction ``serial`` (Amdahl's law)."""
    return 1.0 / (serial + (1.0 - serial) / n)


def parse_threads(spec: str | Sequence[int] | None, default: Sequence[int] = (1, 2)) -> list[int]:
    """Thread counts from ``"1,2,4"`` or a sequence: at least two, positive, distinct, in the given order.

    Raises
    ------
    ValueError
        On a count below 1, fewer than two counts, or a repeated count.
    """
    if spec is None:
        counts = list(default)
    elif isinstance(spec, str):
        try:
            counts = [int(x) for x in spec.replace(" ", "").split(",") if x]
        except ValueError:
            raise ValueError(f"thread counts must be comma-separated integers like 1,2,4, got {spec!r}") from None
    else:
        counts = [int(x) for x in spec]
    if len(counts) < 2 or min(counts) < 1 or len(set(counts)) != len(counts):
        raise ValueError(f"need two or more distinct thread counts >= 1 (the first is the baseline), got {counts}")
    return counts


def run_interleaved(run_once: Callable[[], dict[str, float]], counts: Sequence[int], rounds: int, *,
                    warmup: int = 1) -> tuple[dict[int, list[dict[str, float]]], list[int]]:
    """``run_once()`` ``rounds`` times at each thread count, interleaved (a round runs every count).

    Parameters
    ----------
    run_once : callable
        One run; returns ``{phase: ms}`` (any phases, the same in every run).
    counts : sequence of int
        Thread counts; those above the machine's (:func:`max_threads`) run at its count, and the
        returned ``effective`` list says so.
    rounds, warmup : int
        Measured rounds; unmeasured runs per count first (compilation, caches).

    Returns
    -------
    samples : dict of int to list of dict
        Per requested count, the phase times of each measured run.
    effective : list of int
        The count each requested count actually ran at.
    """
    effective = [min(n, max_threads()) for n in counts]
    for n in counts:
        with threads(n):
            for _ in range(warmup):
                run_once()
    samples: dict[int, list[dict[str, float]]] = {n: [] for n in counts}
    for _ in range(rounds):
        for n in counts:
            with threads(n):
                samples[n].append(run_once())
    return samples, effective


def threading_layer() -> str:
    """numba's threading layer (``"omp"``, ``"tbb"`` or ``"workqueue"``), or ``"none yet"`` before the
    first parallel kernel ran: how a parallel loop's chunks are scheduled depends on it, so a thread
    profile records it (docs/workstation.md)."""
    try:
        return str(numba.threading_layer())
    except ValueError:  # no parallel kernel has run in this process
        return "none yet"


def phase_table(title: str, samples: dict[int, list[dict[str, float]]], effective: Sequence[int],
                phases: Sequence[str], total: str) -> tuple[dict[str, Any], list[str]]:
    """Per-phase medians, speed-ups, serial fractions and the 16-thread projection.

    Parameters
    ----------
    title : str
        First line of the text table.
    samples, effective
        From :func:`run_interleaved`.
    phases : sequence of str
        Phase keys of the samples, in table order; they should add up to ``total``.
    total : str
        Key of the whole run's time.

    Returns
    -------
    fields : dict
        JSON-ready: ``threads`` (requested), ``threads_effective``, ``load_1min``,
        ``threading_layer`` (numba's), and per row
        (each phase and ``total``) ``ms`` (median per count), ``share`` (of the first count's total),
        ``speedup`` (first count over second), ``speedup_vs_first`` (per count), ``serial`` (Amdahl
        fraction from those two) and ``projected_<PROJECT_TO>t`` (Amdahl's speed-up at that many
        threads; a projection).
    lines : list of str
        The same as a text table (for the report's notes).
    """
    counts = list(samples)
    base, other = counts[0], counts[1]
    ratio = effective[1] / effective[0]
    rows: dict[str, dict[str, Any]] = {}
    total_base = statistics.median(r[total] for r in samples[base])
    for key in [*phases, total]:
        ms = {n: statistics.median(r[key] for r in samples[n]) for n in counts}
        speed = ms[base] / ms[other] if ms[other] > 0 else float("nan")
        # Amdahl in units of the base count: ``ratio`` times the threads of the base.
        serial = amdahl_serial(speed, round(ratio)) if ratio >= 2 else float("nan")
        proj = amdahl_speedup(serial, PROJECT_TO // max(effective[0], 1)) if serial == serial else float("nan")
        rows[key] = {"ms": {str(n): round(v, 3) for n, v in ms.items()},
                     "share": round(ms[base] / total_base, 4) if total_base > 0 else None,
                     "speedup": round(speed, 3), "serial": round(serial, 4),
                     "speedup_vs_first": {str(n): round(ms[base] / v, 3) if v > 0 else None for n, v in ms.items()},
                     f"projected_{PROJECT_TO}t": round(proj, 2)}
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    head = "".join(f"{f'{n}t ms':>10s}" for n in counts)
    last = f"x at {counts[-1]}t" if len(counts) > 2 else ""
    layer = threading_layer()
    lines = [f"{title} (1-min load {load:.2f}; numba threading layer {layer}; medians; the {PROJECT_TO}-thread "
             f"column is an Amdahl projection from the {effective[0]}- and {effective[1]}-thread times, "
             "not a measurement)",
             f"{'phase':14s}{head}{'share':>8s}{'speed-up':>10s}{'serial':>8s}{f'{PROJECT_TO}t proj.':>11s}{last:>10s}"]
    for key, row in rows.items():
        cells = "".join(f"{row['ms'][str(n)]:10.2f}" for n in counts)
        lines.append(f"{key:14s}{cells}{100 * (row['share'] or 0):7.1f}%{row['speedup']:9.2f}x"
                     f"{100 * row['serial']:7.1f}%{row[f'projected_{PROJECT_TO}t']:10.2f}x"
                     + (f"{row['speedup_vs_first'][str(counts[-1])]:9.2f}x" if last else ""))
    if list(effective) != counts:
        lines.append(f"requested threads {counts} ran at {list(effective)} (this machine has {max_threads()})")
    fields = {"threads": counts, "threads_effective": list(effective), "load_1min": round(load, 2),
              "threading_layer": layer, "phases": rows}
    return fields, lines
