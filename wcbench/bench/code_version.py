"""The version of the code a benchmark measured, and whether a benchmark JSON is older than the code.

``wcbench bench`` records in each JSON (``code``)::

    "code": {"wcbench": "0.1.0",                               # the package version
             "digests": {"wcbench.bench.model": "3f2a...",      # one sha256 per measured module
                         "wcbench.reference_model": "9c41...", ...}}

The modules are those :data:`wcbench.bench.MEASURES` declares for the suite: the code whose change
can move its numbers, not everything it imports (a digest of the whole package would call every
JSON stale on every commit, and some suites take an hour to re-run). A digest is of the code, not
of its prose: comments, docstrings (any statement that is a bare string), blank lines and trailing
spaces are left out, so documenting code does not stale a benchmark, while any other edit does
(:mod:`wcbench.core.code_digest`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from wcbench.core.code_digest import source_digest


def measured_code(suite: str, *, memo: dict[str, str] | None = None) -> dict[str, Any] | None:
    """The ``code`` record of a benchmark JSON of ``suite`` for the code as it is now.

    ``None`` when :data:`wcbench.bench.MEASURES` declares nothing for the suite (a suite another
    package adds): its JSON cannot be checked against the code. ``memo`` (module -> digest) keeps
    the digests of one check over several suites.
    """
    from wcbench import __version__
    from wcbench.bench import MEASURES

    modules = MEASURES.get(suite)
    if modules is None:
        return None
    memo = {} if memo is None else memo
    for m in modules:
        if m not in memo:
            memo[m] = source_digest(m)
    return {"wcbench": __version__, "digests": {m: memo[m] for m in modules}}


def code_changes(doc: Mapping[str, Any], *, current: Mapping[str, Any] | None = None) -> list[str]:
    """Why a benchmark JSON is older than the code it measures; empty when it is not.

    Parameters
    ----------
    doc : mapping
        A benchmark JSON (:mod:`.schema`) with its ``suite`` and, when written by a ``wcbench bench``
        that records it, ``code``.
    current : mapping, optional
        :func:`measured_code` of its suite, when already taken.

    Returns
    -------
    list of str
        One line per reason: no record, a measured module whose code changed, a module the suite now
        measures that the JSON did not, or one it no longer measures.
    """
    suite = doc.get("suite")
    current = measured_code(str(suite)) if current is None else current
    if current is None:
        return [f"suite {suite!r} declares no measured code (wcbench.bench.MEASURES)"]
    recorded = doc.get("code")
    if not isinstance(recorded, Mapping) or not isinstance(recorded.get("digests"), Mapping):
        return ["it records no code version (written before `wcbench bench` recorded one)"]
    old, new = recorded["digests"], current["digests"]
    reasons = [f"{m} changed" for m in new if m in old and old[m] != new[m]]
    reasons += [f"{m} is now measured too" for m in new if m not in old]
    reasons += [f"{m} is no longer measured" for m in old if m not in new]
    return reasons
