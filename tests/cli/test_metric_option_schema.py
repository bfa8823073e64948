"""Every metric option is declared (type, range or choices, default, meaning) and checked before any
work: a bad value, an unknown key or a value of the wrong type given to ``run`` or ``evaluate``
exits with 2 and one line naming the metric, the option, the value and what is allowed, and nothing
is created in OUT. The cases are generated from the declared schemas, so an option added to a
metric is covered without touching this file (docs/guide.md, "Metric options")."""

from __future__ import annotations

import inspect
import json
from pathlib import Path

import numpy as np
import pytest

from wcbench.cli import main
from wcbench.core.models.catalogue import ModelEntry, ModelSource
from wcbench.core.models.store import ModelStore
from wcbench.core.options import Option, OptionError, Range
from wcbench.evaluation import EvaluateConfig, evaluate
from wcbench.metrics.registry import METRICS, create_metric, metric_schema, validate_metric_options

SCHEMAS = {name: metric_schema(name) for name in METRICS.names()}


def _outside(r: Range) -> list[int]:
    """Integers just outside ``r`` (on each bounded side; every numeric metric option is an integer)."""
    out = []
    if r.low is not None:
        out.append(int(r.low) if r.low_open else int(r.low) - 1)
    if r.high is not None:
        out.append(int(r.high) if r.high_open else int(r.high) + 1)
    return out


def _bad_values(opt: Option) -> list[str]:
    """``--metric-option`` values (as typed) that ``opt`` must refuse."""
    bad = [] if opt.nullable else ["null"]
    if opt.kind == "int":
        return bad + ["abc", "true", "[1]", "1.5"] + [json.dumps(x) for x in _outside(opt.range or Range())]
    if opt.kind == "bool":
        return [*bad, "maybe", "1"]
    if opt.kind == "str":
        return bad + ["5"] + (["no-such-choice"] if opt.choices else [])
    # a custom option: a model, a flow, a file, a weather or a Python object; none is a bare number, and
    # no text of that spelling names one
    return [*bad, "5", "no-such-thing"]


CASES = [pytest.param(name, f"{name}.{key}={value}", key, id=f"{name}.{key}={value}")
         for name, schema in SCHEMAS.items() for key, opt in schema.items() for value in _bad_values(opt)]
CASES += [pytest.param(name, f"{name}.no_such_key=1", "no_such_key", id=f"{name}.no_such_key")
          for name in SCHEMAS]


def _argv(command: str, metric: str, item: str, out: Path, tmp_path: Path) -> list[str]:
    if command == "run":
        head = ["run", "--method", "identity", "--no-progress", "--offline"]
    else:  # the predictions are never looked at: the option is refused first
        head = ["evaluate", "--method", "folder", "--predictions", str(tmp_path / "predictions"), "--no-progress",
                "--offline"]
    return [*head, "--scenes", "demo", "--out", str(out), "--metrics", metric, "--metric-option", item]


@pytest.mark.parametrize("command", ["run", "evaluate"])
@pytest.mark.parametrize("metric, item, key", CASES)
def test_a_bad_metric_option_is_refused_in_one_line_before_any_work(tmp_path, capsys, command, metric, item, key):
    out = tmp_path / "out"
    code = main(_argv(command, metric, item, out, tmp_path))
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and not captured.out, captured
    assert err.startswith(f"wcbench {command}: error: metric option {metric}.{key}="), err
    assert "expected" in err or "takes no option" in err, err
    assert not out.exists()


def test_the_table_of_bad_options_covers_every_declared_option():
    for name, schema in SCHEMAS.items():
        covered = {c.values[2] for c in CASES if c.values[0] == name}
        assert covered == {*schema, "no_such_key"}, name


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_declared_options_are_the_constructor_keywords(name):
    cls = METRICS.get(name)
    assert cls.OPTIONS is not None, f"{name} declares no OPTIONS"
    params = inspect.signature(cls.__init__).parameters
    keywords = {p: v for p, v in params.items() if p != "self" and v.kind in (v.KEYWORD_ONLY, v.POSITIONAL_OR_KEYWORD)}
    assert sorted(cls.OPTIONS) == sorted(keywords)
    for key, opt in cls.OPTIONS.items():
        assert opt.name == key and opt.doc, (name, key)
        assert keywords[key].default is not inspect.Parameter.empty, (name, key)
        assert opt.default == keywords[key].default, (name, key)  # what `metrics show` says is what it does
        if opt.kind == "int":
            assert opt.range is not None, (name, key)


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_each_default_is_allowed_and_builds_the_metric(name):
    schema = SCHEMAS[name]
    defaults = {k: o.default for k, o in schema.items() if o.default is not None or o.nullable}
    assert validate_metric_options(name, defaults) == defaults
    create_metric(name, **defaults)  # builds without loading weights (they load on first use)


@pytest.mark.parametrize("name, options", [
    ("lpips", {"net": "vgg", "backend": "numpy", "skip_identical": False}),
    ("clip_s", {"model": "clip-vit-b16-openai", "backend": "torch", "crop": "squash", "batch_size": 1}),
    ("clip_ds", {"weather": "snow", "prompts": None}),
    ("sem_cs", {"segmenter": "segformer-b0-ade", "ignore_index": None, "source_cache": 0, "num_classes": 19}),
    ("flow_warping_error", {"flow": "farneback"}),
    ("psnr", {"skip_identical": False}),
])
def test_allowed_values_pass(name, options):
    assert validate_metric_options(name, options) == options


