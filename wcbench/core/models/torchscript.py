"""TorchScript archives: recognised from their zip listing, refused unless trusted (docs/design.md §6).

A TorchScript archive is compiled code that ``torch.jit.load`` runs, so no file is loaded as one
unless the user trusted it: explicitly (``--trust-torchscript``) or for the model-store install
running in this context (:func:`trusting`). Nothing here imports torch.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import zipfile
from collections.abc import Iterator
from pathlib import Path

from wcbench.core.models.store_errors import UntrustedTorchScriptError

__all__ = ["check_torchscript", "is_torchscript_archive", "torchscript_refusal", "trusted_key", "trusting"]

#: Resolved paths of the TorchScript archives the user trusted for the install running in this
#: context. Converters are called as ``converter(sources, out_dir, entry)``, so the trust reaches
#: the function that would load the archive through this variable (see :func:`check_torchscript`).
_TRUSTED_TORCHSCRIPT: contextvars.ContextVar[frozenset[str]] = contextvars.ContextVar(
    "wcbench_trusted_torchscript", default=frozenset()
)


def is_torchscript_archive(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a TorchScript archive, from its zip listing alone (nothing is unpickled).

    A TorchScript archive is a zip holding ``<root>/constants.pkl`` or compiled code under
    ``<root>/code/``; a ``torch.save`` checkpoint is a zip too but holds neither.
    """
    try:
        if not zipfile.is_zipfile(path):
            return False
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except (OSError, zipfile.BadZipFile):
        return False
    for name in names:
        parts = name.split("/")
        if parts[-1] == "constants.pkl" or "code" in parts[:-1]:
            return True
    return False



def trusted_key(path: str | os.PathLike[str]) -> str:
    """How a trusted archive is named in :func:`trusting`: its resolved path."""
    return str(Path(path).resolve())


@contextlib.contextmanager
def trusting(keys: frozenset[str]) -> Iterator[None]:
    """Trust the archives ``keys`` (:func:`trusted_key`) for :func:`check_torchscript` within the block.

    The model store wraps a converter call in it: converters are called as
    ``converter(sources, out_dir, entry)``, so the user's trust reaches the function that would load
    the archive through a context variable.
    """
    token = _TRUSTED_TORCHSCRIPT.set(keys)
    try:
        yield
    finally:
        _TRUSTED_TORCHSCRIPT.reset(token)


def torchscript_refusal(path: str | os.PathLike[str]) -> str:
    """The sentence every refusal of a TorchScript archive uses."""
    return (
        f"{path} is a TorchScript archive: loading it runs the code it contains, so wcbench does not "
        "load it by default. Pass --trust-torchscript (python: trust_torchscript=True) only for a file "
        "from a trusted source, or convert a plain state dict instead (safetensors, or a .pt/.bin "
        "written by torch.save of a state dict)"
    )


def check_torchscript(path: str | os.PathLike[str], *, trusted: bool = False) -> bool:
    """Whether ``path`` is a TorchScript archive that may be loaded; refuse an untrusted one.

    Parameters
    ----------
    path : path-like
        The file about to be read.
    trusted : bool
        The caller's explicit trust (``--trust-torchscript``). A file trusted for the model-store
        install running in this context (:meth:`ModelStore.import_file` / :meth:`ModelStore.pull`
        with ``trust_torchscript=True``) is trusted too.

    Returns
    -------
    bool
        ``True``: a trusted TorchScript archive; ``False``: not a TorchScript archive.

    Raises
    ------
    UntrustedTorchScriptError
        For a TorchScript archive nobody trusted (it is never opened beyond its zip listing).
    """
    if not is_torchscript_archive(path):
        return False
    if trusted or trusted_key(path) in _TRUSTED_TORCHSCRIPT.get():
        return True
    raise UntrustedTorchScriptError(torchscript_refusal(path))
