"""The benchmark numbers the docs quote, checked against their JSON, and the JSON against the code.

A number the README or ``docs/`` quotes from a benchmark JSON of ``docs/bench/`` carries a marker
right after it, an HTML comment that Markdown does not show::

    the default profile's training takes 190.1<!--bench model.json:weathercity:time_ms /1000 .1f--> s

Markers in code (a fenced block, an inline span) are shown, not read. ``python -m
wcbench.bench.claims`` (run from the repository root) checks that the text before each
marker is the JSON's value as the marker formats it, and that no benchmark JSON of ``docs/bench/``
is older than the code it measures (:mod:`.code_version`) unless ``docs/bench/stale.toml`` lists
it, with its date and reason. ``--write`` rewrites the numbers from the JSON instead (after a
re-run). ``tests/test_doc_numbers.py`` runs the check. docs/guide.md ("Numbers in the docs") is
the user's account of this.

A marker is ``<!--bench PATH [OP ...] FORMAT-->``:

``PATH``
    ``FILE:CASE:FIELD``. ``FILE`` is a JSON under ``docs/bench/`` (``streets.json``,
    ``history/validity-2026-11-26.json``); ``CASE`` a case's ``name`` (empty: the file's top level,
    as in ``streets.json::created``); ``FIELD`` a key, dotted into nested objects (``frames.15.iou``).
    ``CASE:FIELD`` takes ``FILE``, and ``FIELD`` takes ``FILE`` and ``CASE``, from the marker before
    it in the same paragraph or table (no blank line between). ``{a,b,c}`` lists several cases or
    fields (their values are written joined by `` / ``, case by case); ``*`` in ``CASE`` matches
    several cases (``editor_*``), which an ``OP`` then reduces or the join writes.
``OP``
    ``/N`` or ``*N`` scales every value (``/1000``: ms to s; ``*100``: a fraction to %); ``min``,
    ``max``, ``mean`` reduce the values to one; ``range`` writes ``lo-hi`` (``lo`` when both are
    written alike).
``FORMAT``
    A Python format spec (``.1f``, ``.3f``, ``,.0f``, ``d``) or ``date`` (an ISO time written as
    ``YYYY-MM-DD``). Numbers are rounded half up from the value as the JSON writes it (``20.145``
    is ``20.15`` at ``.2f``); a ``null`` value is written ``-``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import decimal
import fnmatch
import json
import math
import re
import statistics
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from wcbench.bench.code_version import code_changes, measured_code

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

#: Folder of the benchmark JSON the docs quote, in the repository.
BENCH_DIR = Path("docs") / "bench"
#: The allow-list of benchmark JSONs known to be older than their code, in :data:`BENCH_DIR`.
STALE_LIST = "stale.toml"
#: Benchmark JSONs of dated findings, never re-run, hence never stale (in :data:`BENCH_DIR`).
HISTORY = "history"
#: The command that rewrites the docs' numbers, named in messages.
WRITE_COMMAND = "python -m wcbench.bench.claims --write"

_MARKER = re.compile(r"<!--bench\s+(.*?)\s*-->", re.S)
# code shows a marker rather than making one: fenced blocks, and inline spans within a paragraph
_CODE = re.compile(r"^[ \t]*(```|~~~).*?^[ \t]*\1|(`+)(?:(?!\n[ \t]*\n).)+?\2", re.S | re.M)
_PARAGRAPH_BREAK = re.compile(r"\n[ \t]*\n")
_NUM = r"-?\d(?:[\d,]*\d)?(?:\.\d+)?(?:e[-+]?\d+)?"
_VALUE = rf"(?:{_NUM}|-)"
_REDUCE: dict[str, Callable[[list[float]], float]] = {"min": min, "max": max, "mean": statistics.fmean}


class ClaimError(ValueError):
    """A marker that cannot be read or resolved; the message names what was expected."""


@dataclass(frozen=True)
class Claim:
    """One marker: where it is, what it reads and how it writes it (module docstring)."""

    doc: Path
    line: int
    start: int
    end: int
    marker: str
    file: str
    case: str
    field: str
    ops: tuple[str, ...]
    fmt: str

    @property
    def source(self) -> str:
        """``FILE:CASE:FIELD`` as resolved."""
        return f"{self.file}:{self.case}:{self.field}"

    @property
    def reduce(self) -> str | None:
        """The reducing ``OP`` (``min``, ``max``, ``mean``, ``range``), if any."""
        ops = [op for op in self.ops if op in _REDUCE or op == "range"]
        return ops[0] if ops else None


@dataclass
class CheckReport:
    """What :func:`check_docs` found.

    Attributes
    ----------
    claims : int
        Markers read.
    problems : list of str
        One line each: a number that differs from its JSON, a marker that cannot be resolved, a
        benchmark JSON older than its code and not allow-listed, an allow-list entry not needed.
    stale : list of str
        The allow-listed stale JSONs, one line each (reported, not a problem).
    rewritten : list of Path
        Docs ``write=True`` changed.
    """

    claims: int = 0
    problems: list[str] = field(default_factory=list)
    stale: list[str] = field(default_factory=list)
    rewritten: list[Path] = field(default_factory=list)


def expand_braces(text: str) -> list[str]:
    """``a{1,2}b{x,y}`` -> ``["a1bx", "a1by", "a2bx", "a2by"]`` (no nesting)."""
    m = re.search(r"\{([^{}]*)\}", text)
    if m is None:
        if "{" in text or "}" in text:
            raise ClaimError(f"unbalanced braces in {text!r}")
        return [text]
    return [out for alt in m.group(1).split(",")
            for out in expand_braces(text[:m.start()] + alt + text[m.end():])]


def parse_claims(text: str, *, doc: Path) -> tuple[list[Claim], list[str]]:
    """The markers of a Markdown text, with ``FILE`` and ``CASE`` carried over inside a paragraph.

    Returns
    -------
    claims : list of Claim
    problems : list of str
        Markers that cannot be read, as ``doc:line: marker: why``.
    """
    claims: list[Claim] = []
    problems: list[str] = []
    context: tuple[str, str] | None = None
    last_end = 0
    code = [(c.start(), c.end()) for c in _CODE.finditer(text)]
    for m in _MARKER.finditer(text):
        if any(start < m.start() < end for start, end in code):
            continue
        line = text.count("\n", 0, m.start()) + 1
        if _PARAGRAPH_BREAK.search(text, last_end, m.start()):
            context = None
        last_end = m.end()
        try:
            words = m.group(1).split()
            if len(words) < 2:
                raise ClaimError("expected `<!--bench FILE:CASE:FIELD [OP ...] FORMAT-->`")
            parts = words[0].split(":")
            if len(parts) > 3:
                raise ClaimError(f"{words[0]!r} has more than FILE:CASE:FIELD")
            if len(parts) < 3 and context is None:
                raise ClaimError(f"{words[0]!r} leaves out FILE{'' if len(parts) == 2 else ':CASE'}, "
                                 "and no marker before it in this paragraph names it")
            if len(parts) == 3:
                file, case, fld = parts
            elif len(parts) == 2 and context is not None:
                file, (case, fld) = context[0], parts
            else:
                (file, case), fld = context or ("", ""), parts[0]
            if not fld:
                raise ClaimError(f"{words[0]!r} names no FIELD")
            for op in words[1:-1]:
                if op not in _REDUCE and op != "range" and not re.fullmatch(r"[*/]\d+(?:\.\d+)?", op):
                    raise ClaimError(f"unknown OP {op!r} (expected /N, *N, min, max, mean or range)")
            claim = Claim(doc=doc, line=line, start=m.start(), end=m.end(), marker=m.group(0), file=file,
                          case=case, field=fld, ops=tuple(words[1:-1]), fmt=words[-1])
            if sum(op in _REDUCE or op == "range" for op in claim.ops) > 1:
                raise ClaimError("more than one of min, max, mean, range")
            context = (file, case)
            claims.append(claim)
        except ClaimError as exc:
            problems.append(f"{doc}:{line}: {m.group(0)}: {exc}")
    return claims, problems


def _lookup(obj: Any, dotted: str, *, where: str) -> Any:
    for part in dotted.split("."):
        if isinstance(obj, dict) and part in obj:
            obj = obj[part]
        elif isinstance(obj, list) and part.isdigit() and int(part) < len(obj):
            obj = obj[int(part)]
        else:
            keys = ", ".join(sorted(map(str, obj))[:40]) if isinstance(obj, dict) else type(obj).__name__
            raise ClaimError(f"{where} has no {dotted!r} ({part!r} not in: {keys})")
    return obj


def claim_values(claim: Claim, doc: dict[str, Any]) -> list[Any]:
    """The values a claim reads from its benchmark JSON ``doc``, case by case, field by field.

    Raises
    ------
    ClaimError
        If a case or a field is missing.
    """
    fields = expand_braces(claim.field)
    if not claim.case:
        return [_lookup(doc, f, where=claim.file) for f in fields]
    cases = doc.get("cases") or []
    values = []
    for pattern in expand_braces(claim.case):
        if any(c in pattern for c in "*?["):
            found = [c for c in cases if fnmatch.fnmatchcase(str(c.get("name")), pattern)]
        else:
            found = [c for c in cases if c.get("name") == pattern]
        if not found:
            names = ", ".join(str(c.get("name")) for c in cases)
            raise ClaimError(f"{claim.file} has no case {pattern!r} (its cases: {names})")
        for case in found:
            values += [_lookup(case, f, where=f"{claim.file} case {case['name']!r}") for f in fields]
    return values


def _format_one(value: Any, fmt: str, *, what: str) -> str:
    if value is None:
        return "-"
    if fmt == "date":
        try:
            return _dt.datetime.fromisoformat(str(value)).date().isoformat()
        except ValueError:
            raise ClaimError(f"{what} is {value!r}, not an ISO time for `date`") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ClaimError(f"{what} is {value!r}, not a number")
    if fmt and fmt[-1] in "dn" and isinstance(value, float) and value.is_integer():
        value = int(value)
    try:
        if isinstance(value, float) and math.isfinite(value) and (not fmt or fmt[-1] not in "dnxXobc"):
            # half up from the value as the JSON writes it, as a reader rounds: a JSON that stores
            # 65.85 (rounded by its suite) reads 65.9 at one decimal where the float's 65.8499... gives 65.8
            with decimal.localcontext() as ctx:
                ctx.rounding = decimal.ROUND_HALF_UP
                return format(decimal.Decimal(repr(value)), fmt)
        return format(value, fmt)
    except ValueError as exc:
        raise ClaimError(f"format {fmt!r} does not apply to {value!r} ({exc})") from None


def render(claim: Claim, values: Sequence[Any]) -> str:
    """The text a claim's values are written as (module docstring: ``OP`` and ``FORMAT``).

    Raises
    ------
    ClaimError
        If several values have neither a join nor a reducing ``OP`` to go by, a reduced value is
        ``null`` or not a number, or ``FORMAT`` does not apply.
    """
    what = claim.source
    vals = list(values)
    for op in claim.ops:
        if op[0] in "*/":
            k = float(op[1:])
            vals = [v if v is None or isinstance(v, bool) or not isinstance(v, (int, float))
                    else (v * k if op[0] == "*" else v / k) for v in vals]
    reduce = claim.reduce
    if reduce is None:
        return " / ".join(_format_one(v, claim.fmt, what=what) for v in vals)
    if any(v is None or isinstance(v, bool) or not isinstance(v, (int, float)) for v in vals):
        raise ClaimError(f"{what}: {reduce} of values that are not all numbers: {vals}")
    if reduce == "range":
        lo, hi = (_format_one(v, claim.fmt, what=what) for v in (min(vals), max(vals)))
        return lo if lo == hi else f"{lo}-{hi}"
    return _format_one(_REDUCE[reduce](vals), claim.fmt, what=what)


def written_pattern(claim: Claim, count: int) -> str:
    """A regular expression of what the text before a marker may hold where its value goes: the
    claim's shape (``count`` values joined by `` / ``, a range, a date) with any numbers in it."""
    if claim.fmt == "date":
        return r"\d{4}-\d{2}-\d{2}"
    if claim.reduce == "range":
        return rf"{_NUM}(?:-{_NUM})?"
    n = 1 if claim.reduce else count
    return rf"{_VALUE}(?: / {_VALUE}){{{n - 1}}}"


