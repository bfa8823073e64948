"""Run a benchmark suite and write its JSON (one schema for all suites: wcbench.bench.schema).

Suites measure speed against error in one run (fast path vs its slow reference, ours vs the
yardsticks of docs/design.md §8); they never assert times.

Examples::

    wcbench bench --list
    wcbench bench metrics --out bench/metrics.json
    wcbench bench raster --data-root ../shared/data --out bench/raster.json
    wcbench bench validity --quick --out bench/          # a folder: writes bench/validity.json
    wcbench bench --all --data-root ../shared/data --out bench/     # every suite, summary.md, charts/
    wcbench bench --all --summary-only --out bench/                # table and charts from the JSON files

``--all`` runs every suite (the model suite alone takes over an hour; ``--quick`` is a smoke run of every
case, under half an hour on 2 cores),
writes ``OUT/<suite>.json``, then ``OUT/summary.md`` (one table, defaults and their place on the
Pareto front) and ``OUT/charts/<suite>-<knob>.png`` (time against error per knob).

``bench list`` / ``bench all`` and ``--json FILE`` are the deprecated spellings of ``--list``,
``--all`` and ``--out FILE``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from wcbench.bench import SUITES, WEIGHTS
from wcbench.cli.common import (
    add_data_root_argument,
    add_deprecated_alias,
    add_offline_argument,
    add_output_argument,
    used_deprecated,
    warn_deprecated,
)
from wcbench.core.errors import InputError, UnknownNameError
from wcbench.core.registry import LazyRegistry

HELP = "run a benchmark suite (speed vs error)"

#: Folder of ``--all`` when no ``--out`` is given.
ALL_DEFAULT_OUT = Path("bench")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``SUITE | --list | --all``, ``[--out FILE|DIR] [--data-root DIR] [--quick] [--summary-only]``."""
    parser.add_argument("suite", nargs="?", default=None, help="suite name (see --list)")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--list", action="store_true", help="list the suites and exit")
    which.add_argument("--all", action="store_true",
                       help="run every suite, then write OUT/summary.md and OUT/charts/")
    add_output_argument(parser, help="one suite: the benchmark JSON file (OUT ending in .json) or a folder for "
                                     "OUT/<suite>.json (default: write none); with --all: folder of the "
                                     f"suites' JSON, summary.md and charts/ (default: {ALL_DEFAULT_OUT})")
    add_deprecated_alias(parser, "--json", use="--out", dest="out", type=Path, metavar="FILE")
    parser.add_argument("--summary-only", action="store_true",
                        help="with --all: rebuild summary.md and charts/ from the JSON files in --out, run nothing")
    add_data_root_argument(parser, what=", for real-data cases")
    parser.add_argument("--quick", action="store_true", help="small sizes: a smoke run, not a measurement")
    parser.add_argument("--threads", default=None, metavar="N,N,...",
                        help="raster and model: thread counts of the per-phase profile, the first the baseline "
                             "(default 1,2; e.g. 1,2,4,8,16)")
    add_offline_argument(parser)


def _json_path(out: Path, suite: str) -> Path:
    """The JSON file ``--out`` names for one suite: OUT itself when it ends in .json, else OUT/<suite>.json."""
    return out if out.suffix.lower() == ".json" else out / f"{suite}.json"


def _suite_args(args: argparse.Namespace, suite: str, path: Path | None, *, threads: str | None) -> list[str]:
    """The arguments of ``wcbench`` that run ``suite`` alone as ``args`` ran it, writing ``path``."""
    out = [] if path is None else ["--out", str(path)]
    data_root = [] if args.data_root is None else ["--data-root", str(args.data_root)]
    threads_arg = [] if threads is None else ["--threads", threads]
    offline = ["--offline"] if args.offline else []
    return ["bench", suite, *data_root, *(["--quick"] if args.quick else []), *threads_arg, *offline, *out]


def _fetch_weights(names: list[str], args: argparse.Namespace) -> None:
    """The model-store entries the suites ``names`` read (:data:`~wcbench.bench.WEIGHTS`), fetched
    where missing before the first one runs, unless ``--offline``."""
    from wcbench.core.models.fetch import fetch_missing, is_offline

    needed = sorted({w for n in names for w in WEIGHTS.get(n, ())})
    if needed:
        fetch_missing(needed, offline=is_offline(args.offline))


