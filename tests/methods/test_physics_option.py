"""The physics spec of ``lidar-init``, ``physical-editor`` and ``weathercity`` is the method option
``physics``; ``weathers`` (a list of weather kinds on the command line) is its old name, accepted for
one release: the same method and the same info.json, a DeprecationWarning (one line on stderr from
the command line), and both names together refused naming both (docs/design.md §4)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest

from wcbench.cli import main
from wcbench.core.errors import InputError
from wcbench.core.options import OptionError, schema_lines
from wcbench.methods import get_method, method_schema, renamed_method_options

pytest.importorskip("torch")

METHODS = ("lidar-init", "physical-editor", "weathercity")
SPECS = ["presets", "truth", {"rain": {"preset": "heavy", "seed": 3}, "fog": {"visibility_m": 60.0}}]
DEPRECATED = "option weathers is deprecated, use physics"


@pytest.mark.parametrize("name", METHODS)
def test_physics_is_declared_and_weathers_is_its_deprecated_name(name: str, capsys) -> None:
    schema = method_schema(name)
    assert not schema["physics"].renamed_to and schema["weathers"].renamed_to == "physics"
    assert renamed_method_options(name) == {"weathers": "physics"}
    lines = schema_lines(schema)
    assert any(line.startswith("physics  'auto', 'truth', 'presets'") for line in lines)
    assert "weathers  deprecated name of physics (accepted for one release)" in lines
    assert main(["methods", "show", name]) == 0
    out = capsys.readouterr().out
    assert "  physics  " in out and "  weathers  deprecated name of physics" in out


@pytest.mark.parametrize("spec", SPECS, ids=["presets", "truth", "dict"])
@pytest.mark.parametrize("name", METHODS)
def test_the_old_name_warns_and_makes_the_same_method(name: str, spec) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the new name warns of nothing
        new = get_method(name, physics=spec)
    with pytest.warns(DeprecationWarning, match=f"{name} {DEPRECATED}"):
        old = get_method(name, weathers=spec)
    with pytest.warns(DeprecationWarning, match=f"{name} {DEPRECATED}"):
        direct = type(new)(weathers=spec)  # the constructor keeps the old keyword too
    for method in (old, direct):
        assert method.physics_spec == new.physics_spec  # type: ignore[attr-defined]
        for weather in ("clear", "rain", "snow", "fog"):
            assert method.parameters(weather) == new.parameters(weather)  # type: ignore[attr-defined]


@pytest.mark.parametrize("name", METHODS)
def test_both_names_together_are_refused_naming_both(name: str) -> None:
    both = r"weathers and physics both given: weathers is the deprecated name of physics; give physics only"
    with pytest.raises(OptionError, match=f"{name} option {both}"):
        get_method(name, physics="auto", weathers="auto")
    cls = type(get_method(name))
    with pytest.raises(InputError, match=f"{name}: {both}"):
        cls(physics="auto", weathers="presets")


def test_a_bad_value_is_named_as_the_user_gave_it() -> None:
    from wcbench.methods import validate_method_options

    with pytest.raises(OptionError, match=r"weathercity option weathers=\{\"clear\": \{\}\}: weathers\['clear'\]: "
                                          r"not an edited weather \(one of rain, snow, fog; clear has no physics\)"):
        validate_method_options("weathercity", {"weathers": {"clear": {}}})
    with pytest.raises(OptionError, match=r"weathercity option physics=\{\"clear\": \{\}\}: physics\['clear'\]"):
        validate_method_options("weathercity", {"physics": {"clear": {}}})


def test_the_command_line_says_so_once_and_refuses_both(tmp_path: Path, capsys) -> None:
    from wcbench.cli import build_parser
    from wcbench.cli.train import training_options

    args = build_parser().parse_args(["train", "--scenes", "demo", "--method-option", "weathers=presets",
                                      "--method-option", "weathers=presets"])
    assert training_options(args) == {"physics": "presets"}
    assert capsys.readouterr().err == "wcbench: method option weathers is deprecated, use physics\n"
    # both names: one line naming both, nothing written
    out = tmp_path / "both"
    code = main(["run", "--method", "lidar-init", "--scenes", "demo", "--out", str(out), "--no-progress",
                 "--method-option", "weathers=auto", "--method-option", "physics=presets"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.endswith("lidar-init option weathers and physics both given: weathers is the deprecated name of "
                        "physics; give physics only"), err
    assert not out.exists()


@pytest.mark.model
def test_a_run_under_the_old_name_is_the_run_under_the_new_one(tmp_path: Path, capsys) -> None:
    runs = {}
    for name in ("physics", "weathers"):
        out = tmp_path / name
        assert main(["run", "--method", "lidar-init", "--scenes", "demo", "--weathers", "fog", "--frames", "0-1",
                     "--metrics", "psnr", "--out", str(out), "--no-progress", "--offline",
                     "--method-option", f"{name}.fog.visibility_m=60"]) == 0
        runs[name] = (json.loads(next(out.rglob("info.json")).read_text()), capsys.readouterr().err)
    (new, new_err), (old, old_err) = runs["physics"], runs["weathers"]
    assert "deprecated" not in new_err
    assert old_err.count("deprecated") == 1
    assert "wcbench: method option weathers is deprecated, use physics\n" in old_err
    # the same settings, recorded alike: same key (so the same frames), same parameters
    assert old["key"] == new["key"] and old["parameters"] == new["parameters"]
    assert new["parameters"]["physics"]["visibility_m"] == pytest.approx(60.0)
    assert [f["sha256"] for f in old["frames"]] == [f["sha256"] for f in new["frames"]]
