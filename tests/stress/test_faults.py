"""The fault suite: kills at random moments, two runs into one folder, read-only and full outputs.

A run killed at any moment and run again must end with the numbers of a run that was never
killed, with nothing half-written or left over; two runs into one output folder must never lose
one's results; an output that cannot be written must fail with one clear message and keep what
was finished (design §9). Permission cases run as a non-root user (root passes permission checks).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from stress import cases

from wcbench.cli import main
from wcbench.scenes.sets import resolve_scenes

RUN = ["run", "--method", "filter2d", "--weathers", "clear,rain", "--metrics", "temporal_flicker",
       "flow_warping_error", "psnr", "--no-progress"]


def _numbers(out: Path, *, timed: bool = False) -> dict:
    doc = json.loads((out / "results.json").read_text())
    return {(s, w, o): (r["value"], r["per_frame"]) for s, ws in doc["results"].items() for w, outs in ws.items()
            for o, r in outs.items() if timed or r["metric"] != "fps"}


def _leftovers(out: Path) -> list[str]:
    return sorted(p.name for p in out.rglob("*") if ".tmp" in p.name)


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the demo scene (a path, so subprocesses need no cache)."""
    root = tmp_path_factory.mktemp("fault-scene") / "street"
    shutil.copytree(resolve_scenes("demo")[0].path, root)
    return root


