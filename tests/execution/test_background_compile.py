"""The kernels compiled in a second process beside a first run (wcbench.execution.background_compile)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("numba")

from wcbench.execution.background_compile import BACKGROUND_COMPILE_ENV, kernels_compiled_aside
from wcbench.reference_model.kernel_warmup import kernels_compiled, kernels_stamp


@pytest.fixture
def cold_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A wcbench cache without the kernels' stamp, the background compile allowed, two cores."""
    monkeypatch.setenv("WCBENCH_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv(BACKGROUND_COMPILE_ENV, "1")
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    return tmp_path / "cache"


def test_a_cold_cache_starts_a_compiling_child_that_the_block_end_stops(cold_cache: Path) -> None:
    said: list[str] = []
    assert not kernels_compiled()
    with kernels_compiled_aside(echo=said.append) as child:
        assert child is not None
        assert child.args[-5:] == ["-m", "wcbench", "compile", "--nice", "10"]
    assert child.poll() is not None  # stopped (or done), never left running
    assert (cold_cache / "kernels" / "compile.log").is_file()
    assert len(said) == 1 and "second process" in said[0] and BACKGROUND_COMPILE_ENV in said[0]


@pytest.mark.parametrize("why", ["off", "one core", "stamped"])
def test_nothing_starts_when_it_cannot_help(cold_cache: Path, monkeypatch: pytest.MonkeyPatch, why: str) -> None:
    if why == "off":
        monkeypatch.setenv(BACKGROUND_COMPILE_ENV, "0")
    elif why == "one core":
        monkeypatch.setattr(os, "cpu_count", lambda: 1)
    else:
        stamp = kernels_stamp()
        stamp.parent.mkdir(parents=True)
        stamp.write_text("{}")
    said: list[str] = []
    with kernels_compiled_aside(echo=said.append) as child:
        assert child is None
    assert said == []


def test_the_stamp_is_named_by_the_cache_numba_writes_to(cold_cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    here = kernels_stamp()
    assert here.parent == cold_cache / "kernels"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cold_cache / "elsewhere"))
    assert kernels_stamp() != here  # another numba cache holds none of these kernels yet
