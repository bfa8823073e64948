"""Lazy registries of named components ("module:attr" strings, resolved on first use).

A registry maps a name to an import string, so listing names imports nothing heavy. Entry points
in the group ``wcbench.<kind>`` extend the built-ins; a duplicate name is an error, and a miss
suggests close names. A renamed component keeps its old name as a deprecated alias for a release:
:meth:`LazyRegistry.canonical` maps it to the new name (with a :class:`DeprecationWarning`).
"""

from __future__ import annotations

import importlib
import warnings
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
    aliases : Mapping[str, str], optional
        Deprecated old name -> current name. An alias resolves like its name (with a
        :class:`DeprecationWarning`) and is not listed by :meth:`names`.
    """

    def __init__(self, kind: str, builtins: Mapping[str, str], aliases: Mapping[str, str] | None = None):
        self.kind = kind
        self._specs: dict[str, str] = dict(builtins)
        self.aliases: dict[str, str] = dict(aliases or {})
        bad = sorted(a for a, name in self.aliases.items() if a in self._specs or name not in self._specs)
        if bad:
            raise ValueError(f"{kind} aliases {bad}: an alias must not be a name and must point to one")
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
        """Whether ``name`` is registered (a deprecated alias counts)."""
        return name in self.aliases or name in self.names()

    def is_alias(self, name: str) -> bool:
        """Whether ``name`` is a deprecated alias (an old name of a component)."""
        return name in self.aliases and name not in self._specs and name not in self._loaded

    def canonical(self, name: str, *, warn: bool = True) -> str:
        """The current name of ``name``: itself, or the name a deprecated alias stands for.

        Parameters
        ----------
        name : str
            A registered name or a deprecated alias (anything else is returned unchanged).
        warn : bool
            Issue a :class:`DeprecationWarning` when ``name`` is an alias.
        """
        if not self.is_alias(name):
            return name
        new = self.aliases[name]
        if warn:
            warnings.warn(f"{self.kind} name {name!r} is deprecated, use {new!r}", DeprecationWarning, stacklevel=3)
        return new

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def get(self, name: str) -> T:
        """Resolve ``name``, importing its module on first use.

        A deprecated alias resolves to its current name, with a :class:`DeprecationWarning`.

        Raises
        ------
        UnknownNameError
            If no such name is registered (with close-name suggestions).
        """
        name = self.canonical(name)
        if name in self._loaded:
            return self._loaded[name]
        self._read_entry_points()
        if name not in self._specs:
            raise UnknownNameError(self.kind, name, self.names())
        obj: T = import_string(self._specs[name])
        self._loaded[name] = obj
        return obj