def _show(path: Path, root: Path) -> str:
    try:
        return str(path.relative_to(root))
    except ValueError:
        return str(path)


def check_text(text: str, *, doc: Path, load: Callable[[str], dict[str, Any]],
               write: bool = False) -> tuple[str, int, list[str]]:
    """Check (or rewrite) the claims of one Markdown text.

    Parameters
    ----------
    text : str
        The Markdown.
    doc : Path
        Its name in messages.
    load : callable
        ``FILE`` of a marker -> the benchmark JSON; raises :class:`ClaimError` when it cannot.
    write : bool
        Replace each number that differs by the JSON's instead of reporting it.

    Returns
    -------
    text : str
        The text, rewritten where ``write`` changed it.
    claims : int
        Markers read.
    problems : list of str
        ``doc:line: ...`` lines (module docstring).
    """
    claims, problems = parse_claims(text, doc=doc)
    edits: list[tuple[int, int, str]] = []
    for claim in claims:
        where = f"{doc}:{claim.line}: {claim.marker}"
        try:
            values = claim_values(claim, load(claim.file))
            expected = render(claim, values)
        except ClaimError as exc:
            problems.append(f"{where}: {exc}")
            continue
        window = max(0, claim.start - 400)
        m = re.search(rf"(?<![\w.,-])(?:{written_pattern(claim, len(values))})$", text[window:claim.start])
        if m is None:
            problems.append(f"{where}: expected {expected!r} right before the marker")
        elif m.group(0) != expected:
            if write:
                edits.append((window + m.start(), claim.start, expected))
            else:
                how = "".join(f" {op}" for op in claim.ops)
                problems.append(f"{doc}:{claim.line}: says {m.group(0)!r} where {claim.source}{how} gives "
                                f"{expected!r} (`{WRITE_COMMAND}` rewrites it)")
    for start, end, new in reversed(edits):
        text = text[:start] + new + text[end:]
    return text, len(claims), problems


