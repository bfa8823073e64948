"""Lazy registries of named components ("module:attr" strings, resolved on first use).

A registry maps a name to an import string, so listing names imports nothing heavy. Entry points
in the group ``wcbench.<kind>`` extend the built-ins; a duplicate name is an error, and a miss
suggests close names.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from importlib import metadata
from typing import Any, Generic, TypeVar

from wcbench.core.errors import UnknownNameError

T = TypeVar("T")


def import_string(spec: str) -> Any:
    """Import ``"package.module:attr"`` and return the attribute.

    Raises
    ------
    ImportError
        If the module cannot be imported or has no such attribute.
    """
    module_name, _, attr = spec.partition(":")
    if not attr:
        raise ValueError(f"import string {spec!r} must look like 'package.module:attr'")
    module = importlib.import_module(module_name)
    try:
        return getattr(module, attr)
    except AttributeError as exc:
        raise ImportError(f"module {module_name!r} has no attribute {attr!r}") from exc


class LazyRegistry(Generic[T]):
    """Names mapped to lazily imported objects.

    Parameters
    ----------
    kind : str
        What the registry holds ("method", "metric"...): used in error messages and as the
        entry-point group ``wcbench.<kind>s``.
    builtins : Mapping[str, str]
        Built-in names and their ``"module:attr"`` import strings.
    """

    def __init__(self, kind: str, builtins: Mapping[str, str]):
        self.kind = kind
        self._specs: dict[str, str] = dict(builtins)
        self._loaded: dict[str, T] = {}
        self._entry_points_read = False

    def _read_entry_points(self) -> None:
        if self._entry_points_read:
            return
        self._entry_points_read = True
        for ep in metadata.entry_points(group=f"wcbench.{self.kind}s"):
            if ep.name in self._specs and self._specs[ep.name] != ep.value:
                raise ValueError(
                    f"{self.kind} {ep.name!r} from entry point {ep.value!r} clashes with "
                    f"{self._specs[ep.name]!r}"
                )
            self._specs[ep.name] = ep.value

    def register(self, name: str, spec: str | T) -> None:
        """Add ``name``; ``spec`` is an import string or the object itself."""
        self._read_entry_points()
        if name in self._specs or name in self._loaded:
            raise ValueError(f"{self.kind} {name!r} is already registered")
        if isinstance(spec, str):
            self._specs[name] = spec
        else:
            self._loaded[name] = spec

    def names(self) -> list[str]:
        """All registered names, sorted."""
        self._read_entry_points()
        return sorted(set(self._specs) | set(self._loaded))

    def __contains__(self, name: object) -> bool:
        return name in self.names()

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def get(self, name: str) -> T:
        """Resolve ``name``, importing its module on first use.

        Raises
        ------
        UnknownNameError
            If no such name is registered (with close-name suggestions).
        """
        if name in self._loaded:
            return self._loaded[name]
        self._read_entry_points()
        if name not in self._specs:
            raise UnknownNameError(self.kind, name, self.names())
        obj: T = import_string(self._specs[name])
        self._loaded[name] = obj
        return obj
