"""List the metrics with what they need and which way is better.

Example::

    wcbench metrics list
"""

from __future__ import annotations

import argparse

HELP = "list metrics"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``list``."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    sub.add_parser("list", help="list metrics")


def run(args: argparse.Namespace) -> int:
    """Print the metrics."""
    from wcbench.metrics.registry import DEFAULT_METRICS, METRICS

    for name in METRICS.names():
        cls = METRICS.get(name)
        needs = [w for w, on in (("reference", cls.needs_reference), ("no fog", cls.compares_content)) if on]
        arrow = "higher" if cls.higher_is_better else "lower"
        default = "*" if name in DEFAULT_METRICS else " "
        print(f"{default} {name:20s} {arrow:6s} {('needs ' + '+'.join(needs)) if needs else '':16s} {cls.description}")
    print("\n* computed by default; outputs: " + ", ".join(
        o for n in METRICS.names() for o in METRICS.get(n).outputs))
    return 0
