"""The ``wcbench`` command line. One module per verb, imported lazily by :func:`main`.

Each verb module defines ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``
and imports nothing heavy at module level, so ``wcbench --help`` stays instant and never imports
torch or onnxruntime.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import typing
from collections.abc import Sequence

from wcbench import __version__
from wcbench.core.errors import WcbenchError

#: verb -> module; the order is the order in ``--help``.
COMMANDS = {
    "run": "wcbench.cli.run",
    "evaluate": "wcbench.cli.evaluate",
    "render": "wcbench.cli.render",
    "train": "wcbench.cli.train",
    "scenes": "wcbench.cli.scenes",
    "methods": "wcbench.cli.methods",
    "metrics": "wcbench.cli.metrics",
    "models": "wcbench.cli.models",
    "report": "wcbench.cli.report",
    "bench": "wcbench.cli.bench",
    "compile": "wcbench.cli.compile",
}


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line, ``wcbench VERB: error: ...`` (exit 2): the usage
    block is for ``--help``, not printed above every mistake (docs/guide.md, "Method options")."""

    def error(self, message: str) -> typing.NoReturn:
        """Print ``PROG: error: MESSAGE`` (its first line) on stderr and exit with 2."""
        first = message.splitlines()[0] if message else "bad arguments"
        self.exit(2, f"{self.prog}: error: {first} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser (imports every verb module, none of which imports heavy code)."""
    parser = _Parser(
        prog="wcbench",
        description="Weather editing of driving scenes: render, evaluate and benchmark methods.",
        epilog="Run `wcbench VERB --help` for the options of each verb.",
    )
    parser.add_argument("--version", action="version", version=f"wcbench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="VERB")
    for name, module_name in COMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:  # verb not shipped in this build
                continue
            raise
        p = sub.add_parser(name, help=module.HELP, description=module.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``wcbench`` console script; returns the exit status.

    Input errors (:class:`~wcbench.core.errors.WcbenchError`) and files or folders the user may
    not read or write (``PermissionError``) print one message and exit with 2.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except WcbenchError as exc:
        print(f"wcbench {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except PermissionError as exc:  # a file or folder this user may not read or write: no traceback
        where = exc.filename or "a file"
        print(f"wcbench {args.command}: error: {where}: permission denied for this user ({exc.strerror or exc})",
              file=sys.stderr)
        return 2
    except BrokenPipeError:  # `wcbench ... | head`: the reader left, nothing to report
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("wcbench: interrupted; finished work is kept and a re-run resumes", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
