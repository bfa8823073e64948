"""Every method option is declared (type, range, meaning) and checked before any work: a bad value,
an unknown key or a value of the wrong type exits with 2 and one line naming the option, and
nothing is created in OUT. The cases are generated from the declared schemas, so an option added
to a method is covered without touching this file (docs/guide.md, "Method options")."""

from __future__ import annotations

import dataclasses
import inspect
import json
from collections.abc import Iterator

import pytest

from wcbench.cli import main
from wcbench.core.options import Option, OptionError, Range, attribute_docs, validate_options
from wcbench.methods import METHODS, MethodUnavailableError, method_schema


def _schemas() -> dict[str, dict[str, Option]]:
    out = {}
    for name in METHODS.names():
        try:
            out[name] = method_schema(name)
        except MethodUnavailableError:  # the reference model's methods need the [model] extra
            continue
    return out


def _leaves(schema: dict[str, Option], path: str = "") -> Iterator[tuple[str, Option]]:
    for key, opt in schema.items():
        full = f"{path}.{key}" if path else key
        yield full, opt
        if opt.table is not None:
            yield from _leaves(dict(opt.table), full)


def _outside(r: Range, integer: bool) -> list[float]:
    """Numbers just outside ``r`` (on each bounded side)."""
    step = 1 if integer else 0.5
    out = []
    if r.low is not None:
        out.append(r.low if r.low_open else r.low - step)
    if r.high is not None:
        out.append(r.high if r.high_open else r.high + step)
    return out


def _bad_values(opt: Option) -> list[str]:
    """``--method-option`` values (as typed) that ``opt`` must refuse."""
    kind = opt.kind
    if kind in ("int", "float"):
        bad = ["abc", "true", "[1]"] + [json.dumps(x) for x in _outside(opt.range or Range(), kind == "int")]
        return bad + (["1.5"] if kind == "int" else [])
    if kind == "bool":
        return ["maybe", "1"]
    if kind == "str":
        return ["5"] + (["no-such-choice"] if opt.choices else [])
    if kind in ("ints", "floats"):
        bad = ["abc", "5", '["a", "b"]']
        if opt.length is not None:
            bad.append(json.dumps([1] * (opt.length + 1)))
        if opt.range is not None:
            bad += [json.dumps([x] * (opt.length or 1)) for x in _outside(opt.range, kind == "ints")]
        return bad
    if kind == "table":
        return ["5", "abc"]
    return ["5"]  # a custom option: no declared option of the built-ins takes a bare number


CASES = [pytest.param(name, f"{path}={value}", path, id=f"{name}:{path}={value}")
         for name, schema in _schemas().items() for path, opt in _leaves(schema)
         if opt.allowed != "any value" for value in _bad_values(opt)]
CASES += [pytest.param(name, f"{path}.no_such_key=1" if path else "no_such_key=1", f"{path}.no_such_key".lstrip("."),
                       id=f"{name}:{path or '-'}.no_such_key")
          for name, schema in _schemas().items()
          for path in ["", *(p for p, o in _leaves(schema) if o.kind == "table")]]


@pytest.mark.parametrize("method, item, path", CASES)
def test_a_bad_method_option_is_refused_in_one_line_before_any_work(tmp_path, capsys, method, item, path):
    out = tmp_path / "out"
    code = main(["run", "--method", method, "--scenes", "demo", "--out", str(out), "--no-progress",
                 "--method-option", item])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    # named by the schema's check, or by the frame-list reader of holdout=5,15 (the spelling of --holdout)
    assert f"{method} option {path}=" in err or f"--method-option {path}: cannot parse" in err, err
    assert not out.exists()


def test_the_table_of_bad_options_covers_every_declared_option():
    # each method with declared options gets cases, and each of its options at least one
    for name, schema in _schemas().items():
        covered = {c.values[2] for c in CASES if c.values[0] == name}
        for path, opt in _leaves(schema):
            if opt.allowed != "any value":
                assert path in covered, (name, path)


@pytest.mark.parametrize("name", sorted(_schemas()))
def test_declared_options_are_the_constructor_keywords(name):
    factory = METHODS.get(name)
    params = inspect.signature(factory).parameters
    keywords = [p for p, v in params.items() if v.kind in (v.KEYWORD_ONLY, v.POSITIONAL_OR_KEYWORD)]
    assert sorted(method_schema(name)) == sorted(keywords)
    for key, opt in method_schema(name).items():
        assert opt.doc, (name, key)
        if key in params and params[key].default is not inspect.Parameter.empty and opt.kind != "custom":
            default = params[key].default
            # the declared default is the constructor's (None: the method's own, shown as null)
            assert opt.default == default or (default is None and opt.nullable) or (
                isinstance(default, tuple) and list(default) == opt.default), (name, key)


def test_training_settings_are_every_field_of_train_config():
    pytest.importorskip("torch")
    from wcbench.reference_model.training.config import TrainConfig, settings_options

    declared = set(settings_options())
    assert declared == {f.name for f in dataclasses.fields(TrainConfig)} - {"holdout", "profile", "ablation"}
    assert set(attribute_docs(TrainConfig)) >= declared  # every setting has its meaning in the docstring


