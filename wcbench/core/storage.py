"""Atomic file writes and content hashes: nothing is ever half-written.

Every file wcbench produces is written to a temporary file in the same folder and renamed over
the target, so a killed process leaves either the old file or the new one, never a torn one.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import re
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from wcbench.core.errors import InputError, OutputError

_CHUNK = 1 << 20
# mkstemp creates files readable by the owner only; results and frames should get the usual
# permissions, so read the process umask once (setting it is the only way to read it).
_UMASK = os.umask(0o022)
os.umask(_UMASK)


#: Write failures that are the output's fault, not a bug: full disk or quota, read-only
#: filesystem, permissions, a file where a folder should be, a file-size limit.
_OUTPUT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOTDIR,
                            errno.EISDIR, errno.EFBIG, errno.EEXIST})


#: Names :func:`atomic_path` gives its temporary files (mkstemp's random part is 8 characters).
_TEMPORARY = re.compile(r"^\..+\.[A-Za-z0-9_]{8}\.tmp(\.[A-Za-z0-9]+)?$")


def _output_error(path: Path, exc: OSError) -> OutputError:
    reason = exc.strerror or str(exc)
    if exc.errno in (errno.EEXIST, errno.ENOTDIR):
        reason = "a file is in the way of a folder on its path"
    return OutputError(f"{path}: cannot write ({reason}); finished work is kept: fix the folder "
                       "(space, permissions) and run again to resume")


@contextmanager
def atomic_path(path: str | os.PathLike[str], *, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` if the block succeeds.

    Use for writers that want a file name (``cv2.imwrite``, video writers). ``suffix`` keeps an
    extension that such writers look at.

    Raises
    ------
    OutputError
        The folder cannot be written (full, read-only, no permission, a file in the way); the old
        file, if any, is left as it was.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + suffix, dir=path.parent)
        os.fchmod(fd, 0o666 & ~_UMASK)
        os.close(fd)
    except OSError as exc:
        if exc.errno in _OUTPUT_ERRNOS:
            raise _output_error(path, exc) from exc
        raise
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except OSError as exc:
        if exc.errno in _OUTPUT_ERRNOS:
            raise _output_error(path, exc) from exc
        raise
    finally:
        try:
            tmp_path.unlink(missing_ok=True)
        except OSError:
            pass  # the folder went read-only meanwhile: the temporary name is all that is left


def atomic_write(path: str | os.PathLike[str], writer: Callable[[IO[bytes]], Any]) -> None:
    """Write ``path`` atomically: ``writer`` gets an open binary file; fsync then rename."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        writer(fh)
        fh.flush()
        os.fsync(fh.fileno())


def sweep_temporary_files(folder: str | os.PathLike[str]) -> int:
    """Remove the temporary files of atomic writes that a killed process left in ``folder`` (and
    below); the number removed. Call it only while no other process writes there
    (:class:`~wcbench.core.locking.FolderLock`)."""
    removed = 0
    for p in Path(folder).rglob(".*.tmp*"):
        if p.is_file() and _TEMPORARY.match(p.name):
            try:
                p.unlink()
                removed += 1
            except OSError:
                pass  # read-only: the write that follows reports it
    return removed


def check_writable_folder(path: str | os.PathLike[str], *, what: str = "output folder") -> None:
    """Check before any work that ``path`` is, or can be created as, a folder this process can write.

    Raises
    ------
    InputError
        ``path`` (or a parent) exists and is not a folder.
    OutputError
        The folder, or the parent it would be created in, is not writable (a read-only
        filesystem or missing permissions; root passes permission checks).
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{p}: is a file; expected the {what} (a folder, or a path where one can be created)")
    probe = p
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{p}: cannot be created: {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        where = "" if probe == p else f" (it would be created in {probe})"
        raise OutputError(f"{p}: the {what} is not writable{where}; choose another --out or fix its permissions")


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    atomic_write(path, lambda fh: fh.write(data))


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def json_safe(obj: Any) -> Any:
    """Copy ``obj`` with every non-finite float replaced by ``None`` (strict JSON has no NaN/Inf).

    numpy scalars and arrays become Python numbers and lists.
    """
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):
        return json_safe(obj.tolist())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def dumps_json(obj: Any) -> str:
    """Deterministic, strict JSON text (sorted keys, 2-space indent, NaN refused)."""
    return json.dumps(json_safe(obj), indent=2, sort_keys=True, allow_nan=False) + "\n"


def atomic_write_json(path: str | os.PathLike[str], obj: Any) -> None:
    """Write ``obj`` as strict JSON (non-finite floats become null) atomically."""
    atomic_write_text(path, dumps_json(obj))


def sha256_file(path: str | os.PathLike[str]) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(_CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


def sha256_bytes(data: bytes) -> str:
    """Hex sha256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


def sha256_json(obj: Any) -> str:
    """Hex sha256 of the canonical JSON text of ``obj`` (a key for cached work)."""
    return sha256_bytes(dumps_json(obj).encode("utf-8"))
