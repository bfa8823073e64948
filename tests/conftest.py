"""Shared fixtures: the real scene (when present), an isolated cache, small fixture scenes."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from paths import PANDASET

#: The modules of the longest slow tests (tens of minutes on 2 cores), run first: with
#: ``--dist loadfile --no-loadscope-reorder`` (tox.ini) the two processes start on them together and
#: the other modules fill in around them (longest first); last, the README's commands would start
#: after everything else and run alone at the end.
LONGEST_FIRST = ("tests/cli/test_readme_commands.py", "tests/bench/test_all_quick.py",
                 "tests/bench/test_streets_suite.py")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {module: i for i, module in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))  # stable: the rest keep their order


@pytest.fixture(scope="session", autouse=True)
def _isolated_environment(tmp_path_factory: pytest.TempPathFactory) -> None:
    """A private cache (built-in scenes, models), no progress bars, and a working directory outside
    the source tree for the whole session: subprocesses (`python -c`, `python -m`) put the cwd first
    on sys.path, where the repository's `wcbench/` folder would shadow the installed package.
    Offline: no test fetches weights unless it is about fetching (and sets its own store). No kernels
    compiled in a second process beside a run (tests/execution/test_background_compile.py turns it on)."""
    cache = tmp_path_factory.mktemp("wcbench_cache")
    os.chdir(tmp_path_factory.mktemp("cwd"))
    os.environ.setdefault("WCBENCH_CACHE", str(cache))
    os.environ.setdefault("WCBENCH_MODELS", str(cache / "models"))
    os.environ["WCBENCH_PROGRESS"] = "0"
    os.environ["WCBENCH_OFFLINE"] = "1"
    # the tests' kernels compile in the process that calls them; a child compiling beside would slow them
    os.environ["WCBENCH_BACKGROUND_COMPILE"] = "0"
    os.environ.pop("WCBENCH_DATA", None)


@pytest.fixture(autouse=True)
def _seeded_global_generators() -> None:
    """Every test starts from the same global torch and numpy state, so a test that draws from
    them without its own generator still sees the same numbers on every machine and every run."""
    np.random.seed(0)  # noqa: NPY002 - seeds the legacy global state on purpose
    try:
        import torch
    except ImportError:  # the torch-free install of the test matrix
        return
    torch.manual_seed(0)


@pytest.fixture(scope="session")
def pandaset_root() -> Path:
    """../shared/data/pandaset_002, or skip when it is not beside the project."""
    if not (PANDASET / "images").is_dir():
        pytest.skip(f"real scene not present at {PANDASET}")
    return PANDASET


@pytest.fixture(scope="session")
def demo_scene():
    """The built-in procedural scene (12 frames, 320x180)."""
    from wcbench.scenes.sets import resolve_scenes

    return resolve_scenes("demo")[0].load()


@pytest.fixture(scope="session")
def synth_hard(tmp_path_factory: pytest.TempPathFactory):
    """The harder synthetic street (synth_hard_1: sun shadows, buildings above the lidar, no sky
    masks, untracked movers), generated once for the session: under pytest-xdist (tox.ini) once for
    all the processes, into a folder they share, the others waiting on its lock (it takes minutes)."""
    pytest.importorskip("torch", reason="the synth scenes are rendered by the reference model")
    from wcbench.core.locking import EntryLock
    from wcbench.scenes.sets import resolve_scenes

    base = tmp_path_factory.getbasetemp()
    shared = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "synth_hard_cache"
    lock = EntryLock(shared.with_name("synth_hard_cache.lock"), what="generating the tests' synth_hard_1",
                     timeout_s=None)
    with lock, pytest.MonkeyPatch.context() as mp:
        mp.setenv("WCBENCH_CACHE", str(shared))
        return resolve_scenes("synth_hard_1")[0].load()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
