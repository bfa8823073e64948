"""The errors of the model store (torch-free)."""

from __future__ import annotations

from wcbench.core.errors import InputError, WcbenchError

__all__ = ["ModelMissingError", "ModelStoreError", "SourceMismatchError", "UntrustedTorchScriptError"]


class ModelStoreError(WcbenchError):
    """A model could not be fetched, imported or verified (the message says what to do)."""


class ModelMissingError(ModelStoreError):
    """A model's files are not installed in the store."""


class SourceMismatchError(ModelStoreError, InputError):
    """A downloaded or imported file is not the one the entry pins (its sha256 differs)."""


class UntrustedTorchScriptError(ModelStoreError, InputError):
    """A TorchScript archive was given without ``trust_torchscript`` (loading it would run its code)."""