@dataclass(frozen=True)
class StaleEntry:
    """One entry of :data:`STALE_LIST`: a benchmark JSON allowed to be older than its code."""

    since: _dt.date
    reason: str
    rerun: str | None = None


def read_stale_list(path: Path) -> dict[str, StaleEntry]:
    """The allow-list of stale benchmark JSONs: file name (in its folder) -> entry.

    The file is TOML, ``[[stale]]`` tables of ``file``, ``since`` (a date), ``reason`` and
    optionally ``rerun`` (the command that re-runs it, for a JSON that records none or whose recorded
    command wrote elsewhere: it is named instead); a missing file is an empty list.

    Raises
    ------
    ValueError
        If the file is not TOML or an entry lacks a field, names a file twice, or gives no date.
    """
    if not path.is_file():
        return {}
    try:
        entries = tomllib.loads(path.read_text(encoding="utf-8")).get("stale", [])
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not TOML ({exc})") from None
    out: dict[str, StaleEntry] = {}
    for i, entry in enumerate(entries, 1):
        file, since, reason, rerun = (entry.get(k) for k in ("file", "since", "reason", "rerun"))
        if not isinstance(file, str) or not isinstance(since, _dt.date) or not isinstance(reason, str) \
                or not reason.strip() or not isinstance(rerun, (str, type(None))) \
                or set(entry) - {"file", "since", "reason", "rerun"}:
            raise ValueError(f"{path}: entry {i} needs file (a string), since (a date, e.g. 2026-11-29) and "
                             f"a reason, and may give rerun (a command); got {entry!r}")
        if file in out:
            raise ValueError(f"{path}: {file!r} is listed twice")
        out[file] = StaleEntry(since=since, reason=" ".join(reason.split()), rerun=rerun)
    return out


