"""Regenerate the tiny random-weight segmenters used by the torch-free tests.

    python tests/data/make_tiny_seg_onnx.py

Writes ``tests/data/seg_tiny_segformer/`` and ``tests/data/seg_tiny_upernet/``: converted
segmenter folders (``model.onnx``, ``weights.safetensors``, ``segmenter.json``, as the model store
holds them) of miniature SegFormer / UperNet-ConvNeXt networks with 5 classes and a 64x64 input,
plus ``expected.npz``: a fixed test image, the torch logits for it and the torch labels at the
image's own size, so tests without torch can check onnxruntime against torch. Seeded: the same
torch version writes the same numbers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from wcbench.metrics.semantic.pytorch.backend import TorchSegmenter
from wcbench.metrics.semantic.pytorch.convert import write_segmenter_dir
from wcbench.metrics.semantic.pytorch.segformer import SegFormer, SegFormerConfig
from wcbench.metrics.semantic.pytorch.upernet_convnext import UperNetConvNext, UperNetConvNextConfig
from wcbench.metrics.semantic.segmenter import SegmenterSpec

HERE = Path(__file__).resolve().parent
INPUT_SIZE = (64, 64)


def _randomize(model: torch.nn.Module, seed: int) -> torch.nn.Module:
    """Weights of unit-ish scale (default inits give near-constant logits, a weak test)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for _, p in sorted(model.named_parameters()):
            fan_in = p[0].numel() if p.ndim > 1 else 1
            p.copy_(torch.randn(p.shape, generator=g) / max(fan_in, 1) ** 0.5)
        for name, b in sorted(model.named_buffers()):
            if name.endswith("running_mean"):
                b.copy_(torch.randn(b.shape, generator=g) * 0.1)
            elif name.endswith("running_var"):
                b.copy_(torch.rand(b.shape, generator=g) + 0.5)
    return model.eval()


def _balance_classes(model: torch.nn.Module, img: np.ndarray, stride: int) -> None:
    """Shift the classifier bias by minus each class's mean logit on ``img``.

    Random networks give logits whose class offsets dwarf their spatial variation (one label
    everywhere); centred, the classes compete and the label map has regions and boundaries.
    """
    spec = SegmenterSpec(arch="x", variant="x", num_classes=5, input_size=INPUT_SIZE, logits_stride=stride)
    logits = TorchSegmenter(model, spec).logits(img[None])[0]
    with torch.no_grad():
        bias: torch.Tensor = model.get_parameter("decode_head.classifier.bias")
        bias -= torch.from_numpy(logits.mean(axis=(1, 2)))


def tiny_segformer() -> SegFormer:
    """A 5-class SegFormer with every feature of MiT (sequence reduction, four stages)."""
    cfg = SegFormerConfig(
        hidden_sizes=(8, 16, 24, 32),
        depths=(1, 1, 2, 1),
        decoder_hidden_size=16,
        num_labels=5,
        num_attention_heads=(1, 2, 3, 4),
    )
    return _randomize(SegFormer(cfg), 0)  # type: ignore[return-value]


def tiny_upernet() -> UperNetConvNext:
    """A 5-class UperNet-ConvNeXt with all four stages, pyramid pooling and FPN."""
    cfg = UperNetConvNextConfig(hidden_sizes=(8, 16, 24, 32), depths=(1, 1, 2, 1), channels=16, num_labels=5)
    return _randomize(UperNetConvNext(cfg), 1)  # type: ignore[return-value]


def sample_image() -> np.ndarray:
    """A fixed 50x70 RGB image in [0, 1] (float32), smooth enough to give regions."""
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:50, 0:70] / 10.0
    img = np.stack([np.sin(xx + rng.random()), np.cos(yy * 1.3), np.sin(xx * yy / 5)], -1) * 0.5 + 0.5
    return np.clip(img + rng.normal(0, 0.05, img.shape), 0, 1).astype(np.float32)


def main() -> None:
    """Write both folders."""
    img = sample_image()
    for name, model, arch, stride in (
        ("seg_tiny_segformer", tiny_segformer(), "segformer", 4),
        ("seg_tiny_upernet", tiny_upernet(), "upernet-convnext", 1),
    ):
        _balance_classes(model, img, stride)
        out = write_segmenter_dir(
            model, HERE / name, arch=arch, variant="custom", input_size=INPUT_SIZE, logits_stride=stride
        )
        seg = TorchSegmenter(model, SegmenterSpec.from_file(out / "segmenter.json"))
        np.savez_compressed(
            out / "expected.npz", image=img, logits=seg.logits(img[None]), labels=seg(img[None])
        )
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
