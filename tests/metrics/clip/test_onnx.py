"""ONNX export of the CLIP towers against torch, and the committed tiny ONNX files."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

import importlib.util  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from paths import DATA  # noqa: E402

from wcbench.metrics.clip.config import CLIP_ARCHS  # noqa: E402
from wcbench.metrics.clip.onnx_backend import OnnxClipBackend  # noqa: E402
from wcbench.metrics.clip.pytorch.backend import TorchClipBackend  # noqa: E402
from wcbench.metrics.clip.pytorch.export import export_onnx  # noqa: E402
from wcbench.metrics.clip.pytorch.model import ClipModel, randomize_  # noqa: E402

#: Required agreement of embeddings (|x| ~ 1) between onnxruntime and torch: both float32,
#: different kernels and summation order (measured ~2e-6 for ViT-B/32).
ONNX_TOL = 1e-4


def _tiny_module():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("make_tiny_onnx", DATA / "make_tiny_onnx.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def random_inputs(arch_size: int, vocab: int, batch: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    pixels = rng.standard_normal((batch, 3, arch_size, arch_size)).astype(np.float32)
    tokens = np.zeros((batch, 77), np.int64)
    for r in range(batch):
        n = int(rng.integers(1, 60))
        tokens[r, 0] = vocab - 2
        tokens[r, 1 : n + 1] = rng.integers(1, vocab - 2, n)
        tokens[r, n + 1] = vocab - 1  # end-of-text, the largest id
    return pixels, tokens


def compare(model: ClipModel, onnx: OnnxClipBackend, batches: tuple[int, ...] = (1, 3)) -> float:
    torch_backend = TorchClipBackend(model, identity="t")
    worst = 0.0
    for b in batches:  # the batch axis is dynamic in the exported graphs
        pixels, tokens = random_inputs(model.arch.image_size, model.arch.vocab_size, b, seed=b)
        for a, o in (
            (torch_backend.encode_image(pixels), onnx.encode_image(pixels)),
            (torch_backend.encode_text(tokens), onnx.encode_text(tokens)),
        ):
            assert a.shape == o.shape == (b, model.arch.embed_dim)
            worst = max(worst, float(np.abs(a - o).max()))
    return worst


def test_committed_tiny_files_are_the_seeded_model() -> None:
    tiny = _tiny_module()
    onnx = OnnxClipBackend(tiny.VISUAL, tiny.TEXT)
    assert onnx.image_size == 32 and onnx.context_length == 77
    assert compare(tiny.tiny_model(), onnx) <= ONNX_TOL


def test_export_vit_b32_random_weights(tmp_path: Path) -> None:
    model = randomize_(ClipModel(CLIP_ARCHS["ViT-B/32"]), seed=3).eval()
    paths = export_onnx(model, tmp_path)
    assert paths["visual"].name == "visual.onnx" and not list(tmp_path.glob(".*"))
    assert compare(model, OnnxClipBackend(paths["visual"], paths["text"]), batches=(2,)) <= ONNX_TOL


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ViT-B/16", "ViT-L/14"])
def test_export_large_archs(tmp_path: Path, name: str) -> None:
    model = randomize_(ClipModel(CLIP_ARCHS[name]), seed=4).eval()
    paths = export_onnx(model, tmp_path)
    assert compare(model, OnnxClipBackend(paths["visual"], paths["text"]), batches=(2,)) <= ONNX_TOL


def test_onnx_input_checks(tmp_path: Path) -> None:
    tiny = _tiny_module()
    onnx = OnnxClipBackend(tiny.VISUAL)
    with pytest.raises(ValueError, match=r"expected \[B, 3, 32, 32\]"):
        onnx.encode_image(np.zeros((1, 3, 224, 224), np.float32))
    with pytest.raises(ValueError, match=r"no text\.onnx"):
        onnx.encode_text(np.zeros((1, 77), np.int64))
    with pytest.raises(FileNotFoundError, match="ONNX file not found"):
        OnnxClipBackend(tmp_path / "missing.onnx")
