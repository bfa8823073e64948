"""A Dask worker plugin that kills its own worker process once, when a chosen task starts.

The marker file makes it fire once across the whole cluster: the nanny restarts the killed
worker, the plugin is set up again there, and finds the marker.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

from distributed import WorkerPlugin


class KillOnTask(WorkerPlugin):
    """SIGKILL the worker when the ``nth`` task whose key starts with ``prefix`` begins executing."""

    def __init__(self, marker: Path, prefix: str, nth: int = 2):
        self.marker, self.prefix, self.nth, self.seen = str(marker), prefix, nth, 0

    def setup(self, worker: Any) -> None:
        self.seen = 0

    def transition(self, key: Any, start: str, finish: str, **kwargs: Any) -> None:
        if finish != "executing" or not str(key).startswith(self.prefix):
            return
        self.seen += 1
        if self.seen < self.nth:
            return
        try:
            fd = os.open(self.marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            return  # fired already (this is the restarted worker or the other one)
        os.write(fd, str(os.getpid()).encode())
        os.close(fd)
        os.kill(os.getpid(), signal.SIGKILL)
