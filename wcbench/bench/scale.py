"""Benchmark suite ``scale``: the same job on the local executor and on a Dask ``LocalCluster``.

The job is ``wcbench run`` of ``identity`` and ``filter2d`` on the built-in ``demo`` scene and a
copy of it under a second name, every weather, default metrics: 2 methods x 2 scenes x 4 weathers
= 16 units, each rendered then scored. It runs on the local executor and on LocalClusters of 1 and
2 worker processes (one thread each, numba/torch/BLAS limited to the worker's share of the cores).
``time_ms`` is the median wall time of the job over the rounds (a fresh output folder each round),
without the cluster's start, which is reported apart (``start_ms``); ``error`` is the largest
difference of any number of results.json (per-frame values included, the measured fps left out)
from the local run's, which must be 0.

The ``empty_units`` cases submit units that do no work through the same path (pickled run, one task
per unit, progress, results gathered): what the distributed path costs per unit by itself.
Needs the ``[dask]`` extra; the suite says so and measures the local executor alone without it.
"""

from __future__ import annotations

import importlib.util
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from wcbench.bench.schema import BenchCase, BenchReport
from wcbench.evaluation import EvaluateConfig, evaluate
from wcbench.execution import Executor, make_executor
from wcbench.execution.tasks import UnitSpec
from wcbench.scenes.sets import resolve_scenes
from wcbench.units import RenderSettings

__all__ = ["run"]

_METHODS = ("identity", "filter2d")
_WEATHERS = ("clear", "rain", "snow", "fog")


def _job(scenes: str, out: Path, executor: Executor | None, methods: tuple[str, ...],
         weathers: tuple[str, ...]) -> tuple[float, dict[tuple[str, ...], float]]:
    """Run the job into ``out``; its wall seconds and every non-fps number of its results."""
    numbers: dict[tuple[str, ...], float] = {}
    start = time.perf_counter()
    for method in methods:
        cfg = EvaluateConfig(method=method, scenes=scenes, predictions=out / method / method, out=out / method,
                             weathers=list(weathers), show_progress=False, render=RenderSettings(show_progress=False))
        doc = evaluate(cfg, executor=executor).results
        for scene, ws in doc["results"].items():
            for weather, outputs in ws.items():
                for name, r in outputs.items():
                    if r["metric"] == "fps":
                        continue
                    values = [r["value"], *(r["per_frame"] or [])]
                    for i, v in enumerate(values):
                        numbers[(method, scene, weather, name, str(i))] = float("nan") if v is None else float(v)
    return time.perf_counter() - start, numbers


def _max_difference(a: dict[tuple[str, ...], float], b: dict[tuple[str, ...], float]) -> float:
    if set(a) != set(b):
        return float("inf")
    diffs = [0.0 if (x != x and y != y) else abs(x - y) for x, y in ((a[k], b[k]) for k in a)]
    return max(diffs, default=0.0)


def run(*, data_root: Path | None = None, quick: bool = False) -> BenchReport:
    """Run the suite (``data_root`` is not used: the job is the built-in scene).

    Parameters
    ----------
    quick : bool
        A smoke run: one method, two weathers, one round, 20 empty units.

    Returns
    -------
    BenchReport
        Suite ``"scale"``: cases ``local``, ``dask_1``, ``dask_2`` (knob ``executor``) and
        ``empty_units_1``, ``empty_units_2`` (knob ``workers``, ``time_ms`` per unit).
    """
    report = BenchReport(suite="scale")
    methods = _METHODS[1:] if quick else _METHODS
    weathers = _WEATHERS[:2] if quick else _WEATHERS
    rounds, n_empty = (1, 20) if quick else (3, 200)
    units = len(methods) * 2 * len(weathers)
    has_dask = importlib.util.find_spec("distributed") is not None
    report.notes.append(f"job: run {', '.join(methods)} on demo + a copy, weathers {', '.join(weathers)}: "
                        f"{units} units, median of {rounds} round(s); cluster start not included")
    with tempfile.TemporaryDirectory(prefix="wcbench-scale-") as tmp:
        root = Path(tmp)
        copy = root / "scenes" / "demo_copy"
        shutil.copytree(resolve_scenes("demo")[0].path, copy)
        scenes = f"demo,{copy}"
        _job(scenes, root / "warm", None, methods, weathers)  # compile kernels, fill caches

        def rounds_of(executor: Executor | None, name: str) -> tuple[float, dict[tuple[str, ...], float]]:
            times: list[float] = []
            numbers: dict[tuple[str, ...], float] = {}
            for i in range(rounds):
                seconds, numbers = _job(scenes, root / f"{name}-{i}", executor, methods, weathers)
                times.append(seconds)
            return statistics.median(times), numbers

        local_s, local_numbers = rounds_of(None, "local")
        report.cases.append(BenchCase("local", "executor", "local", local_s * 1e3, 0.0, "abs",
                                      {"units": units, "speedup_vs_local": 1.0, "default": True}))
        if not has_dask:
            report.notes.append('Dask distributed not installed (pip install "wcbench[dask]"): local executor only')
            return report
        for workers in (1, 2):
            start = time.perf_counter()
            with make_executor("dask", workers=workers, show_progress=False, log=lambda _: None) as executor:
                start_ms = (time.perf_counter() - start) * 1e3
                _job(scenes, root / f"warm-dask{workers}", executor, methods, weathers)  # workers compile too
                seconds, numbers = rounds_of(executor, f"dask{workers}")
                report.cases.append(BenchCase(
                    f"dask_{workers}", "executor", f"dask, {workers} worker(s)", seconds * 1e3,
                    _max_difference(numbers, local_numbers), "abs",
                    {"units": units, "speedup_vs_local": local_s / seconds, "start_ms": start_ms},
                ))
                assert hasattr(executor, "run_empty")
                demo = resolve_scenes("demo")[0]
                specs = [UnitSpec(label=f"empty {i}", scene=demo, weather="clear", root=demo.path, source_hashes=(),
                                  check_unedited=False, key=str(i)) for i in range(n_empty)]
                executor.run_empty(specs[: min(10, n_empty)])  # warm the path
                t0 = time.perf_counter()
                executor.run_empty(specs)
                per_unit_ms = (time.perf_counter() - t0) * 1e3 / n_empty
                report.cases.append(BenchCase(
                    f"empty_units_{workers}", "workers", workers, per_unit_ms, None, "abs",
                    {"units": n_empty, "what": "wall time per unit that does no work"},
                ))
    local_unit_ms = local_s * 1e3 / units
    report.notes.append(f"local: {local_unit_ms:.0f} ms per unit of this job")
    return report
