"""One training per cache entry (:class:`~wcbench.core.locking.EntryLock`): two processes asking for
the same entry at once (one makes it, the other waits and loads it), a lock left by a killed
process taken over, and a wait that times out with a message naming the holder."""

from __future__ import annotations

import importlib
import json
import multiprocessing
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from wcbench.core.locking import EntryLock, LockTimeoutError

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="EntryLock serialises with flock (POSIX)")


#: One process's request for the entry ``folder/model.npy``, as a module file: a spawned interpreter
#: imports its target by module name, and the tests folder is not importable outside the checkout.
WORKER = r'''
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from wcbench.core.locking import EntryLock


def make_or_load(folder: str, barrier: Any, waiting: Any, queue: Any) -> None:
    # make the entry ("train": counted) if it is missing, else load it; what it did, the result and
    # its messages go to the queue
    entry = Path(folder) / "model.npy"
    said: list[str] = []

    def log(message: str) -> None:
        said.append(message)
        waiting.set()

    barrier.wait()  # both ask at the same moment
    with EntryLock(Path(folder) / "model.lock", what="training demo", timeout_s=60, log=log):
        if entry.exists():
            role, result = "loaded", np.load(entry)
        else:
            with open(Path(folder) / "trainings.txt", "a") as fh:
                fh.write(f"{os.getpid()}\n")
            # training, which lasts until the other process waits for it however the two are scheduled
            assert waiting.wait(timeout=60)
            time.sleep(0.3)
            result = np.random.default_rng(7).normal(size=(64, 3)).astype(np.float32)
            np.save(entry, result)
            role = "trained"
    queue.put({"pid": os.getpid(), "role": role, "result": result.tolist(), "said": said})
'''


def _worker(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Any:
    folder = tmp_path / "worker"
    folder.mkdir()
    (folder / "lock_worker.py").write_text(WORKER)
    monkeypatch.syspath_prepend(str(folder))  # spawned children get the parent's sys.path
    return importlib.import_module("lock_worker")


def test_two_processes_asking_for_one_entry_make_it_once_and_the_other_loads_it(tmp_path: Path,
                                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    make_or_load = _worker(tmp_path, monkeypatch).make_or_load
    ctx = multiprocessing.get_context("spawn")  # fresh interpreters, as two `wcbench train` runs
    barrier, waiting, queue = ctx.Barrier(2), ctx.Event(), ctx.Queue()
    procs = [ctx.Process(target=make_or_load, args=(str(tmp_path), barrier, waiting, queue)) for _ in range(2)]
    for p in procs:
        p.start()
    reports = [queue.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(timeout=60)
        assert p.exitcode == 0
    trainings = (tmp_path / "trainings.txt").read_text().split()
    assert len(trainings) == 1  # the training function ran once
    by_role = {r["role"]: r for r in reports}
    assert set(by_role) == {"trained", "loaded"}
    assert by_role["trained"]["pid"] == int(trainings[0])
    assert by_role["loaded"]["result"] == by_role["trained"]["result"]
    # the waiter was told who it waited for; the trainer was told nothing
    (message,) = by_role["loaded"]["said"]
    assert message.startswith(f"waiting for another process training demo (pid {by_role['trained']['pid']}, since ")
    assert by_role["trained"]["said"] == []
    assert not (tmp_path / "model.lock").exists()  # released: the lock file is removed


HOLD = """
import sys, time
from wcbench.core.locking import EntryLock
with EntryLock(sys.argv[1], what="training demo", timeout_s=0):
    print("held", flush=True)
    time.sleep(600)
"""


def test_lock_of_a_killed_process_is_taken_over_at_once(tmp_path: Path) -> None:
    lock = tmp_path / "demo-0123.lock"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(lock)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(LockTimeoutError):  # held while the holder lives
            with EntryLock(lock, what="training demo", timeout_s=0.3, log=lambda m: None):
                pass
    finally:
        holder.send_signal(signal.SIGKILL)  # killed: no release, its lock file stays behind
        holder.wait()
    assert json.loads(lock.read_text())["pid"] == holder.pid
    said: list[str] = []
    start = time.perf_counter()
    with EntryLock(lock, what="training demo", timeout_s=5, log=said.append):
        waited = time.perf_counter() - start
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    assert waited < 1.0  # no waiting out a staleness bound: the kernel released the killed holder's flock
    (message,) = said
    assert message.startswith(f"taking over the lock of a process that ended while training demo (pid {holder.pid}, "
                              "since ")
    assert not lock.exists()


def test_lock_file_naming_a_dead_pid_does_not_hold_anyone(tmp_path: Path) -> None:
    # a lock file as a killed process leaves it on another machine's view of a shared cache, or from
    # a pid that no longer exists: only a held flock counts, never what the file says
    lock = tmp_path / "demo-0123.lock"
    lock.write_text(json.dumps({"pid": 2**22 + 11, "host": socket.gethostname(), "since": "2026-01-01T00:00:00+00:00",
                                "what": "training demo"}))
    said: list[str] = []
    with EntryLock(lock, what="training demo", timeout_s=0, log=said.append):
        pass
    assert said == ["taking over the lock of a process that ended while training demo (pid 4194315, "
                    "since 2026-01-01T00:00:00+00:00)"]


def test_waiting_past_the_timeout_fails_naming_the_holder(tmp_path: Path) -> None:
    lock = tmp_path / "demo-0123.lock"
    said: list[str] = []
    with EntryLock(lock, what="training demo", timeout_s=0):
        start = time.perf_counter()
        with pytest.raises(LockTimeoutError) as caught:
            with EntryLock(lock, what="training demo", timeout_s=0.5, log=said.append):
                pytest.fail("entered a lock another holder has")
        waited = time.perf_counter() - start
    assert 0.5 <= waited < 2.0
    text = str(caught.value)
    assert text.startswith(f"gave up after 0.5 s waiting for another process training demo (pid {os.getpid()}, since ")
    assert str(lock) in text and "If that process is hung, end it" in text
    assert len(said) == 1 and said[0].startswith("waiting for another process training demo")
    with EntryLock(lock, what="training demo", timeout_s=0):  # released by the first holder: free again
        pass


def test_timeout_must_be_a_number_of_seconds(tmp_path: Path) -> None:
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="timeout_s must be >= 0 or None"):
            EntryLock(tmp_path / "x.lock", what="training demo", timeout_s=bad)