def test_appearance_options_are_the_presets_keys():
    pytest.importorskip("torch")
    from wcbench.reference_model.appearance.editor import APPEARANCE_KEYS, appearance_options
    from wcbench.reference_model.weather.conditions import load_presets

    presets = load_presets()["appearance"]
    schema = appearance_options()
    assert {f"{t}.{k}" for t, o in schema.items() for k in (o.table or {})} == \
        {f"{t}.{k}" for t, keys in presets.items() for k in keys} == set(APPEARANCE_KEYS)


def test_validation_converts_and_names_nested_paths():
    schema = {"size": Option("size", "ints", "size", length=2, range=Range(1), nullable=True),
              "t": Option("t", "table", "a table", table={"x": Option("x", "float", "x", range=Range(0, 1))})}
    assert validate_options(schema, {"size": [4, 3], "t": {"x": 0.5}}) == {"size": (4, 3), "t": {"x": 0.5}}
    assert validate_options(schema, {"size": None}) == {"size": None}
    with pytest.raises(OptionError, match=r"^m t\.x=2: expected a number in \[0, 1\]$"):
        validate_options(schema, {"t": {"x": 2}}, prefix="m ")
    with pytest.raises(OptionError, match=r"no option sise .did you mean size"):
        validate_options(schema, {"sise": 1}, owner="m")
    with pytest.raises(OptionError, match="expected a number"):
        validate_options(schema, {"t": {"x": float("nan")}})


def test_methods_show_lists_every_declared_option(capsys):
    for name, schema in _schemas().items():
        assert main(["methods", "show", name]) == 0
        shown = capsys.readouterr().out
        for path, _ in _leaves(schema):
            assert f"  {path}  " in shown, (name, path)


# The rows of issue 37's table: each refused with exit 2, one line, nothing on disk.
ROWS = [
    (["run", "--method", "physical-editor", "--method-option", "size=ab"], "physical-editor option size=ab"),
    (["run", "--method", "physical-editor", "--method-option", "size=5"], "physical-editor option size=5"),
    (["run", "--method", "physical-editor", "--method-option", "appearance=foo"], "option appearance=foo"),
    (["run", "--method", "physical-editor", "--method-option", "appearance.rain=5"], "option appearance.rain=5"),
    (["run", "--method", "physical-editor", "--method-option", "appearance.rain.exposure=0"],
     "appearance.rain.exposure=0: expected a number > 0"),
    (["run", "--method", "physical-editor", "--method-option", "appearance.rain.puddle_max=x"],
     "appearance.rain.puddle_max=x: expected a number in [0, 1]"),
    (["run", "--method", "weathercity", "--method-option", "holdout=5"], "weathercity option holdout=5"),
    (["run", "--method", "weathercity", "--method-option", "settings=5"], "weathercity option settings=5"),
    (["run", "--method", "weathercity", "--method-option", "jitter=x"], "jitter=x: expected a number in [0, 1]"),
    (["run", "--method", "weathercity", "--method-option", "settings.iterations=abc"],
     "settings.iterations=abc: expected an integer >= 1"),
    (["run", "--method", "weathercity", "--method-option", "settings.iterations=-3"],
     "settings.iterations=-3: expected an integer >= 1"),
    (["train", "--method-option", "settings.iterations=-3"], "settings.iterations=-3: expected an integer >= 1"),
    (["run", "--method", "lidar-init", "--method-option", "physics=truth"], "truth/weather.json: not found"),
    (["run", "--method", "weathercity", "--profile", "quick", "--ablation", "no-content-loss",
      "--edit", "remove class=Unicorn"],
     "'Unicorn']}: selects no object"),
    (["run", "--method", "weathercity", "--supervision", "foo"], "weathercity option supervision=foo: expected"),
    (["run", "--method", "identity", "--frames", "0-99"],
     "frames 12-99 are beyond the 12 frames (0-11) of scene 'demo'"),
    (["render", "--weathers", "rain", "--frames", "0-99"], "frames 12-99 are beyond the 12 frames (0-11) of the scene"),
]


@pytest.mark.parametrize("argv, needle", ROWS, ids=[" ".join(r[0][:3] + r[0][-1:]) for r in ROWS])
def test_issue_rows_are_refused_in_one_line_before_anything_is_written(tmp_path, capsys, argv, needle):
    if any(m in argv for m in ("physical-editor", "weathercity", "lidar-init", "render", "train")):
        pytest.importorskip("torch")
    out = tmp_path / "out"
    metrics = ["--metrics", "psnr"] if argv[0] == "run" else []  # no notices of metric weights kept offline
    code = main([*argv, "--scenes", "demo", "--out", str(out), "--no-progress", *metrics])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert needle in err, err
    assert not out.exists()


@pytest.mark.parametrize("argv, needle", [
    (["--frames", "9-3"], "argument --frames: the range 9-3 is reversed; write 3-9"),
    (["--metric-resolution", "abc"], "argument --metric-resolution:"),
    (["--method", "filtr2d"], "unknown method 'filtr2d'. Did you mean 'filter2d'?"),
])
def test_argument_errors_are_one_line_without_the_usage_block(tmp_path, capsys, argv, needle):
    out = tmp_path / "out"
    args = ["run", "--method", "identity", "--scenes", "demo", "--out", str(out)]
    with pytest.raises(SystemExit) as exc:
        main([*args, *argv])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2
    assert err.startswith("wcbench run: error: ") and len(err.splitlines()) == 1, err
    assert needle in err and "usage:" not in err
    assert not out.exists()