def run(args: argparse.Namespace) -> int:
    """Run the suite, print its table, write the JSON (or list the suites, or run them all)."""
    from wcbench.core.storage import check_writable_folder
    from wcbench.scenes.sets import data_root_from

    suites: LazyRegistry = LazyRegistry("benchmark", SUITES)  # entry points add suites of other packages
    if args.suite in ("list", "all") and args.suite not in suites:  # the old spellings
        warn_deprecated(f"`wcbench bench {args.suite}`", f"`wcbench bench --{args.suite}`")
        setattr(args, args.suite, True)
        args.suite = None
    if args.list and args.all:
        raise InputError("--list and --all go alone: give one")
    if args.suite is not None and (args.list or args.all):
        raise InputError(f"give a suite name, --list or --all, not both ({args.suite!r} and "
                         f"{'--list' if args.list else '--all'})")
    if args.list:
        for name in suites.names():
            print(f"{name:10s} {SUITES.get(name, '(entry point)')}")
        return 0
    if args.all:
        if used_deprecated(args, "--json"):
            raise InputError("--json names one suite's file; `bench --all` writes every suite's JSON into --out")
        return _run_all(args, suites)
    if args.suite is None:
        raise InputError(f"expected a suite name ({', '.join(suites.names())}), --list or --all")
    if args.summary_only:
        raise InputError("--summary-only goes with `bench --all`")
    if args.suite not in suites:
        raise UnknownNameError("benchmark suite", args.suite, suites.names())
    path = None if args.out is None else _json_path(args.out, args.suite)
    if path is not None:
        check_writable_folder(path.parent, what="folder of the benchmark JSON")
    options = {}
    if args.threads is not None:
        if args.suite not in ("raster", "model"):
            raise InputError(f"--threads goes with `bench raster` and `bench model`, not {args.suite!r}")
        from wcbench.bench.phases import parse_threads

        try:
            options["threads"] = parse_threads(args.threads)
        except ValueError as exc:
            raise InputError(f"--threads: {exc}") from None
    from wcbench.bench.code_version import measured_code
    from wcbench.bench.schema import bench_command

    _fetch_weights([args.suite], args)
    code = measured_code(args.suite)  # the code as the suite starts, not as it may be an hour later
    report = suites.get(args.suite)(data_root=data_root_from(args.data_root), quick=args.quick, **options)
    report.code, report.command = code, bench_command(_suite_args(args, args.suite, path, threads=args.threads))
    print(report.format_table())
    if path is not None:
        report.write(path)
        print(f"wrote {path}")
    sys.stdout.flush()
    for what in report.stand_ins:
        print(f"WARNING: stand-in data: {what} (these numbers are not the documented ones; "
              "give --data-root or set WCBENCH_DATA)", file=sys.stderr)
    return 0


def _run_all(args: argparse.Namespace, suites: LazyRegistry) -> int:
    from wcbench.bench.overview import ALL_SUITES, run_all, summarize
    from wcbench.bench.schema import bench_command
    from wcbench.core.storage import check_writable_folder
    from wcbench.scenes.sets import data_root_from

    out = ALL_DEFAULT_OUT if args.out is None else args.out
    check_writable_folder(out, what="benchmark folder")
    try:
        if args.summary_only:
            done = summarize(out)
        else:
            order = [n for n in ALL_SUITES if n in suites] + [n for n in suites.names() if n not in ALL_SUITES]
            _fetch_weights(order, args)
            done = run_all({n: suites.get(n) for n in order}, out=out,
                           data_root=data_root_from(args.data_root), quick=args.quick,
                           echo=lambda line: print(line, file=sys.stderr, flush=True),
                           command=lambda n: bench_command(_suite_args(args, n, out / f"{n}.json", threads=None)))
    except ValueError as exc:
        raise InputError(str(exc)) from None
    print(f"wrote {out / 'summary.md'} and {len(done['charts'])} charts in {out / 'charts'}")
    for suite, knob, case in done["off_front"]:
        print(f"default off its Pareto front: {suite} / {knob}: {case}")
    sys.stdout.flush()
    return 0