@pytest.fixture(scope="module")
def reference(scene: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An uninterrupted run (its frames also serve as predictions to evaluate)."""
    out = tmp_path_factory.mktemp("fault-ref") / "out"
    assert main([*RUN, "--scenes", str(scene), "--out", str(out)]) == 0
    return out


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "wcbench", *args]


def _kill_at(cmd: list[str], delay: float) -> bool:
    """Start ``cmd``, SIGKILL it after ``delay`` s; whether it was still running then."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        proc.wait(timeout=delay)
        return False
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        return True


def _clock(cmd: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    return time.perf_counter() - start


def test_killed_at_random_moments_then_resumed_gives_the_uninterrupted_numbers(scene, reference, tmp_path,
                                                                                case_counter):
    rng = np.random.default_rng(20261126)
    preds = reference / "filter2d"
    commands = {
        "run": lambda out: _cli(*RUN, "--scenes", str(scene), "--out", str(out)),
        "evaluate": lambda out: _cli("evaluate", "--method", "filter2d", "--scenes", str(scene), "--predictions",
                                     str(preds), "--out", str(out), "--weathers", "clear,rain", "--metrics",
                                     "temporal_flicker", "flow_warping_error", "psnr", "fps", "--no-progress"),
        "report": lambda out: _cli("report", str(reference), "--out", str(out / "report.html")),
    }
    expected_eval = None
    kills = cases(quick=2, full=10)  # per command: 6 in the quick pass, 30 in the full run
    for name, command in commands.items():
        full = _clock(command(tmp_path / f"{name}-timing"))
        for i in range(kills):
            out = tmp_path / f"{name}-{i}"
            delay = float(rng.uniform(0.1, 0.9)) * full  # interpreter start included: some kills land early
            killed = _kill_at(command(out), delay)
            subprocess.run(command(out), check=True, capture_output=True)
            case_counter[f"faults: SIGKILL during {name} then resume" + ("" if killed else " (finished first)")] += 1
            assert _leftovers(out) == [], f"{name} killed at {delay:.2f} s left temporary files"
            if name == "report":
                html = (out / "report.html").read_text(encoding="utf-8")
                assert html.rstrip().endswith("</html>")
            elif name == "run":
                assert _numbers(out) == _numbers(reference)
            else:
                got = _numbers(out, timed=True)
                expected_eval = expected_eval or _numbers(tmp_path / f"{name}-timing", timed=True)
                assert got == expected_eval


def test_two_runs_into_one_folder_never_lose_results(scene, tmp_path, case_counter):
    out = tmp_path / "out"
    a = subprocess.Popen(_cli(*RUN, "--scenes", str(scene), "--out", str(out)), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    b_args = [x if x != "clear,rain" else "clear,snow" for x in RUN]
    b = subprocess.Popen(_cli(*b_args, "--scenes", str(scene), "--out", str(out)), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    results = [(p.wait(timeout=300), *p.communicate()) for p in (a, b)]
    case_counter["faults: two concurrent runs into one folder"] += 1
    codes = sorted(code for code, _, _ in results)
    assert codes == [0, 2], results
    winner = next(out_text for code, out_text, _ in results if code == 0)
    loser_err = next(err for code, _, err in results if code == 2)
    assert "wrote" in winner and "wrote" not in next(o for c, o, _ in results if c == 2)
    assert "finished results of another configuration" in loser_err
    doc = json.loads((out / "results.json").read_text())
    assert sorted(doc["config"]["weathers"]) in (["clear", "rain"], ["clear", "snow"])


@pytest.fixture
def as_nobody():
    """A command prefix that runs as an unprivileged user (empty when not root); skips when that
    user cannot run this interpreter. Folders on the way to the environment that others may not
    enter (tox makes ``.tox`` private) are opened for traversal (o+x only) during the test."""
    if os.geteuid() != 0:
        yield []
        return
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: permissions cannot be tested")
    import wcbench

    opened: list[tuple[Path, int]] = []
    for top in {Path(sys.prefix), Path(wcbench.__file__).parent}:
        for d in [top, *top.parents]:
            mode = d.stat().st_mode
            if d.is_dir() and not mode & stat.S_IXOTH:
                d.chmod(mode | stat.S_IXOTH)
                opened.append((d, mode))
    prefix = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", "--"]
    try:
        probe = subprocess.run([*prefix, sys.executable, "-c", "import wcbench"], capture_output=True, cwd="/")
        if probe.returncode != 0:
            pytest.skip(f"an unprivileged user cannot run this interpreter: {probe.stderr.decode()[-200:]}")
        yield prefix
    finally:
        for d, mode in reversed(opened):
            d.chmod(mode)


@pytest.fixture
def shared_tmp():
    """A temporary folder the unprivileged user can enter (pytest's own are private to root)."""
    path = Path(tempfile.mkdtemp(prefix="wcbench-faults-"))
    path.chmod(0o777)
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.mark.parametrize("kind", ["read-only folder", "read-only parent", "read-only results file"])
def test_read_only_output_fails_clearly_before_work_as_a_non_root_user(kind, scene, reference, shared_tmp,
                                                                        as_nobody, case_counter):
    prefix = as_nobody
    shutil.copytree(scene, shared_tmp / "scene")
    shutil.copytree(reference / "filter2d", shared_tmp / "preds")
    out = shared_tmp / ("parent/out" if kind == "read-only parent" else "out")
    out.parent.mkdir(exist_ok=True)
    if kind == "read-only results file":
        shutil.copytree(reference, out, ignore=shutil.ignore_patterns("filter2d"))
        for p in [out, *out.rglob("*")]:
            p.chmod(0o555 if p.is_dir() else 0o444)
    elif kind == "read-only folder":
        out.mkdir()
        out.chmod(0o555)
    else:
        out.parent.chmod(0o555)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} if out.is_dir() else {}
    env = {**os.environ, "HOME": str(shared_tmp), "WCBENCH_CACHE": str(shared_tmp / "cache")}
    cmd = [*prefix, *_cli("evaluate", "--method", "filter2d", "--scenes", str(shared_tmp / "scene"),
                          "--predictions", str(shared_tmp / "preds"), "--out", str(out), "--weathers",
                          "clear,rain", "--metrics", "temporal_flicker", "psnr", "--overwrite", "--no-progress")]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=shared_tmp)
    case_counter["faults: read-only output as a non-root user"] += 1
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "error:" in proc.stderr
    assert "not writable" in proc.stderr or "cannot write" in proc.stderr, proc.stderr
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} if out.is_dir() else {}
    assert after == before
    for p in [shared_tmp, *shared_tmp.rglob("*")]:  # let the fixture clean up
        p.chmod(p.stat().st_mode | stat.S_IWUSR)


@pytest.mark.parametrize("kind", ["unreadable predictions folder", "unreadable frame"])
def test_unreadable_predictions_exit_2_naming_the_file_as_a_non_root_user(kind, scene, reference, shared_tmp,
                                                                          as_nobody, case_counter):
    prefix = as_nobody
    shutil.copytree(scene, shared_tmp / "street")
    shutil.copytree(reference / "filter2d", shared_tmp / "preds")
    for p in [shared_tmp, *shared_tmp.rglob("*")]:
        p.chmod(0o777 if p.is_dir() else 0o666)
    rain = shared_tmp / "preds" / "street" / "rain"
    locked = rain if kind == "unreadable predictions folder" else rain / "004.png"
    locked.chmod(0o000)
    out = shared_tmp / "out"
    env = {**os.environ, "HOME": str(shared_tmp), "WCBENCH_CACHE": str(shared_tmp / "cache")}
    cmd = [*prefix, *_cli("evaluate", "--method", "filter2d", "--scenes", str(shared_tmp / "street"),
                          "--predictions", str(shared_tmp / "preds"), "--out", str(out), "--weathers",
                          "clear,rain", "--metrics", "temporal_flicker", "psnr", "--no-progress")]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=shared_tmp)
    finally:
        locked.chmod(0o777 if locked.is_dir() else 0o666)
    case_counter["faults: unreadable predictions as a non-root user"] += 1
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and str(locked) in proc.stderr, proc.stderr
    assert proc.stderr.count("error:") == 1 and proc.stderr.startswith("wcbench evaluate: error:")  # one message
    assert not (out / "results.json").exists() and not list(out.rglob("*.json"))


