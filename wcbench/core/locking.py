"""Exclusive locks between processes: one writer per output folder, one training per cache entry.

:class:`FolderLock`: two runs into one ``OUT`` would each check that no results exist, then each
write theirs, and one run's results would be lost. The second run waits for the first instead (it
is told so), then finds the first run's results and refuses to replace them unless asked
(docs/design.md §9). The lock is ``flock`` on the folder's own descriptor, so no lock file is left
behind; it is released when the process ends, however it ends.

:class:`EntryLock`: two processes asking for the same cache entry (a trained model) would both make
it in full. The second waits for the first (it is told who holds it and since when), then finds the
entry made. The lock is a ``flock`` on a lock file next to the entry, released by the kernel when
the holder ends, so a killed holder's lock is taken over at once.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any

from wcbench.core.errors import WcbenchError

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: runs are not serialised there
    fcntl = None  # type: ignore[assignment]

__all__ = ["POLL_S", "EntryLock", "FolderLock", "LockTimeoutError"]


def _to_stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


class FolderLock:
    """Hold an exclusive lock on ``folder`` (created if missing) while the block runs.

    Parameters
    ----------
    folder : Path
    log : callable
        Told once when the lock is held by another process and this one waits.
    remove_if_unused : bool
        On an exception, remove ``folder`` again if this lock created it and it is still empty
        (a refused run leaves nothing behind).
    """

    def __init__(self, folder: str | os.PathLike[str], *, log: Callable[[str], None] = _to_stderr,
                 remove_if_unused: bool = True):
        self.folder, self.log, self.remove_if_unused = Path(folder), log, remove_if_unused
        self._fd: int | None = None
        self._created = False

    def __enter__(self) -> FolderLock:
        self._created = not self.folder.exists()
        self.folder.mkdir(parents=True, exist_ok=True)
        if fcntl is None:
            return self
        self._fd = os.open(self.folder, os.O_RDONLY)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.log(f"{self.folder}: another wcbench run is writing here; waiting for it to finish")
            fcntl.flock(self._fd, fcntl.LOCK_EX)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc is not None and self._created and self.remove_if_unused:
            try:
                self.folder.rmdir()  # only succeeds when empty
            except OSError:
                pass
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor releases the lock
            self._fd = None


#: Seconds between two tries of a waiting :class:`EntryLock` (the lock is free at most this long
#: before a waiter notices).
POLL_S = 0.25


class LockTimeoutError(WcbenchError):
    """An :class:`EntryLock` stayed held by another process for longer than the caller would wait."""


def _holder(path: Path) -> dict[str, Any] | None:
    """The holder a lock file records (pid, host, since), or ``None`` when it records none yet."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):  # missing, being written, or not ours: the message says "unknown"
        return None
    return data if isinstance(data, dict) else None


def _describe(holder: dict[str, Any] | None) -> str:
    if holder is None:
        return "pid unknown"
    host = "" if holder.get("host") == socket.gethostname() else f" on {holder.get('host')}"
    return f"pid {holder.get('pid')}{host}, since {holder.get('since')}"


class EntryLock:
    """Hold one cache entry exclusively while the block runs; another process asking for it waits.

    The lock is an exclusive ``flock`` on a lock file next to the entry (``<entry>.lock``), which
    records the holder (pid, host, start time) for the message a waiter prints. No stale-lock
    detection is needed, and none is done: the kernel drops a ``flock`` when its holder ends,
    however it ends (SIGKILL, out of memory), so a waiter takes over at once from a killed holder;
    a lock file left behind by one is only re-used (the message says whose it was). The recorded
    pid and time are never used to decide anything. On a shared folder the filesystem must support
    ``flock`` (Linux NFS does, by its byte-range locks); not on POSIX nothing is serialised
    (docs/design.md §9).

    Parameters
    ----------
    path : path-like
        The lock file (created if missing, removed on release).
    what : str
        What the holder does, for the messages: ``"training demo_street"``.
    timeout_s : float or None
        Seconds to wait for another holder before :class:`LockTimeoutError`; ``None``: no limit.
    log : callable
        Told once when another process holds the lock and this one waits.

    Raises
    ------
    LockTimeoutError
        From ``with``, when the lock is still held by another process after ``timeout_s``.
    """

    def __init__(self, path: str | os.PathLike[str], *, what: str, timeout_s: float | None,
                 log: Callable[[str], None] = _to_stderr):
        if timeout_s is not None and not timeout_s >= 0:
            raise ValueError(f"timeout_s must be >= 0 or None, got {timeout_s!r}")
        self.path, self.what, self.timeout_s, self.log = Path(path), what, timeout_s, log
        #: Seconds the last ``with`` waited for another holder (0 when the lock was free).
        self.waited_s = 0.0
        self._fd: int | None = None

    def __enter__(self) -> EntryLock:
        if fcntl is None:
            return self
        self.path.parent.mkdir(parents=True, exist_ok=True)
        start = time.monotonic()
        told = False
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                holder = self._wait_for_record()
                waited = time.monotonic() - start
                if self.timeout_s is not None and waited >= self.timeout_s:
                    raise LockTimeoutError(
                        f"gave up after {waited:.1f} s waiting for another process {self.what} "
                        f"({_describe(holder)}; lock file {self.path}). If that process is hung, end it "
                        "and run again: the lock is released when it ends") from None
                if not told:
                    self.log(f"waiting for another process {self.what} ({_describe(holder)}; lock file "
                             f"{self.path})")
                    told = True
                left = None if self.timeout_s is None else self.timeout_s - waited
                time.sleep(POLL_S if left is None else min(POLL_S, max(left, 0.0)))
                continue
            if self._is_current(fd):
                self.waited_s = time.monotonic() - start if told else 0.0
                break
            # a holder removed the file on release after this process opened it: the lock held is on
            # a file no other process will open again, so try again on the one at the path now
            os.close(fd)
        try:
            left_by = _holder(self.path)
            if left_by is not None:  # a released lock file is removed: its holder ended without releasing
                self.log(f"taking over the lock of a process that ended while {self.what} ({_describe(left_by)})")
            record = {"pid": os.getpid(), "host": socket.gethostname(),
                      "since": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"), "what": self.what}
            os.ftruncate(fd, 0)
            os.pwrite(fd, json.dumps(record).encode(), 0)
        except BaseException:
            os.close(fd)  # a record that cannot be written (full disk...): release rather than hold unseen
            raise
        self._fd = fd
        return self

    def _is_current(self, fd: int) -> bool:
        """Whether ``fd`` is the file at :attr:`path` (not one a holder removed before it released)."""
        try:
            here = os.stat(self.path)
        except FileNotFoundError:
            return False
        mine = os.fstat(fd)
        return (here.st_dev, here.st_ino) == (mine.st_dev, mine.st_ino)

    def _wait_for_record(self) -> dict[str, Any] | None:
        """The holder's record, given the moment between its ``flock`` and its write to appear."""
        for _ in range(5):
            holder = _holder(self.path)
            if holder is not None:
                return holder
            time.sleep(0.02)
        return None

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._fd is None:
            return
        # removed while still held, so a waiter that opened it sees the file is gone and reopens
        self.path.unlink(missing_ok=True)
        os.close(self._fd)  # closing the descriptor releases the lock
        self._fd = None
