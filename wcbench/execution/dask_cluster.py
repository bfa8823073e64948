"""The Dask executor: units on a Dask cluster, with the guarantees of a local run.

``wcbench run ... --executor dask --scheduler tcp://HOST:8786`` uses a running cluster;
``--executor dask --workers N`` starts a ``LocalCluster`` of N worker processes. Needs the
``[dask]`` extra (``pip install "wcbench[dask]"``); nothing else of wcbench imports this module.

How a run goes (docs/design.md §10):

- the client plans the units as a local run does; a runnable method's scenes each get one set-up
  task (training), and the scene's weathers render after it (a task dependency), so a scene trains
  once, on one worker, and the other workers load its checkpoint from the cache folder;
- the client opens the rendered units, computes their keys, and sends only the units whose result
  is not kept in ``OUT/.work/`` yet; a worker writes each result atomically under its key;
- the client assembles ``results.json`` from the unit files alone. A killed worker's units are
  rescheduled by Dask; a killed client resumes from the kept units; a failed unit is reported with
  its error after the others finish (:class:`~wcbench.execution.base.UnitsFailedError`).

``OUT``, the predictions and the cache folder (``WCBENCH_CACHE``) must be one shared filesystem
for the client and every worker. Units ask for Dask resources (``torch`` for a method or metric that
needs the ``[model]`` extra), so a worker started without ``--resources torch=1`` scores but never
trains; each worker limits numba, torch and BLAS to its share of its machine's cores.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import uuid
from collections.abc import Callable, Sequence
from typing import Any

import dask
from distributed import Client, LocalCluster, WorkerPlugin, as_completed

from wcbench.core.errors import InputError
from wcbench.core.progress import progress
from wcbench.execution.base import Executor, UnitsFailedError
from wcbench.execution.tasks import (
    RunShared,
    UnitSpec,
    empty_task,
    pack,
    render_task,
    score_task,
    setup_scene_task,
    spec_of,
)
from wcbench.units import RenderSettings, Scoring, UnitResult, WorkUnit

__all__ = ["DaskExecutor", "ThreadLimits", "thread_env", "threads_per_worker"]

#: Environment variables that size the thread pools of BLAS, OpenMP (torch) and numba.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")


def threads_per_worker(cores: int, workers_on_host: int) -> int:
    """Threads each worker of a machine may use so that the workers do not oversubscribe its cores."""
    return max(1, cores // max(1, workers_on_host))


def _host(address: str) -> str:
    """``tcp://10.0.0.5:41234`` -> ``10.0.0.5``."""
    return address.split("://")[-1].rsplit(":", 1)[0]


def thread_env(threads: int) -> dict[str, str]:
    """The environment that limits a new worker process to ``threads`` threads."""
    return {name: str(threads) for name in THREAD_VARIABLES}


class ThreadLimits(WorkerPlugin):
    """Limits each worker to its share of its machine's cores (workers already running included).

    Parameters
    ----------
    threads_by_host : dict of str to int
        Threads per worker on each host; a worker on another host takes
        ``cores // worker threads``.
    """

    def __init__(self, threads_by_host: dict[str, int]):
        self.threads_by_host = dict(threads_by_host)

    def setup(self, worker: Any) -> None:
        """Set the thread variables, and the pools of numba and torch when already imported."""
        import sys

        n = self.threads_by_host.get(_host(worker.address))
        n = n or threads_per_worker(os.cpu_count() or 1, worker.state.nthreads)
        os.environ.update(thread_env(n))
        if "torch" in sys.modules:
            sys.modules["torch"].set_num_threads(n)
        if "numba" in sys.modules:
            numba = sys.modules["numba"]
            numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))