def test_a_read_only_model_store_exits_2_naming_it_as_a_non_root_user(shared_tmp, as_nobody, case_counter):
    store = shared_tmp / "store"
    store.mkdir()
    source = shared_tmp / "weights.safetensors"
    source.write_bytes(b"not weights")
    source.chmod(0o644)
    store.chmod(0o555)
    env = {**os.environ, "HOME": str(shared_tmp), "WCBENCH_MODELS": str(store)}
    cmd = [*as_nobody, *_cli("models", "import", "lpips-alex", str(source), "--allow-unverified")]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=shared_tmp)
    case_counter["faults: read-only model store as a non-root user"] += 1
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and str(store) in proc.stderr and "permission denied" in proc.stderr
    assert not list(store.iterdir())
    store.chmod(0o777)


def test_a_full_disk_fails_clearly_keeps_finished_work_and_resumes(scene, reference, tmp_path, monkeypatch,
                                                                   capsys, case_counter):
    import wcbench.core.storage as storage

    preds = reference / "filter2d"
    args = ["evaluate", "--method", "filter2d", "--scenes", str(scene), "--predictions", str(preds),
            "--weathers", "clear,rain", "--metrics", "temporal_flicker", "psnr", "fps", "--no-progress"]
    assert main([*args, "--out", str(tmp_path / "clean")]) == 0
    expected = _numbers(tmp_path / "clean", timed=True)
    real_fsync = os.fsync
    for nth in range(1, cases(quick=4, full=4) + 1):  # the unit files, then results.csv, then results.json
        out = tmp_path / f"full-{nth}"
        calls = {"n": 0}

        def fsync(fd: int, _nth: int = nth, _calls: dict = calls) -> None:
            _calls["n"] += 1
            if _calls["n"] == _nth:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            real_fsync(fd)

        monkeypatch.setattr(storage.os, "fsync", fsync)
        capsys.readouterr()
        assert main([*args, "--out", str(out)]) == 2
        monkeypatch.setattr(storage.os, "fsync", real_fsync)
        err = capsys.readouterr().err
        assert "No space left on device" in err and "cannot write" in err and "Traceback" not in err, err
        case_counter["faults: disk full at a write, then resumed"] += 1
        assert not (out / "results.json").exists() and _leftovers(out) == []
        assert main([*args, "--out", str(out)]) == 0
        assert _numbers(out, timed=True) == expected
