"""List the method adapters: runnable methods and output readers with the layouts they read.

Examples::

    wcbench methods list
    wcbench methods list -v        # with each reader's expected file layout
"""

from __future__ import annotations

import argparse

HELP = "list method adapters"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``list [-v]``."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    lst = sub.add_parser("list", help="list methods")
    lst.add_argument("-v", "--verbose", action="store_true", help="also show the file layout of each")


def run(args: argparse.Namespace) -> int:
    """Print the methods."""
    from wcbench.methods import INSTALL_HINT, METHODS, MethodUnavailableError, get_method

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
