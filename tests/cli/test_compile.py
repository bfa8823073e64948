"""``wcbench compile``: every kernel runs once (loaded from numba's cache when it is there)."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("numba")

from wcbench.cli import main


def test_compile_runs_every_kernel(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from wcbench.reference_model.kernel_warmup import kernels_compiled

    monkeypatch.setenv("WCBENCH_CACHE", str(tmp_path))
    assert not kernels_compiled()
    assert main(["compile"]) == 0
    assert kernels_compiled()  # the stamp a first run reads to leave the kernels to numba's cache
    captured = capsys.readouterr()
    assert "compiling the numba kernels" in captured.err
    for step in ("raster", "weather", "editor", "training"):
        assert f"{step} kernels ready" in captured.err
    assert captured.out.startswith("kernels ready in ")


def test_compile_reports_a_missing_backend(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
                                           tmp_path: Path) -> None:
    from wcbench.reference_model import _numba_backend
    from wcbench.reference_model.kernel_warmup import kernels_compiled

    monkeypatch.setitem(_numba_backend._failed, "weather.fog_kernels", "ImportError: no numba")
    monkeypatch.delitem(_numba_backend._loaded, "weather.fog_kernels", raising=False)
    monkeypatch.setenv("WCBENCH_CACHE", str(tmp_path))
    assert main(["compile"]) == 2
    assert not kernels_compiled()
    assert "numba kernels weather.fog_kernels unavailable: ImportError: no numba" in capsys.readouterr().err


def test_compile_refuses_a_niceness_out_of_range(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["compile", "--nice", "25"]) == 2
    assert "--nice 25: a niceness increment from 0 to 19 was expected" in capsys.readouterr().err
