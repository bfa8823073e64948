"""Benchmark suites (``wcbench bench SUITE``): speed against error measured in one run.

Every suite is a function ``run(*, data_root, quick) -> BenchReport`` writing the one JSON schema
of :mod:`.schema`; :data:`SUITES` names them for the CLI. Suites report ratios and errors, never
assert times. :data:`MEASURES` says which code each suite's numbers measure.
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

#: suite -> the model-store entries it reads, fetched before it runs as ``wcbench run`` fetches them
#: (``wcbench bench`` unless ``--offline``): the suites that train WeatherCity train it with the
#: content loss's VGG16, or a fresh machine's run would measure another model than ``run`` trains
#: (what stays missing is skipped with the reason, as in a run).
WEIGHTS: dict[str, tuple[str, ...]] = {"model": ("vgg16",), "streets": ("vgg16",)}

#: suite -> the modules and packages whose code its numbers measure: the suite's own modules and
#: what it times or scores, not every import (the CLI, the core helpers, the JSON schema). A JSON
#: records their digests (:mod:`.code_version`); the docs test calls it stale when one changes
#: (docs/bench/stale.toml, docs/guide.md "Numbers in the docs"). Parent packages must import light.
MEASURES: dict[str, tuple[str, ...]] = {
    "metrics": ("wcbench.bench.metrics", "wcbench.bench.metric_models", "wcbench.bench.scoring",
                "wcbench.metrics", "wcbench.evaluation", "wcbench.units", "wcbench.predictions",
                "wcbench.methods.identity", "wcbench.methods.filter2d", "wcbench.scenes.demo",
                "wcbench.core.image_io", "wcbench.core.working_size"),
    "raster": ("wcbench.bench.raster", "wcbench.bench.phases", "wcbench.reference_model.raster",
               "wcbench.scenes.loaders"),
    "weather": ("wcbench.bench.weather", "wcbench.reference_model.weather", "wcbench.reference_model.raster",
                "wcbench.reference_model.scene_graph", "wcbench.scenes.loaders"),
    "report": ("wcbench.bench.report", "wcbench.reports", "wcbench.results"),
    "model": ("wcbench.bench.model", "wcbench.bench.phases", "wcbench.reference_model",
              "wcbench.methods.scene_training", "wcbench.methods.weathercity", "wcbench.methods.filter2d",
              "wcbench.methods.weather_spec", "wcbench.metrics.temporal", "wcbench.scenes.loaders"),
    "scale": ("wcbench.bench.scale", "wcbench.execution", "wcbench.evaluation", "wcbench.units",
              "wcbench.methods.identity", "wcbench.methods.filter2d"),
    "validity": ("wcbench.bench.validity", "wcbench.methods", "wcbench.reference_model", "wcbench.scenes",
                 "wcbench.metrics", "wcbench.evaluation", "wcbench.units"),
    "streets": ("wcbench.bench.streets", "wcbench.reference_model", "wcbench.methods.physical_editor",
                "wcbench.methods.weathercity", "wcbench.methods.scene_training", "wcbench.methods.weather_spec",
                "wcbench.metrics.temporal", "wcbench.scenes"),
    # not a `wcbench bench` suite: the stress suites' counts (tests/stress, written under
    # WCBENCH_STRESS_JSON); its number, the non-finite outputs, comes from the hostile-number subjects
    "stress": ("wcbench.reference_model.raster", "wcbench.reference_model.weather", "wcbench.metrics"),
}
