"""Run a benchmark suite and write its JSON (one schema for all suites: wcbench.bench.schema).

Suites measure speed against error in one run (fast path vs its slow reference, ours vs the
yardsticks of docs/design.md §8); they never assert times.

Examples::

    wcbench bench list
    wcbench bench metrics --json bench/metrics.json
    wcbench bench raster --data-root ../shared/data --json bench/raster.json
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from wcbench.bench import SUITES
from wcbench.core.errors import UnknownNameError
from wcbench.core.registry import LazyRegistry

HELP = "run a benchmark suite (speed vs error)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``SUITE [--json FILE] [--data-root DIR] [--quick]``."""
    parser.add_argument("suite", help="suite name, or `list`")
    parser.add_argument("--json", type=Path, default=None, help="write the benchmark JSON here")
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
    if args.suite not in suites:
        raise UnknownNameError("benchmark suite", args.suite, suites.names())
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
