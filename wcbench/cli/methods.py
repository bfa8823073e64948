"""List the method adapters: runnable methods and output readers with the layouts they read, and
the options each takes.

Examples::

    wcbench methods list
    wcbench methods list -v        # with each reader's expected file layout
    wcbench methods show weathercity   # every option: type, range, default, meaning

``show`` lists the declared options of a method (``--method-option KEY=VALUE``; a table's keys as
``KEY.SUB=VALUE``, e.g. ``settings.iterations=500``): run, render and train check every option
against this list before any work starts and refuse a bad one in one line.
"""

from __future__ import annotations

import argparse

from wcbench.cli.common import method_name

HELP = "list method adapters and show their options"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``list [-v]`` and ``show NAME``."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    lst = sub.add_parser("list", help="list methods")
    lst.add_argument("-v", "--verbose", action="store_true", help="also show the file layout of each")
    show = sub.add_parser("show", help="show a method and every option it takes (type, range, default, meaning)")
    show.add_argument("name", type=method_name, metavar="NAME", help="method name (see `wcbench methods list`)")


def show(name: str) -> int:
    """Print method ``name``: kind, weathers, description and its declared options, one per line."""
    from wcbench.core.options import schema_lines
    from wcbench.methods import get_method, method_schema

    m = get_method(name)
    print(f"{name}  {m.info.kind}  {','.join(m.info.weathers)}\n  {m.info.description}")
    lines = schema_lines(method_schema(name))
    if not lines:
        print("options: none")
        return 0
    print("options (--method-option KEY=VALUE; a table's keys as KEY.SUB=VALUE):")
    for line in lines:
        print(f"  {line}")
    return 0


def run(args: argparse.Namespace) -> int:
    """Print the methods, or one method's options."""
    from wcbench.methods import INSTALL_HINT, METHODS, MethodUnavailableError, get_method

    if args.action == "show":
        return show(args.name)

    names = METHODS.names()
    width = max(len(n) for n in names)
    for name in names:
        try:
            m = get_method(name)
        except MethodUnavailableError as exc:
            print(f"{name:{width}s} {'-':9s} {'-':22s} unavailable: needs {exc.package} ({INSTALL_HINT})")
            continue
        print(f"{name:{width}s} {m.info.kind:9s} {','.join(m.info.weathers):22s} {m.info.description}")
        if args.verbose and m.info.layout:
            for line in m.info.layout.splitlines():
                print(f"{'':{width + 2}s}{line}")
    return 0
