"""One writer per output folder: an exclusive advisory lock on the folder itself.

Two runs into one ``OUT`` would each check that no results exist, then each write theirs, and
one run's results would be lost. The second run waits for the first instead (it is told so), then
finds the first run's results and refuses to replace them unless asked (docs/design.md §9). The
lock is ``flock`` on the folder's own descriptor, so no lock file is left behind; it is released
when the process ends, however it ends.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: runs are not serialised there
    fcntl = None  # type: ignore[assignment]

__all__ = ["FolderLock"]


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
