"""The executor seam: the Dask executor gives the local executor's numbers (docs/design.md §10)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from wcbench.cli import main
from wcbench.core.errors import InputError
from wcbench.evaluation import EvaluateConfig, evaluate
from wcbench.execution import UnitsFailedError, make_executor
from wcbench.execution.dask_cluster import thread_env, threads_per_worker
from wcbench.scenes.sets import resolve_scenes
from wcbench.units import RenderSettings

WEATHERS = ["clear", "rain", "snow", "fog"]
METHODS = ("identity", "filter2d")


@pytest.fixture(scope="module")
def two_scenes(tmp_path_factory: pytest.TempPathFactory) -> str:
    """``--scenes`` of the built-in demo and a copy of it named demo_copy."""
    demo = resolve_scenes("demo")[0].path
    copy = tmp_path_factory.mktemp("scenes") / "demo_copy"
    shutil.copytree(demo, copy)
    return f"demo,{copy}"


@pytest.fixture(scope="module")
def cluster():
    """A 2-process LocalCluster shared by the tests of this module."""
    with make_executor("dask", workers=2, show_progress=False) as executor:
        yield executor


def _cfg(method: str, scenes: str, out: Path, *, render: bool, predictions: Path | None = None) -> EvaluateConfig:
    return EvaluateConfig(method=method, scenes=scenes, predictions=predictions or out / method, out=out,
                          weathers=list(WEATHERS), show_progress=False,
                          render=RenderSettings(seed=3, show_progress=False) if render else None)


def _numbers(doc: dict, *, timed: bool = True) -> dict:
    """Every output's value and per-frame values (``timed=False`` leaves out the measured fps)."""
    return {(s, w, o): (r["value"], r["per_frame"], r["reason"])
            for s, ws in doc["results"].items() for w, outs in ws.items() for o, r in outs.items()
            if timed or r["metric"] != "fps"}


def test_dask_scores_every_unit_as_the_local_executor_does(two_scenes, cluster, tmp_path):
    for method in METHODS:
        local = evaluate(_cfg(method, two_scenes, tmp_path / "local" / method, render=True))
        assert local.units_computed == 8  # 2 scenes x 4 weathers
        preds = tmp_path / "local" / method / method
        # the same frames scored on the cluster: every number equal, fps (read from info.json) included
        remote = evaluate(_cfg(method, two_scenes, tmp_path / "dask" / method, render=False, predictions=preds),
                          executor=cluster)
        assert remote.units_computed == 8
        assert _numbers(remote.results) == _numbers(local.results)
        assert remote.results["skipped"] == local.results["skipped"]
        # rendered on the cluster too: the same frames, so the same numbers but the timings
        ran = evaluate(_cfg(method, two_scenes, tmp_path / "run" / method, render=True), executor=cluster)
        assert _numbers(ran.results, timed=False) == _numbers(local.results, timed=False)
        for scene in ("demo", "demo_copy"):
            for w in WEATHERS:
                a = json.loads((preds / scene / w / "info.json").read_text())["frames"]
                b = json.loads((tmp_path / "run" / method / method / scene / w / "info.json").read_text())["frames"]
                assert [f["sha256"] for f in a] == [f["sha256"] for f in b]
        # a re-run finds every unit kept and computes nothing
        again = evaluate(_cfg(method, two_scenes, tmp_path / "dask" / method, render=False, predictions=preds),
                         executor=cluster)
        assert again.status == "up-to-date"


def test_a_killed_worker_loses_no_unit_and_changes_no_number(two_scenes, tmp_path):
    import cloudpickle
    import dask_faults

    cloudpickle.register_pickle_by_value(dask_faults)  # workers cannot import tests/support
    local = evaluate(_cfg("filter2d", two_scenes, tmp_path / "local", render=True))
    preds = tmp_path / "local" / "filter2d"
    marker = tmp_path / "killed"
    with make_executor("dask", workers=2, show_progress=False) as executor:
        executor.client.register_plugin(dask_faults.KillOnTask(marker, "score_task", nth=2), name="kill-once")
        pids = set(executor.client.run(lambda: __import__("os").getpid()).values())
        remote = evaluate(_cfg("filter2d", two_scenes, tmp_path / "dask", render=False, predictions=preds),
                          executor=executor)
        executor.client.wait_for_workers(2, timeout=60)
        after = set(executor.client.run(lambda: __import__("os").getpid()).values())
    assert marker.is_file(), "the plugin never killed a worker"
    assert int(marker.read_text()) in pids and int(marker.read_text()) not in after  # that process died
    assert remote.units_computed == 8
    assert _numbers(remote.results) == _numbers(local.results)


