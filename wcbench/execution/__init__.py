"""Where the units of work run: an executor takes the units :func:`wcbench.evaluation.evaluate`
plans and renders or scores them (docs/design.md §10).

``local`` (the default) runs them one after the other in this process; ``dask`` hands them to a
Dask cluster (an existing scheduler, or a ``LocalCluster`` it starts), with the same results: each
unit's result is kept atomically under its key in ``OUT/.work/`` and the client assembles
``results.json`` from those files alone. Executors are found by name in :data:`EXECUTORS`, and
imported only when asked for, so the local path never imports Dask.
"""

from wcbench.core.errors import InputError
from wcbench.core.registry import LazyRegistry
from wcbench.execution.base import Executor, UnitsFailedError

__all__ = ["EXECUTORS", "Executor", "UnitsFailedError", "make_executor"]

#: executor name -> "module:class" (entry points in the group ``wcbench.executors`` add others)
EXECUTORS: LazyRegistry = LazyRegistry("executor", {
    "local": "wcbench.execution.local:LocalExecutor",
    "dask": "wcbench.execution.dask_cluster:DaskExecutor",
})


def make_executor(name: str = "local", **options: object) -> Executor:
    """The executor ``name`` built with ``options`` (see each executor's parameters).

    Raises
    ------
    UnknownNameError
        No executor of that name.
    InputError
        The executor's extra is not installed (``pip install "wcbench[NAME]"``).
    """
    try:
        cls = EXECUTORS.get(name)
    except ModuleNotFoundError as exc:
        raise InputError(f"executor {name!r} needs {exc.name!r}, which is not installed: "
                         f'pip install "wcbench[{name}]"') from None
    executor: Executor = cls(**options)
    return executor
