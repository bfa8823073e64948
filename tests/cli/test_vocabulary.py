"""One command-line vocabulary (issue 25 §3): every command's ``--help`` is parsed and the shared
concepts are spelled alike; every deprecated spelling still parses, says so in ``--help`` and
prints one line on stderr."""

from __future__ import annotations

import argparse
import json
import re
import warnings
from pathlib import Path

import pytest

from wcbench.cli import build_parser, main
from wcbench.cli.common import DeprecatedAlias, method_name, method_options_from

#: concept -> (the one spelling, every spelling that would name the same concept, the commands that
#: must take it). A spelling of the second set other than the first must be a deprecated alias.
CONCEPTS: dict[str, tuple[str, set[str], set[str]]] = {
    "output": ("--out", {"--out", "-o", "--output", "--json", "--out-dir", "--output-dir", "--dest"},
               {"run", "evaluate", "render", "train", "report", "bench"}),
    "weathers": ("--weathers", {"--weathers", "--weather", "-w"}, {"run", "evaluate", "render"}),
    "scenes": ("--scenes", {"--scenes", "--scene"}, {"run", "evaluate", "render", "train"}),
    "data root": ("--data-root", {"--data-root", "--data", "--root-data", "--data-dir", "--dataset-root"},
                  {"run", "evaluate", "render", "train", "bench", "scenes show"}),
    "method option": ("--method-option", {"--method-option", "--setting", "--option", "--method-options"},
                      {"run", "render", "train"}),
    "metric option": ("--metric-option", {"--metric-option", "--metric-options"}, {"run", "evaluate"}),
    "progress": ("--no-progress", {"--no-progress", "--progress", "--quiet", "-q"},
                 {"run", "evaluate", "render", "train"}),
    "offline": ("--offline", {"--offline", "--no-fetch", "--no-download"}, {"run", "evaluate", "train"}),
    "frames": ("--frames", {"--frames", "--frame"}, {"run", "evaluate", "render"}),
    "size": ("--scale", {"--scale", "--size", "--resolution"}, {"run", "evaluate", "render"}),
}
#: The method options run, render and train take as flags of their own (each a --method-option KEY).
METHOD_OPTION_FLAGS = {"--method-option", "--profile", "--supervision", "--jitter", "--ablation", "--holdout"}
#: Every deprecated spelling: (command, old) -> new, and an argv in which it is used.
DEPRECATED = {
    ("report", "-o"): ("--out", ["report", "r", "-o", "x.html"]),
    ("report", "--output"): ("--out", ["report", "r", "--output", "x.html"]),
    ("bench", "--json"): ("--out", ["bench", "metrics", "--json", "x.json"]),
    ("render", "--weather"): ("--weathers", ["render", "--scenes", "demo", "--out", "o", "--weather", "rain"]),
    ("train", "--setting"): ("--method-option settings.KEY=VALUE",
                             ["train", "--scenes", "demo", "--setting", "iterations=5"]),
}


