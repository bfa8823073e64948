"""Exceptions that reach the user.

Every error caused by the user's input (a file, a name, an option) is a :class:`WcbenchError`.
The CLI prints its message and exits with status 2; anything else is a bug and keeps its
traceback.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class WcbenchError(Exception):
    """Base class for errors caused by input: bad files, unknown names, wrong options."""

    exit_code = 2


class InputError(WcbenchError, ValueError):
    """A file or folder does not hold what was expected (missing, corrupt, wrong shape...)."""


class UnknownNameError(WcbenchError, KeyError):
    """A method, scene set, metric, weather or benchmark name that no registry knows."""

    def __init__(self, kind: str, name: str, known: Iterable[str]):
        known = sorted(known)
        close = difflib.get_close_matches(name, known, n=3, cutoff=0.5)
        hint = f" Did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
        msg = f"unknown {kind} {name!r}.{hint} Known: {', '.join(known) or '(none)'}."
        super().__init__(msg)
        self.kind, self.name, self.known, self.suggestions = kind, name, known, close

    def __str__(self) -> str:  # KeyError would otherwise wrap the message in quotes
        return str(self.args[0])


class OutputError(WcbenchError):
    """An output file or folder cannot be written: read-only, full, or not a folder.

    Raised before any work when it can be seen then, else at the write that failed; finished work
    is kept either way (atomic writes).
    """


class ResultsExistError(WcbenchError):
    """An output folder holds finished results that a run would overwrite."""
