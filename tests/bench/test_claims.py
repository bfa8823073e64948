"""The markers that tie a number of the docs to its benchmark JSON, and the check of a JSON against
the code it measures (wcbench.bench.claims; the docs themselves: tests/test_doc_numbers.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from wcbench.bench.claims import (
    ClaimError,
    check_docs,
    check_freshness,
    expand_braces,
    read_stale_list,
)
from wcbench.bench.code_version import measured_code
from wcbench.bench.schema import BenchCase, BenchReport

_CASES = [
    BenchCase("editor_a", "scene", "a", 18.57, None, "-", {"setup_s": 4.87, "flicker_rain": 0.7223,
                                                          "flicker_snow": 0.7855, "frames": {"5": {"iou": 0.9261}},
                                                          "blue": 40116, "nothing": None}),
    BenchCase("editor_b", "scene", "b", 19.46, None, "-", {"setup_s": 1.01, "flicker_rain": 0.83,
                                                          "flicker_snow": 1.0191, "frames": {"5": {"iou": 0.9725}},
                                                          "blue": 49245, "nothing": None}),
    BenchCase("train", "method", "wc", 190052.07, 20.145, "psnr_db"),
]


#: module -> digest, shared by this module's tests (a digest reads the whole reference model)
_DIGESTS: dict[str, str] = {}


@pytest.fixture(scope="module")
def streets_code() -> dict:
    """The ``code`` record of the streets suite now."""
    code = measured_code("streets", memo=_DIGESTS)
    assert code is not None
    return code


def _repo(tmp_path: Path, doc: str, *, code: dict | None = None, command: str | None = None) -> Path:
    """A repository root with ``docs/bench/streets.json`` (of the suite ``streets``) and README.md."""
    bench = tmp_path / "docs" / "bench"
    bench.mkdir(parents=True)
    report = BenchReport("streets", cases=list(_CASES), code=code, command=command)
    obj = report.to_json()
    obj["created"] = "2026-11-28T22:42:19+00:00"
    (bench / "streets.json").write_text(json.dumps(obj))
    (tmp_path / "README.md").write_text(doc)
    return tmp_path


def _problems(root: Path) -> list[str]:
    return check_docs(root, freshness=False).problems


def test_expand_braces() -> None:
    assert expand_braces("a{1,2}b{x,y}") == ["a1bx", "a1by", "a2bx", "a2by"]
    assert expand_braces("x_{,_every}") == ["x_", "x__every"]
    with pytest.raises(ClaimError, match="unbalanced"):
        expand_braces("a{b")


def test_numbers_that_are_their_json_pass(tmp_path: Path) -> None:
    doc = ("Set-up 1.0-4.9<!--bench streets.json:editor_*:setup_s range .1f--> s, a median of\n"
           "18.6<!--bench editor_a:time_ms .1f--> ms, flicker 0.72 / 0.79<!--bench flicker_{rain,snow} .2f-->,\n"
           "IoU 0.926<!--bench frames.5.iou .3f--> of 40,116<!--bench blue ,d--> px, none: -<!--bench nothing .1f-->;\n"
           "mean set-up 2.9<!--bench editor_{a,b}:setup_s mean .1f--> s, trained in\n"
           "3.2<!--bench train:time_ms /60000 .1f--> min to 20.15<!--bench error .2f--> dB on\n"
           "2026-11-28<!--bench :created date-->.\n")
    root = _repo(tmp_path, doc)
    report = check_docs(root, freshness=False)
    assert report.problems == [] and report.claims == 10


def test_a_number_that_differs_is_reported_with_the_json_value(tmp_path: Path) -> None:
    root = _repo(tmp_path, "flicker 0.72 / 0.80<!--bench streets.json:editor_a:flicker_{rain,snow} .2f--> and\n"
                           "18.7<!--bench time_ms .1f--> ms\n")
    problems = _problems(root)
    assert len(problems) == 2
    assert "README.md:1: says '0.72 / 0.80'" in problems[0] and "gives '0.72 / 0.79'" in problems[0]
    assert "README.md:2: says '18.7'" in problems[1] and "gives '18.6'" in problems[1]


@pytest.mark.parametrize(("marker", "message"), [
    ("streets.json:editor_a:setup", "has no 'setup'"),
    ("streets.json:editor_c:setup_s", "no case 'editor_c'"),
    ("model.json:editor_a:setup_s", "no docs/bench/model.json"),
    ("../streets.json:editor_a:setup_s", "not a JSON file under docs/bench"),
    ("setup_s", "no marker before it in this paragraph"),
    ("streets.json:editor_*:setup_s", "expected '4.9 / 1.0' right before"),  # two values: no range given
])
def test_a_marker_that_cannot_be_resolved_is_a_problem(tmp_path: Path, marker: str, message: str) -> None:
    root = _repo(tmp_path, f"set-up 4.9<!--bench {marker} .1f--> s\n")
    problems = _problems(root)
    assert len(problems) == 1 and message in problems[0], problems


def test_file_and_case_carry_over_within_a_paragraph_only(tmp_path: Path) -> None:
    doc = ("| a | 4.9<!--bench streets.json:editor_a:setup_s .1f--> |\n| b | 1.0<!--bench editor_b:setup_s .1f--> |\n"
           "\nthen 1.0<!--bench setup_s .1f--> s\n")
    problems = _problems(_repo(tmp_path, doc))
    assert len(problems) == 1 and "README.md:4:" in problems[0] and "leaves out FILE:CASE" in problems[0]


def test_markers_in_code_are_shown_not_read(tmp_path: Path) -> None:
    marker = "9.9<!--bench streets.json:editor_a:setup_s .1f-->"
    doc = f"A marker: `{marker}`, and\n\n```md\n{marker}\n```\n\nbut {marker}\n"
    report = check_docs(_repo(tmp_path, doc), freshness=False)
    assert report.claims == 1 and "README.md:7: says '9.9'" in report.problems[0]


def test_numbers_round_half_up_from_the_json(tmp_path: Path) -> None:
    # 20.145 is 20.144999... as a float; read from the JSON it is 20.145, which a reader rounds up
    root = _repo(tmp_path, "20.14<!--bench streets.json:train:error .2f--> dB\n")
    assert "gives '20.15'" in _problems(root)[0]


def test_write_rewrites_the_numbers_and_nothing_else(tmp_path: Path) -> None:
    doc = ("Set-up 1-9<!--bench streets.json:editor_*:setup_s range .1f--> s (was 1-9), flicker\n"
           "0.1 / 0.2<!--bench editor_b:flicker_{rain,snow} .2f-->; a 2025-01-01<!--bench :created date--> run.\n")
    root = _repo(tmp_path, doc)
    report = check_docs(root, write=True, freshness=False)
    assert report.problems == [] and report.rewritten == [root / "README.md"]
    assert (root / "README.md").read_text() == (
        "Set-up 1.0-4.9<!--bench streets.json:editor_*:setup_s range .1f--> s (was 1-9), flicker\n"
        "0.83 / 1.02<!--bench editor_b:flicker_{rain,snow} .2f-->; a 2026-11-28<!--bench :created date--> run.\n")
    assert _problems(root) == []


def test_a_json_with_the_current_code_is_fresh_and_one_without_is_stale(tmp_path: Path, streets_code: dict) -> None:
    root = _repo(tmp_path, "", code=streets_code, command="wcbench bench streets --out x.json")
    bench = root / "docs" / "bench"
    assert check_freshness(bench, root=root, digests=_DIGESTS) == ([], [])

    obj = json.loads((bench / "streets.json").read_text())
    obj["code"]["digests"]["wcbench.reference_model"] = "0" * 64
    del obj["code"]["digests"]["wcbench.scenes"]
    (bench / "streets.json").write_text(json.dumps(obj))
    problems, stale = check_freshness(bench, root=root, digests=_DIGESTS)
    assert stale == [] and len(problems) == 1
    assert "docs/bench/streets.json is older than the code it measures (wcbench.reference_model changed; " \
           "wcbench.scenes is now measured too)" in problems[0]
    assert "re-run `wcbench bench streets --out x.json`" in problems[0]

    del obj["code"], obj["command"]
    (bench / "streets.json").write_text(json.dumps(obj))
    problems, _ = check_freshness(bench, root=root, digests=_DIGESTS)
    assert "records no code version" in problems[0] and "`wcbench bench streets --out docs/bench/streets.json`" \
        in problems[0]


def test_the_stale_list_allows_a_stale_json_and_must_stay_current(tmp_path: Path, streets_code: dict) -> None:
    root = _repo(tmp_path, "")
    bench = root / "docs" / "bench"
    (bench / "stale.toml").write_text('[[stale]]\nfile = "streets.json"\nsince = 2026-11-29\nreason = "not re-run"\n'
                                      'rerun = "wcbench bench streets --data-root D --out docs/bench/streets.json"\n')
    problems, stale = check_freshness(bench, root=root, digests=_DIGESTS)
    assert problems == [] and len(stale) == 1
    assert "listed since 2026-11-29 (not re-run)" in stale[0] and "--data-root D" in stale[0]

    # the list's command names the run that writes the right file, over one the JSON recorded
    obj = json.loads((bench / "streets.json").read_text())
    obj["command"] = "wcbench bench streets --data-root D --out /tmp/scratch/streets.json"
    (bench / "streets.json").write_text(json.dumps(obj))
    _, stale = check_freshness(bench, root=root, digests=_DIGESTS)
    assert "--out docs/bench/streets.json" in stale[0] and "/tmp/scratch" not in stale[0]

    # re-run: the entry must go
    BenchReport("streets", code=streets_code).write(bench / "streets.json")
    problems, stale = check_freshness(bench, root=root, digests=_DIGESTS)
    assert stale == [] and "up to date with its code: remove it" in problems[0]

    (bench / "streets.json").unlink()
    problems, _ = check_freshness(bench, root=root, digests=_DIGESTS)
    assert problems == ["docs/bench/stale.toml lists 'streets.json', which is not in docs/bench"]


def test_a_stale_entry_needs_a_date_and_a_reason(tmp_path: Path) -> None:
    path = tmp_path / "stale.toml"
    path.write_text('[[stale]]\nfile = "a.json"\nsince = "yesterday"\nreason = "x"\n')
    with pytest.raises(ValueError, match="entry 1 needs file"):
        read_stale_list(path)
    path.write_text('[[stale]]\nfile = "a.json"\nsince = 2026-11-29\nreason = " "\n')
    with pytest.raises(ValueError, match="entry 1 needs file"):
        read_stale_list(path)
    assert read_stale_list(tmp_path / "absent.toml") == {}