def _commands() -> dict[str, argparse.ArgumentParser]:
    """Every command and sub-command parser: ``run``, ``scenes show``, ``models pull``..."""
    def walk(prefix: str, parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
        out = {prefix: parser} if prefix else {}
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    out.update(walk(f"{prefix} {name}".strip(), sub))
        return out
    return walk("", build_parser())


def _help(capsys: pytest.CaptureFixture[str], command: str) -> str:
    with pytest.raises(SystemExit) as exit_:
        main([*command.split(), "--help"])
    assert exit_.value.code == 0
    return capsys.readouterr().out


def _options_in_help(text: str) -> dict[str, str]:
    """Option -> its help line(s), read from the ``options`` sections of a ``--help`` text."""
    out: dict[str, str] = {}
    current: list[str] = []
    for line in text.splitlines():
        m = re.match(r"^  (-{1,2}[\w-]+.*?)(?:\s{2,}(.*))?$", line)
        if m:
            current = re.findall(r"(?<![\w-])(-{1,2}[a-z][\w-]*)", m.group(1))
            for flag in current:
                out[flag] = m.group(2) or ""
        elif current and line.startswith(" " * 10):
            for flag in current:
                out[flag] += " " + line.strip()
        else:
            current = []
    return out


def test_every_command_spells_the_shared_concepts_alike(capsys: pytest.CaptureFixture[str]) -> None:
    commands = _commands()
    assert {"run", "evaluate", "render", "train", "report", "bench", "scenes show", "models pull"} <= set(commands)
    problems = []
    for command in commands:
        options = _options_in_help(_help(capsys, command))
        for concept, (spelling, synonyms, required) in CONCEPTS.items():
            if command in required and spelling not in options:
                problems.append(f"{command}: no {spelling} ({concept})")
            for flag in sorted(synonyms & set(options) - {spelling}):
                if f"deprecated alias of {spelling}" not in options[flag]:
                    problems.append(f"{command}: {flag} names the {concept} ({spelling} elsewhere) and is not "
                                    "a deprecated alias of it")
    assert not problems, "\n".join(problems)


def test_run_render_and_train_take_the_same_method_options(capsys: pytest.CaptureFixture[str]) -> None:
    for command in ("run", "render", "train"):
        options = _options_in_help(_help(capsys, command))
        assert METHOD_OPTION_FLAGS <= set(options), command
    # read alike: the shorthands are --method-option keys, --setting is settings.KEY
    run = build_parser().parse_args(["run", "--method", "weathercity", "--scenes", "demo", "--out", "o",
                                     "--profile", "quick", "--holdout", "5,15", "--jitter", "0.5",
                                     "--method-option", "settings.iterations=500", "--supervision", "filter2d",
                                     "--ablation", "no-wgs"])
    train = build_parser().parse_args(["train", "--scenes", "demo", "--method-option", "profile=quick",
                                       "--method-option", "holdout=[5,15]", "--method-option", "jitter=0.5",
                                       "--setting", "iterations=500", "--method-option", "supervision=filter2d",
                                       "--ablation", "no-wgs"])
    from wcbench.cli.train import training_options

    expected = {"profile": "quick", "holdout": [5, 15], "jitter": 0.5, "settings": {"iterations": 500},
                "supervision": "filter2d", "ablation": "no-wgs"}
    assert method_options_from(run) == expected
    pytest.importorskip("torch")  # train checks its options against weathercity's schema (the [model] extra)
    assert training_options(train) == {**expected, "holdout": (5, 15)}
    capsys.readouterr()


def test_method_option_keys_nest_and_a_key_given_twice_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("torch")  # weathercity's options are checked by its constructor (the [model] extra)
    from wcbench.core.errors import InputError

    args = build_parser().parse_args([
        "run", "--method", "weathercity", "--scenes", "demo", "--out", "o",
        "--method-option", 'settings={"budget": 9}', "--method-option", "settings.iterations=500",
        "--method-option", "physics.rain.preset=heavy", "--method-option", "holdout=3-5"])
    assert method_options_from(args) == {"settings": {"budget": 9, "iterations": 500},
                                         "physics": {"rain": {"preset": "heavy"}}, "holdout": [3, 4, 5]}
    args = build_parser().parse_args(["run", "--method", "weathercity", "--scenes", "demo", "--out", "o",
                                      "--profile", "quick", "--method-option", "profile=default"])
    with pytest.raises(InputError, match="method option profile given twice: as --profile and as --method-option"):
        method_options_from(args)
    for bad in ("=1", "a..b=1", "novalue"):
        args = build_parser().parse_args(["run", "--method", "identity", "--scenes", "demo", "--out", "o",
                                          "--method-option", bad])
        with pytest.raises(InputError, match="expected KEY=VALUE"):
            method_options_from(args)
    # train refuses, by name, an option that only concerns rendering
    code = main(["train", "--scenes", "demo", "--method-option", "size=[8,8]", "--out", "o"])
    assert code == 2 and "method option size concerns rendering, not training" in capsys.readouterr().err


@pytest.mark.parametrize("key", sorted(DEPRECATED))
def test_every_deprecated_spelling_parses_as_the_new_one_and_warns_once(
        key: tuple[str, str], capsys: pytest.CaptureFixture[str]) -> None:
    _, old = key
    new, argv = DEPRECATED[key]
    args = build_parser().parse_args(argv)
    err = capsys.readouterr().err
    assert err == f"wcbench: {old} is deprecated, use {new}\n"
    dest = {"--out": "out", "--weathers": "weathers"}.get(new)
    if dest == "out":
        assert args.out == Path(argv[-1])
    elif dest == "weathers":
        assert args.weathers == ["rain"]
    else:
        assert method_options_from(args) == {"settings": {"iterations": 5}}
    # given twice, still one line
    build_parser().parse_args([*argv, *argv[-2:]])
    assert capsys.readouterr().err.count("deprecated") == 1


def test_the_deprecated_spellings_are_exactly_the_listed_ones() -> None:
    found = {(command, flag) for command, parser in _commands().items() for action in parser._actions
             if isinstance(action, DeprecatedAlias) for flag in action.option_strings}
    assert found == set(DEPRECATED)


def test_old_and_new_spellings_give_the_same_namespace(capsys: pytest.CaptureFixture[str]) -> None:
    parse = build_parser().parse_args
    for old, new in (
        (["report", "r", "-o", "x.html"], ["report", "r", "--out", "x.html"]),
        (["bench", "metrics", "--json", "x.json"], ["bench", "metrics", "--out", "x.json"]),
        (["render", "--scenes", "demo", "--out", "o", "--weather", "fog"],
         ["render", "--scenes", "demo", "--out", "o", "--weathers", "fog"]),
    ):
        a, b = vars(parse(old)), vars(parse(new))
        a.pop("_deprecated_used")
        assert {k: v for k, v in a.items() if k != "_run"} == {k: v for k, v in b.items() if k != "_run"}
    capsys.readouterr()


def test_method_names_use_hyphens_and_old_names_are_deprecated_aliases(capsys: pytest.CaptureFixture[str]) -> None:
    from wcbench.methods import METHODS, canonical_method_name, get_method

    assert not [n for n in METHODS.names() if "_" in n]
    assert "lidar-init" in METHODS.names() and "lidar_init" not in METHODS.names()
    assert method_name("lidar_init") == "lidar-init"
    assert capsys.readouterr().err == "wcbench: method name 'lidar_init' is deprecated, use 'lidar-init'\n"
    assert method_name("sim-editor") == "sim-editor" and capsys.readouterr().err == ""
    assert canonical_method_name("lidar_init") == "lidar-init" and canonical_method_name("identity") == "identity"
    with pytest.warns(DeprecationWarning, match="method name 'sim_editor' is deprecated, use 'sim-editor'"):
        assert get_method("sim_editor").info.name == "sim-editor"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        get_method("sim-editor")
    # an unknown name still lists the current names only
    with pytest.raises(argparse.ArgumentTypeError, match="Did you mean 'lidar-init'"):
        method_name("lidar-int")


def test_bench_list_and_all_are_flags_and_the_old_positional_forms_still_work(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--list"]) == 0
    listed = capsys.readouterr()
    assert "metrics" in listed.out and listed.err == ""
    assert main(["bench", "list"]) == 0
    old = capsys.readouterr()
    assert old.out == listed.out
    assert old.err == "wcbench: `wcbench bench list` is deprecated, use `wcbench bench --list`\n"
    # `bench all` is `bench --all` (here on an empty folder: a clear error after the deprecation line)
    assert main(["bench", "all", "--summary-only", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "wcbench: `wcbench bench all` is deprecated, use `wcbench bench --all`"
    assert "no benchmark JSON files" in err[1]
    assert main(["bench", "--all", "--summary-only", "--out", str(tmp_path)]) == 2
    assert "deprecated" not in capsys.readouterr().err
    # neither a suite nor a flag, or both: exit 2 naming what is expected
    assert main(["bench"]) == 2
    assert re.search(r"expected a suite name \(.*metrics.*\), --list or --all", capsys.readouterr().err)
    assert main(["bench", "metrics", "--all"]) == 2
    assert "give a suite name, --list or --all, not both" in capsys.readouterr().err


def _fake_suite(*, data_root: object, quick: bool) -> object:
    from wcbench.bench.schema import BenchCase, BenchReport

    report = BenchReport("fake")
    report.cases.append(BenchCase("a", "k", 1, 1.0, 0.0, "abs"))
    return report


def test_bench_out_is_the_json_file_or_a_folder_for_it(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    from wcbench.bench import SUITES

    monkeypatch.setitem(SUITES, "fake", f"{__name__}:_fake_suite")
    assert main(["bench", "fake", "--out", str(tmp_path / "b.json")]) == 0
    assert main(["bench", "fake", "--out", str(tmp_path / "folder")]) == 0
    assert main(["bench", "fake", "--json", str(tmp_path / "old.json")]) == 0
    for path in (tmp_path / "b.json", tmp_path / "folder" / "fake.json", tmp_path / "old.json"):
        assert json.loads(path.read_text())["suite"] == "fake"
    assert capsys.readouterr().err == "wcbench: --json is deprecated, use --out\n"


def test_render_takes_several_weathers_and_refuses_none_or_an_unknown_one(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("torch")  # render draws with the reference model (the [model] extra)
    from wcbench.cli.render import _weathers

    parse = build_parser().parse_args
    assert _weathers(parse(["render", "--scenes", "demo", "--out", "o", "--weathers", "rain,snow", "fog"])) == \
        ["rain", "snow", "fog"]
    assert main(["render", "--scenes", "demo", "--out", str(tmp_path / "o")]) == 2
    assert "--weathers is required: one or more of clear, rain, snow, fog" in capsys.readouterr().err
    assert main(["render", "--scenes", "demo", "--out", str(tmp_path / "o"), "--weathers", "rian"]) == 2
    assert "unknown weather 'rian'. Did you mean 'rain'?" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_report_reads_results_written_under_a_method_s_old_name(
        demo_scene: object, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "old"
    assert main(["run", "--method", "identity", "--scenes", "demo", "--weathers", "clear", "--frames", "0-1",
                 "--metrics", "psnr", "--out", str(out), "--no-progress", "--offline"]) == 0
    path = out / "results.json"
    doc = json.loads(path.read_text())
    doc["config"]["method"] = "lidar_init"  # as a release before the rename wrote it
    path.write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(["report", str(out), "--out", str(tmp_path / "r.html"), "--no-frames"]) == 0
    assert "lidar_init" in (tmp_path / "r.html").read_text()
    assert capsys.readouterr().err == ""