def test_a_client_killed_before_assembling_resumes_without_redoing_a_unit(two_scenes, cluster, tmp_path):
    evaluate(_cfg("filter2d", two_scenes, tmp_path / "local", render=True))
    preds, out = tmp_path / "local" / "filter2d", tmp_path / "dask"
    first = evaluate(_cfg("filter2d", two_scenes, out, render=False, predictions=preds), executor=cluster)
    (out / "results.json").unlink()  # the client died after the units, before results.json
    stamps = {p: p.stat().st_mtime_ns for p in (out / ".work").rglob("*.json")}
    again = evaluate(_cfg("filter2d", two_scenes, out, render=False, predictions=preds), executor=cluster)
    assert (again.units_computed, again.units_reused) == (0, 8)
    assert {p: p.stat().st_mtime_ns for p in (out / ".work").rglob("*.json")} == stamps  # nothing rewritten
    assert _numbers(again.results) == _numbers(first.results)


def test_failed_unit_is_reported_and_the_others_are_kept(two_scenes, cluster, tmp_path):
    evaluate(_cfg("filter2d", two_scenes, tmp_path / "local", render=True))
    preds = tmp_path / "local" / "filter2d"
    bad = preds / "demo_copy" / "rain" / "002.png"
    bad.write_bytes(bad.read_bytes()[:200])  # truncated: found only when the frame is decoded
    out = tmp_path / "dask"
    with pytest.raises(UnitsFailedError) as err:
        evaluate(_cfg("filter2d", two_scenes, out, render=False, predictions=preds), executor=cluster)
    text = str(err.value)
    assert "1 unit(s) failed while scoring, 7 finished" in text and "filter2d demo_copy rain" in text
    assert "002.png" in text and err.value.exit_code == 2
    assert not (out / "results.json").exists()
    kept = sorted(p.relative_to(out / ".work").as_posix() for p in (out / ".work").rglob("*.json"))
    assert len(kept) == 7 and "demo_copy/rain.json" not in kept


def test_threads_are_shared_out_and_missing_resources_are_refused(cluster):
    assert threads_per_worker(2, 2) == 1 and threads_per_worker(8, 3) == 2 and threads_per_worker(1, 4) == 1
    assert thread_env(3)["OMP_NUM_THREADS"] == "3" and thread_env(3)["NUMBA_NUM_THREADS"] == "3"
    limits = cluster.client.run(lambda: __import__("os").environ.get("OMP_NUM_THREADS"))
    cores = __import__("os").cpu_count()
    assert set(limits.values()) == {str(threads_per_worker(cores, 2))}
    with pytest.raises(InputError, match="gpu=1"):
        cluster._resources(["gpu"])


@pytest.mark.slow  # 20 s: starts local Dask clusters; the executor's scoring is tested above
def test_cli_options_of_the_executor(tmp_path, capsys):
    assert main(["run", "--method", "filter2d", "--scenes", "demo", "--out", str(tmp_path / "a"),
                 "--workers", "2"]) == 2
    assert "--executor dask" in capsys.readouterr().err
    assert main(["run", "--method", "filter2d", "--scenes", "demo", "--out", str(tmp_path / "b"),
                 "--executor", "dask", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["run", "--method", "filter2d", "--scenes", "demo", "--out", str(tmp_path / "c"),
                 "--executor", "dask", "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert "cannot reach the Dask scheduler" in capsys.readouterr().err


def test_two_scene_ids_that_clash_are_refused(tmp_path):
    demo = resolve_scenes("demo")[0].path
    copy = tmp_path / "demo"  # another folder, whose id is the set's scene's
    shutil.copytree(demo, copy)
    with pytest.raises(InputError, match=r"scene ids \['demo'\] come up more than once"):
        resolve_scenes(f"{copy},demo")
    with pytest.raises(InputError, match="one scene folder given twice"):  # one folder, two names
        resolve_scenes(f"{demo},demo")


def test_the_local_path_never_imports_dask(tmp_path):
    code = (
        "import sys\n"
        "from wcbench.cli import main\n"
        f"assert main(['run', '--method', 'filter2d', '--scenes', 'demo', '--out', {str(tmp_path / 'o')!r}, "
        "'--weathers', 'clear,rain', '--no-progress']) == 0\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"


def test_the_dask_executor_without_its_extra_says_how_to_install_it():
    code = (
        "import sys\n"
        "sys.modules['distributed'] = None  # as if the [dask] extra were not installed\n"
        "from wcbench.cli import main\n"
        "sys.exit(main(['evaluate', '--method', 'folder', '--scenes', 'demo', '--predictions', '.', "
        "'--out', 'o', '--executor', 'dask']))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 2, proc.stderr
    assert "pip install \"wcbench[dask]\"" in proc.stderr and "Traceback" not in proc.stderr