def test_python_objects_pass_where_the_command_line_cannot_give_them(tmp_path):
    # an injected store with its own catalogue: its models are the ones a model option names
    entry = ModelEntry(name="clip-x", kind="clip", description="test", file="w.bin",
                       source=ModelSource(kind="import"))
    store = ModelStore(tmp_path, registry={"clip-x": entry})
    assert create_metric("clip_s", model="clip-x", store=store).model == "clip-x"
    with pytest.raises(OptionError, match=r"^metric option clip_s\.model=clip-x: expected a model of the catalogue"):
        validate_metric_options("clip_s", {"model": "clip-x"})
    metric = create_metric("lpips", distance=lambda a, b: np.zeros(len(a)))
    assert metric.required_models() == ()
    assert create_metric("flow_warping_error", flow=lambda a, b: np.zeros((*a.shape[:2], 2), np.float32)).config() \
        == {"flow": "<lambda>"}


def test_a_prompts_file_sets_the_weathers_a_weather_option_takes(tmp_path):
    prompts = tmp_path / "prompts.toml"
    prompts.write_text('[hail]\ntarget = "a street in hail"\nsource = "a dry street"\n')
    assert validate_metric_options("clip_ds", {"prompts": str(prompts), "weather": "hail"})["weather"] == "hail"
    refused = rf"^metric option clip_ds\.weather=rain: expected a weather of {prompts}: hail$"
    with pytest.raises(OptionError, match=refused):
        validate_metric_options("clip_ds", {"prompts": str(prompts), "weather": "rain"})
    prompts.write_text('[hail]\ntarget = "same"\nsource = "same"\n')
    with pytest.raises(OptionError, match=r"target and source texts must differ"):
        validate_metric_options("clip_ds", {"prompts": str(prompts)})


def test_metrics_show_lists_every_declared_option(capsys):
    for name, schema in SCHEMAS.items():
        assert main(["metrics", "show", name]) == 0
        shown = capsys.readouterr().out
        assert shown.startswith(f"{name}  ")
        for key in schema:
            assert f"\n  {key}  " in shown, (name, key)
        if not schema:
            assert "options: none" in shown
    assert main(["metrics", "show", "lpip"]) == 2
    assert "unknown metric 'lpip'. Did you mean 'lpips'" in capsys.readouterr().err


# What issue 37 measured: a traceback, values accepted silently, an error after other work.
ROWS = [
    ("lpips.net=vgg2", "metric option lpips.net=vgg2: expected one of 'alex', 'vgg'"),
    ("clip_s.batch_size=abc", "metric option clip_s.batch_size=abc: expected an integer >= 1"),
    ("clip_s.batch_size=-3", "metric option clip_s.batch_size=-3: expected an integer >= 1"),
    ("sem_cs.segmenter=foo", "metric option sem_cs.segmenter=foo: expected a model of the catalogue"),
    ("sem_cs.segmenter=segformer-b0", "(did you mean segformer-b0-ade"),
    ("temporal_flicker.colour=1", "metric option temporal_flicker.colour=1: metric 'temporal_flicker' takes no "
                                  "option colour; it takes: none"),
]


@pytest.mark.parametrize("item, needle", ROWS, ids=[r[0] for r in ROWS])
def test_issue_rows_are_refused_before_anything_is_said_or_written(tmp_path, capsys, item, needle):
    out = tmp_path / "out"
    code = main(["run", "--method", "identity", "--scenes", "demo", "--metrics",
                 "psnr,lpips,clip_s,temporal_flicker,sem_cs", "--metric-option", item, "--out", str(out), "--offline"])
    captured = capsys.readouterr()
    assert code == 2
    assert captured.out == "" and len(captured.err.strip().splitlines()) == 1, captured
    assert needle in captured.err, captured.err
    assert not out.exists()


def test_the_python_api_refuses_before_the_folder_is_made(tmp_path):
    out = tmp_path / "out"
    cfg = EvaluateConfig(method="folder", scenes="demo", predictions=tmp_path / "p", out=out, metrics=["lpips"],
                         metric_options={"lpips": {"net": "vgg2"}}, show_progress=False, offline=True)
    with pytest.raises(OptionError, match=r"^metric option lpips\.net=vgg2: expected one of 'alex', 'vgg'$"):
        evaluate(cfg)
    assert not out.exists()


def test_an_undeclared_plugin_metric_takes_its_keywords(monkeypatch):
    class Plugin(METRICS.get("fps")):
        OPTIONS = None

        def __init__(self, *, level: int = 1) -> None:
            super().__init__()
            self.level = level

    class Open(Plugin):
        def __init__(self, **options: object) -> None:
            super().__init__()

    # the registry holds no way to remove a name: the test's entries go with monkeypatch
    monkeypatch.setitem(METRICS._loaded, "plugin_x", Plugin)
    monkeypatch.setitem(METRICS._loaded, "plugin_open", Open)
    assert list(metric_schema("plugin_x")) == ["level"]
    assert create_metric("plugin_x", level="anything").level == "anything"
    with pytest.raises(OptionError, match=r"^metric option plugin_x\.levle=2: metric 'plugin_x' takes no option levle"):
        validate_metric_options("plugin_x", {"levle": 2})
    assert validate_metric_options("plugin_open", {"whatever": 2}) == {"whatever": 2}