class DaskExecutor(Executor):
    """Units on a Dask cluster.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler (``tcp://HOST:8786``).
    workers : int, optional
        Start a ``LocalCluster`` of this many worker processes (default: one per core).
    show_progress : bool
        One progress bar over the units on the client.
    log : callable
        Where one-line messages go (the dashboard link).

    Raises
    ------
    InputError
        Both or bad ``scheduler``/``workers`` are given, or the scheduler cannot be reached.
    """

    name = "dask"

    def __init__(self, *, scheduler: str | None = None, workers: int | None = None, show_progress: bool = True,
                 log: Callable[[str], None] = print):
        if scheduler and workers:
            raise InputError("give --scheduler (a running cluster) or --workers (a local cluster), not both")
        if workers is not None and workers < 1:
            raise InputError(f"--workers must be at least 1, got {workers}")
        self.show_progress, self.cluster = show_progress, None
        if scheduler:
            try:
                self.client = Client(scheduler, timeout="20s")
            except (OSError, TimeoutError) as exc:
                raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        else:
            n = workers or os.cpu_count() or 1
            has_torch = importlib.util.find_spec("torch") is not None
            # Dask's nanny sets MALLOC_TRIM_THRESHOLD_=65536 in its workers, which turns off glibc's
            # dynamic mmap threshold: every frame buffer is then a fresh mmap, and scoring took
            # 2.2x as long (0.55 s against 0.25 s for 4 demo units, one process, measured)
            with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
                self.cluster = LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",  # any free port
                    resources={"torch": 1} if has_torch else None, silence_logs=logging.ERROR,
                    env=thread_env(threads_per_worker(os.cpu_count() or 1, n)),
                )
            self.client = Client(self.cluster)
        self._limit_threads()
        if importlib.util.find_spec("bokeh") is not None:  # the dashboard serves pages only with bokeh
            log(f"dask: dashboard at {self.client.dashboard_link}")

    def _limit_threads(self) -> None:
        per_host: dict[str, int] = {}
        for address, w in self.client.scheduler_info().get("workers", {}).items():
            per_host[_host(address)] = per_host.get(_host(address), 0) + int(w.get("nthreads", 1))
        cores = os.cpu_count() or 1  # the client's; hosts of another size fall back in the plugin
        self.client.register_plugin(ThreadLimits({h: threads_per_worker(cores, n) for h, n in per_host.items()}),
                                    name="wcbench-thread-limits")

    def _resources(self, needs: Sequence[str]) -> dict[str, float] | None:
        """Dask resources of a task needing ``needs``; refuses when no worker offers them."""
        if not needs:
            return None
        workers = self.client.scheduler_info().get("workers", {})
        if not any(all(w.get("resources", {}).get(r, 0) >= 1 for r in needs) for w in workers.values()):
            offer = " ".join(f"{r}=1" for r in needs)
            raise InputError(
                f"no Dask worker offers the resources {list(needs)} these units need (the [model] extra); "
                f'start workers with `dask worker SCHEDULER --nthreads 1 --resources "{offer}"`'
            )
        return dict.fromkeys(needs, 1.0)

    def _gather(self, futures: dict[Any, str], *, desc: str) -> tuple[dict[str, Any], list[tuple[str, BaseException]]]:
        """Wait for every future with one progress bar; results and failures by label."""
        results: dict[str, Any] = {}
        failures: list[tuple[str, BaseException]] = []
        done = progress(as_completed(list(futures)), desc=desc, total=len(futures), enabled=self.show_progress,
                        unit="unit")
        for f in done:
            label = futures[f]
            if f.status == "error":
                exc = f.exception()
                failures.append((label, exc if isinstance(exc, BaseException) else RuntimeError(str(exc))))
            else:
                results[label] = f.result()
        return results, failures

    def _submit(self, fn: Callable[..., Any], *args: Any, label: str, resources: dict[str, float] | None) -> Any:
        return self.client.submit(fn, *args, key=f"{fn.__name__} {label} {uuid.uuid4().hex[:12]}",
                                  resources=resources, pure=False, retries=0)

    def render(self, plan: Sequence[Sequence[WorkUnit]], settings: RenderSettings) -> None:
        """One set-up task per scene, then its weathers' render tasks after it (see the module docstring)."""
        units = [u for scene_units in plan for u in scene_units]
        if not units:
            return
        method = units[0].method
        shared = RunShared(method, {}, {}, render=RenderSettings(seed=settings.seed, frames=settings.frames,
                                                 overwrite=settings.overwrite, video=settings.video,
                                                 show_progress=False))
        data, digest = pack(shared)
        resources = self._resources(method.info.requires)
        futures: dict[Any, str] = {}
        for scene_units in plan:
            if not scene_units:
                continue
            first = scene_units[0]
            label = f"{method.info.name} {first.scene.id} (scene set-up)"
            setup = self._submit(setup_scene_task, data, digest, spec_of(first).scene, label=label, resources=resources)
            futures[setup] = label
            for u in scene_units:
                futures[self._submit(render_task, data, digest, spec_of(u), setup, label=u.label,
                                     resources=resources)] = u.label
        results, failures = self._gather(futures, desc="rendering units")
        if failures:
            raise UnitsFailedError(failures, finished=len(results), phase="rendering")

    def score(self, units: Sequence[WorkUnit], scoring: Scoring, keys: Sequence[str]) -> list[UnitResult]:
        """Send the units not kept yet to the workers; read every result from its unit file."""
        todo = [(u, k) for u, k in zip(units, keys) if u.cached_result(scoring.out, k) is None]
        if todo:
            shared = RunShared(units[0].method, scoring.metrics, scoring.metric_config, out=scoring.out.resolve(),
                               fps=scoring.fps, resolution=scoring.resolution, score_size=scoring.score_size)
            data, digest = pack(shared)
            needs = sorted({r for m in scoring.metrics.values() for r in m.requires()})
            resources = self._resources(needs)
            futures = {self._submit(score_task, data, digest, spec_of(u, key=k), label=u.label,
                                    resources=resources): u.label for u, k in todo}
            results, failures = self._gather(futures, desc="scoring units")
            if failures:
                raise UnitsFailedError(failures, finished=len(results), phase="scoring")
        out: list[UnitResult] = []
        computed = {id(u) for u, _ in todo}
        for u, k in zip(units, keys):
            result = u.cached_result(scoring.out, k)
            if result is None:
                raise InputError(
                    f"{u.work_path(scoring.out)}: a worker scored {u.label} but its result is not there: "
                    "OUT must be on a filesystem the client and every worker share"
                )
            out.append(UnitResult(u, k, result, computed=id(u) in computed))
        return out

    def run_empty(self, specs: Sequence[UnitSpec]) -> int:
        """Submit one task per spec that does no work and wait for them; the number finished.

        What the distributed path costs per unit by itself (scheduling, serialisation, results).
        """
        data, digest = pack(RunShared(method=None, metrics={}, metric_config={}))
        futures = {self._submit(empty_task, data, digest, s, label=s.label, resources=None): s.label for s in specs}
        results, failures = self._gather(futures, desc="empty units")
        if failures:
            raise UnitsFailedError(failures, finished=len(results), phase="running empty units")
        return len(results)

    def close(self) -> None:
        """Close the client, and the local cluster if this executor started it."""
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()
