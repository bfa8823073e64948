"""The errors of the model store (torch-free)."""

from __future__ import annotations

from wcbench.core.errors import InputError, WcbenchError

__all__ = ["ModelMissingError", "ModelStoreError", "SourceMismatchError", "SourceUnreachableError",
           "UntrustedTorchScriptError"]


class ModelStoreError(WcbenchError):
    """A model could not be fetched, imported or verified (the message says what to do)."""


class ModelMissingError(ModelStoreError):
    """A model's files are not installed in the store."""


class SourceMismatchError(ModelStoreError, InputError):
    """A downloaded or imported file is not the one the entry pins (its sha256 differs)."""


class UntrustedTorchScriptError(ModelStoreError, InputError):
    """A TorchScript archive was given without ``trust_torchscript`` (loading it would run its code)."""


class SourceUnreachableError(ModelStoreError):
    """A source's host could not be reached: connection refused, name not resolved, timed out, no route.

    Raised only for such network failures, where nothing was learnt about the file; an HTTP error
    (404...), a file that is not the pinned one or a conversion that fails is another
    :class:`ModelStoreError`. A fetch on first use tries such a host once per run (:mod:`.fetch`).
    """
