"""tools/: the workstation check's shell scripts parse, and its guided-filter fallback is the exact
guided filter (and OpenCV's where OpenCV's is) (docs/workstation.md)."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

TOOLS = Path(__file__).resolve().parents[1] / "tools"


def _fallback():
    spec = importlib.util.spec_from_file_location("ximgproc_fallback", TOOLS / "ximgproc_fallback.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _exact(guide: np.ndarray, src: np.ndarray, r: int, eps: float) -> np.ndarray:
    """He et al.'s guided filter in float64, colour guide, written out."""
    I, p = guide.astype(np.float64), src.astype(np.float64)  # noqa: E741

    def mean(a):
        return cv2.boxFilter(a, cv2.CV_64F, (2 * r + 1, 2 * r + 1), normalize=True, borderType=cv2.BORDER_REFLECT)

    mI = [mean(I[..., k]) for k in range(3)]
    mp = mean(p)
    cov = np.stack([mean(I[..., k] * p) - mI[k] * mp for k in range(3)], -1)
    S = np.stack([np.stack([mean(I[..., i] * I[..., j]) - mI[i] * mI[j] for j in range(3)], -1) for i in range(3)], -2)
    a = np.linalg.solve(S + eps * np.eye(3), cov[..., None])[..., 0]
    b = mp - sum(a[..., k] * mI[k] for k in range(3))
    return sum(mean(a[..., k]) * I[..., k] for k in range(3)) + mean(b)


@pytest.fixture(scope="module")
def case():
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.random((45, 80, 3)).astype(np.float32), (0, 0), 2)
    return image, (image.mean(-1) > 0.5).astype(np.float32)


@pytest.mark.parametrize("r, eps", [(2, 1e-4), (4, 1e-3), (8, 1e-2)])
def test_the_fallback_is_the_exact_guided_filter(case, r, eps):
    image, mask = case
    np.testing.assert_allclose(_fallback().guided_filter(image, mask, r, eps), _exact(image, mask, r, eps), atol=1e-4)


@pytest.mark.skipif(not hasattr(cv2, "ximgproc"), reason="OpenCV without the contrib modules")
def test_the_fallback_equals_opencvs_for_a_gray_guide_and_a_colour_guide_at_eps_1e2(case):
    image, mask = case
    f = _fallback()
    gray = np.ascontiguousarray(image[..., 0])
    np.testing.assert_allclose(f.guided_filter(gray, mask, 4, 1e-3), cv2.ximgproc.guidedFilter(gray, mask, 4, 1e-3),
                               atol=1e-4)  # the borders: float32 rounding of the box sums
    np.testing.assert_allclose(f.guided_filter(image, mask, 8, 1e-2), cv2.ximgproc.guidedFilter(image, mask, 8, 1e-2),
                               atol=1e-4)  # the borders: float32 rounding of the box sums
    assert f.install() is False  # ximgproc is there: nothing replaced


@pytest.mark.skipif(shutil.which("bash") is None, reason="no bash")
@pytest.mark.parametrize("script", ["workstation_check.sh", "prepare_workstation_wheels.sh"])
def test_the_workstation_scripts_parse(script):
    subprocess.run(["bash", "-n", str(TOOLS / script)], check=True)


def test_the_prebuilt_gsplat_module_raises_importerror_when_its_file_does_not_load(tmp_path, monkeypatch):
    # gsplat imports gsplat.csrc inside try/except ImportError and builds its kernels instead: any other
    # exception from a file that does not load (another torch, no CUDA here) would stop it.
    bad = tmp_path / "gsplat_cuda.so"
    bad.write_bytes(b"not a shared object")
    monkeypatch.setenv("WCBENCH_GSPLAT_SO", str(bad))
    spec = importlib.util.spec_from_file_location("csrc_under_test", TOOLS / "gsplat_prebuilt.py")
    assert spec is not None and spec.loader is not None
    with pytest.raises(ImportError, match="the prebuilt gsplat extension does not load"):
        spec.loader.exec_module(importlib.util.module_from_spec(spec))
    monkeypatch.delenv("WCBENCH_GSPLAT_SO")
    with pytest.raises(ImportError):  # no file named at all
        spec.loader.exec_module(importlib.util.module_from_spec(spec))


@pytest.mark.slow  # the sky segmentation of 30 frames: about 50 s on the shared 2-core machine
def test_the_exported_sky_masks_are_what_the_analysis_then_reads(pandaset_root, tmp_path):
    pytest.importorskip("torch")
    from wcbench.reference_model.scene_analysis.analysis import analyse_scene, clear_analysis_cache
    from wcbench.scenes.loaders import load_scene

    scene_dir = tmp_path / "pandaset_002"
    shutil.copytree(pandaset_root, scene_dir, ignore=shutil.ignore_patterns("sky_masks"))
    subprocess.run([sys.executable, str(TOOLS / "export_sky_masks.py"), str(scene_dir)], check=True)
    clear_analysis_cache()
    segmented = analyse_scene(load_scene(pandaset_root), log=None)
    shipped = analyse_scene(load_scene(scene_dir), log=None)  # the workstation's path: no cv2.ml needed
    assert shipped.sky.facts["source"] == "shipped sky masks"
    np.testing.assert_array_equal(shipped.sky.masks, segmented.sky.masks)


def _step_profile(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(TOOLS / "gpu_step_profile.py"), *args], capture_output=True,
                          text=True, env={**os.environ, "WCBENCH_PROGRESS": "0", "WCBENCH_OFFLINE": "1"})


def test_the_step_profile_refuses_bad_options_in_one_line(tmp_path):
    pytest.importorskip("torch")
    bad = _step_profile("--data-root", str(tmp_path), "--out", str(tmp_path / "p.json"))
    assert bad.returncode == 2 and "pandaset_002: no such folder" in bad.stderr
    bad = _step_profile("--data-root", str(tmp_path), "--steps", "0", "--out", str(tmp_path / "p.json"))
    assert bad.returncode == 2 and "must be at least 1" in bad.stderr
    assert not (tmp_path / "p.json").exists()


@pytest.mark.slow  # prepares pandaset_002's training: about 60 s on the shared 2-core machine
def test_the_step_profile_labels_every_part_of_a_cpu_step(pandaset_root, tmp_path):
    pytest.importorskip("torch")
    out = tmp_path / "p.json"
    done = _step_profile("--data-root", str(pandaset_root.parent), "--device", "cpu", "--warmup", "1", "--steps", "2",
                         "--record", "2", "--out", str(out))
    assert done.returncode == 0, done.stderr
    profile = json.loads(out.read_text())
    assert profile["device"] == "cpu" and profile["gaussians"] > 100_000 and profile["ms_per_step"] > 0
    parts = profile["parts_host_ms_per_step"]
    for part in ("render", "rasterizer", "decoders", "sky", "rgb_loss", "backward", "optimizer", "log_transfer"):
        assert parts[part] > 0, part
    assert parts["render"] >= parts["rasterizer"] + parts["decoders"]  # nested inside the render
    assert profile["aten_calls_per_step"] > 100 and profile["launches_per_step"] is None
