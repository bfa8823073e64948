"""Run a benchmark suite and write its JSON (one schema for all suites: wcbench.bench.schema).

Suites measure speed against error in one run (fast path vs its slow reference, ours vs the
yardsticks of docs/design.md §8); they never assert times.

Examples::

    wcbench bench list
    wcbench bench metrics --json bench/metrics.json
    wcbench bench raster --data-root ../shared/data --json bench/raster.json
    wcbench bench all --data-root ../shared/data --out bench/      # every suite, summary.md, charts/
    wcbench bench all --summary-only --out bench/                 # table and charts from the JSON files

``all`` runs every suite (the model suite alone takes over an hour; ``--quick`` a few minutes),
writes ``OUT/<suite>.json``, then ``OUT/summary.md`` (one table, defaults and their place on the
Pareto front) and ``OUT/charts/<suite>-<knob>.png`` (time against error per knob).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from wcbench.bench import SUITES
from wcbench.core.errors import InputError, UnknownNameError
from wcbench.core.registry import LazyRegistry

HELP = "run a benchmark suite (speed vs error)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``SUITE [--json FILE] [--data-root DIR] [--quick]``."""
    parser.add_argument("suite", help="suite name, `all`, or `list`")
    parser.add_argument("--json", type=Path, default=None, help="write the benchmark JSON here")
    parser.add_argument("--out", type=Path, default=Path("bench"),
                        help="with `all`: folder of the suites' JSON, summary.md and charts/ (default: bench)")
    parser.add_argument("--summary-only", action="store_true",
                        help="with `all`: rebuild summary.md and charts/ from the JSON files in --out, run nothing")
    parser.add_argument("--data-root", type=Path, default=None,
                        help="dataset folder for real-data cases (default: $WCBENCH_DATA)")
    parser.add_argument("--quick", action="store_true", help="small sizes: a smoke run, not a measurement")


def run(args: argparse.Namespace) -> int:
    """Run the suite, print its table, write the JSON."""
    from wcbench.core.storage import check_writable_folder
    from wcbench.scenes.sets import data_root_from

    suites: LazyRegistry = LazyRegistry("benchmark", SUITES)  # entry points add suites of other packages
    if args.suite == "list":
        for name in suites.names():
            print(f"{name:10s} {SUITES.get(name, '(entry point)')}")
        return 0
    if args.suite == "all":
        if args.json:
            raise InputError("--json names one suite's file; `bench all` writes every suite's JSON into --out")
        return _run_all(args, suites)
    if args.summary_only:
        raise InputError("--summary-only goes with `bench all`")
    if args.suite not in suites:
        raise UnknownNameError("benchmark suite", args.suite, [*suites.names(), "all"])
    if args.json:
        check_writable_folder(args.json.parent, what="folder of the benchmark JSON")
    report = suites.get(args.suite)(data_root=data_root_from(args.data_root), quick=args.quick)
    print(report.format_table())
    if args.json:
        report.write(args.json)
        print(f"wrote {args.json}")
    sys.stdout.flush()
    for what in report.stand_ins:
        print(f"WARNING: stand-in data: {what} (these numbers are not the documented ones; "
              "give --data-root or set WCBENCH_DATA)", file=sys.stderr)
    return 0


def _run_all(args: argparse.Namespace, suites: LazyRegistry) -> int:
    from wcbench.bench.overview import ALL_SUITES, run_all, summarize
    from wcbench.core.storage import check_writable_folder
    from wcbench.scenes.sets import data_root_from

    check_writable_folder(args.out, what="benchmark folder")
    try:
        if args.summary_only:
            done = summarize(args.out)
        else:
            order = [n for n in ALL_SUITES if n in suites] + [n for n in suites.names() if n not in ALL_SUITES]
            done = run_all({n: suites.get(n) for n in order}, out=args.out,
                           data_root=data_root_from(args.data_root), quick=args.quick,
                           echo=lambda line: print(line, file=sys.stderr, flush=True))
    except ValueError as exc:
        raise InputError(str(exc)) from None
    print(f"wrote {args.out / 'summary.md'} and {len(done['charts'])} charts in {args.out / 'charts'}")
    for suite, knob, case in done["off_front"]:
        print(f"default off its Pareto front: {suite} / {knob}: {case}")
    sys.stdout.flush()
    return 0