def check_freshness(bench_dir: Path, *, root: Path, digests: dict[str, str] | None = None
                    ) -> tuple[list[str], list[str]]:
    """Which benchmark JSONs of ``bench_dir`` are older than the code they measure.

    Every ``*.json`` directly in ``bench_dir`` is checked (:func:`~.code_version.code_changes`);
    those of ``history/`` are dated records of past findings, never re-run. ``root`` is what
    messages show paths relative to; ``digests`` (module -> digest) may carry the digests of the
    code over several calls.

    Returns
    -------
    problems : list of str
        A stale JSON that :data:`STALE_LIST` does not list (with the command that re-runs it), an
        entry of that list whose JSON is not stale or does not exist.
    stale : list of str
        The listed stale JSONs, with their date, reason and why they are stale.
    """
    listed = read_stale_list(bench_dir / STALE_LIST)
    problems: list[str] = []
    stale: list[str] = []
    digests = {} if digests is None else digests
    allow_list = _show(bench_dir / STALE_LIST, root)
    for path in sorted(bench_dir.glob("*.json")):
        doc = json.loads(path.read_text(encoding="utf-8"))
        suite = str(doc.get("suite"))
        reasons = code_changes(doc, current=measured_code(suite, memo=digests))
        shown = _show(path, root)
        if not reasons:
            if path.name in listed:
                problems.append(f"{shown} is up to date with its code: remove it from {allow_list}")
            continue
        entry = listed.get(path.name)
        # the list's command corrects a recorded one (a run written to a scratch folder, then copied)
        recorded = (entry.rerun if entry else None) or doc.get("command")
        command = (f"`{recorded}`" if recorded else
                   f"`wcbench bench {suite} --out {shown}` with the options its docs/findings.md section gives")
        if entry is not None:
            stale.append(f"{shown}, listed since {entry.since.isoformat()} ({entry.reason}): "
                         f"{'; '.join(reasons)}; re-run {command}")
        else:
            problems.append(f"{shown} is older than the code it measures ({'; '.join(reasons)}): re-run "
                            f"{command}, then `{WRITE_COMMAND}`; or list it in {allow_list} with a date and a reason")
    for name in sorted(set(listed) - {p.name for p in bench_dir.glob("*.json")}):
        problems.append(f"{allow_list} lists {name!r}, which is not in {_show(bench_dir, root)}")
    return problems, stale


