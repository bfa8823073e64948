"""Benchmark suites (``wcbench bench SUITE``): speed against error measured in one run.

Every suite is a function ``run(*, data_root, quick) -> BenchReport`` writing the one JSON schema
of :mod:`.schema`; :data:`SUITES` names them for the CLI. Suites report ratios and errors, never
assert times.
"""

#: suite -> "module:function" returning a :class:`~wcbench.bench.schema.BenchReport`
SUITES = {
    "metrics": "wcbench.bench.metrics:run",
    "raster": "wcbench.bench.raster:run",
    "weather": "wcbench.bench.weather:run",
    "report": "wcbench.bench.report:run",
    "model": "wcbench.bench.model:run",
    "scale": "wcbench.bench.scale:run",
    "validity": "wcbench.bench.validity:run",
    "streets": "wcbench.bench.streets:run",
}
