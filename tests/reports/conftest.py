"""Fixtures of the report tests: small synthetic results folders with real frames."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from wcbench.bench.report import make_results_folders

#: Small enough that a report builds in about a second.
SMALL = {"methods": ("tint", "haze", "grain"), "scenes": ("scene_a", "scene_b"), "weathers": ("clear", "rain", "fog"),
         "n_frames": 5, "size": (64, 36)}


@pytest.fixture(scope="session")
def _small_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("small_results")
    make_results_folders(root, **SMALL)  # type: ignore[arg-type]
    return root


@pytest.fixture
def small(_small_root: Path, tmp_path: Path) -> dict[str, Path]:
    """A private copy of the three folders (method -> folder); the source frames stay shared."""
    out = {}
    for method in SMALL["methods"]:
        shutil.copytree(_small_root / method, tmp_path / method)
        out[method] = tmp_path / method
    return out