def doc_paths(root: Path) -> list[Path]:
    """The Markdown the check reads: ``README.md`` and every ``*.md`` under ``docs/``."""
    return [p for p in [root / "README.md", *sorted((root / "docs").rglob("*.md"))] if p.is_file()]


def check_docs(root: Path, *, paths: Sequence[Path] | None = None, write: bool = False,
               freshness: bool = True) -> CheckReport:
    """Check the docs' benchmark numbers against ``root/docs/bench`` and its JSON against the code.

    Parameters
    ----------
    root : Path
        The repository root.
    paths : sequence of Path, optional
        The Markdown files (default :func:`doc_paths`).
    write : bool
        Rewrite the numbers that differ from their JSON (the other problems are still reported).
    freshness : bool
        Also check the JSON against the code (:func:`check_freshness`).
    """
    bench_dir = root / BENCH_DIR
    cache: dict[str, dict[str, Any]] = {}

    def load(file: str) -> dict[str, Any]:
        if file not in cache:
            path = (bench_dir / file).resolve()
            if not path.is_relative_to(bench_dir.resolve()) or path.suffix != ".json":
                raise ClaimError(f"{file!r} is not a JSON file under {BENCH_DIR}")
            if not path.is_file():
                raise ClaimError(f"no {BENCH_DIR / file}")
            try:
                cache[file] = json.loads(path.read_text(encoding="utf-8"))
            except json.JSONDecodeError as exc:
                raise ClaimError(f"{BENCH_DIR / file} is not JSON ({exc})") from None
        return cache[file]

    report = CheckReport()
    for path in doc_paths(root) if paths is None else paths:
        text = path.read_text(encoding="utf-8")
        new, count, problems = check_text(text, doc=Path(_show(path, root)), load=load, write=write)
        report.claims += count
        report.problems += problems
        if new != text:
            path.write_text(new, encoding="utf-8")
            report.rewritten.append(path)
    if freshness:
        problems, report.stale = check_freshness(bench_dir, root=root)
        report.problems += problems
    return report


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m wcbench.bench.claims [--write] [--root DIR] [FILE ...]``: 0 when all is well, else 1."""
    parser = argparse.ArgumentParser(prog="python -m wcbench.bench.claims", description=__doc__.split("\n")[0])
    parser.add_argument("files", nargs="*", type=Path, help="Markdown files (default: README.md and docs/**/*.md)")
    parser.add_argument("--root", type=Path, default=Path("."), help="repository root (default: .)")
    parser.add_argument("--write", action="store_true", help="rewrite the numbers from the JSON")
    args = parser.parse_args(argv)
    root = args.root.resolve()
    report = check_docs(root, paths=[p.resolve() for p in args.files] or None, write=args.write)
    for path in report.rewritten:
        print(f"rewrote {_show(path, root)}")
    for line in report.stale:
        print(f"stale (allowed): {line}")
    for line in report.problems:
        print(line)
    print(f"{report.claims} numbers checked, {len(report.problems)} problems, {len(report.stale)} stale JSON allowed")
    return 1 if report.problems else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
