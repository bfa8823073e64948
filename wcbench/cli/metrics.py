"""List the metrics with what they need and which way is better, and the options each takes.

Examples::

    wcbench metrics list
    wcbench metrics show lpips     # every option: type, range or choices, default, meaning

``show`` lists the declared options of a metric (``--metric-option METRIC.KEY=VALUE`` on run and
evaluate, e.g. ``lpips.net=vgg``): run and evaluate check every option against this list before
any folder is made or weight fetched, and refuse a bad one in one line.
"""

from __future__ import annotations

import argparse

HELP = "list metrics and show their options"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``list`` and ``show NAME``."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    sub.add_parser("list", help="list metrics")
    show = sub.add_parser("show", help="show a metric and every option it takes (type, range, default, meaning)")
    show.add_argument("name", metavar="NAME", help="metric name (see `wcbench metrics list`)")


def show(name: str) -> int:
    """Print metric ``name``: outputs, direction, what it needs, description and its declared options."""
    from wcbench.core.options import schema_lines
    from wcbench.metrics.registry import METRICS, metric_schema

    cls = METRICS.get(name)
    arrow = "higher" if cls.higher_is_better else "lower"
    print(f"{name}  {arrow} is better  outputs: {', '.join(cls.outputs)}\n  {cls.description}")
    lines = schema_lines(metric_schema(name))
    if not lines:
        print("options: none")
        return 0
    print(f"options (--metric-option {name}.KEY=VALUE):")
    for line in lines:
        print(f"  {line}")
    return 0


def run(args: argparse.Namespace) -> int:
    """Print the metrics, or one metric's options."""
    from wcbench.metrics.registry import DEFAULT_METRICS, METRICS

    if args.action == "show":
        return show(args.name)

    for name in METRICS.names():
        cls = METRICS.get(name)
        needs = [w for w, on in (("reference", cls.needs_reference), ("no fog", cls.compares_content)) if on]
        arrow = "higher" if cls.higher_is_better else "lower"
        default = "*" if name in DEFAULT_METRICS else " "
        print(f"{default} {name:20s} {arrow:6s} {('needs ' + '+'.join(needs)) if needs else '':16s} {cls.description}")
    print("\n* computed by default; outputs: " + ", ".join(
        o for n in METRICS.names() for o in METRICS.get(n).outputs))
    print("options of each: wcbench metrics show NAME")
    return 0
