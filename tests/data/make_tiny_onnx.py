"""Regenerate the tiny random-weight CLIP ONNX files the torch-free tests use.

    python tests/data/make_tiny_onnx.py

Writes ``clip_tiny_visual.onnx`` (pixels [B, 3, 32, 32] -> [B, 8]) and ``clip_tiny_text.onnx``
(tokens [B, 77] int64, ids < 512, the largest id of a row marks its end -> [B, 8]) beside this
script. The model is the real CLIP architecture (``wcbench.metrics.clip.pytorch.model.ClipModel``) at toy
sizes with seeded random weights, so the files carry no trained weights and regenerate the same
numbers; ``tests/metrics/clip/test_onnx.py`` checks them against torch.
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
VISUAL = HERE / "clip_tiny_visual.onnx"
TEXT = HERE / "clip_tiny_text.onnx"
SEED = 0
#: Larger than CLIP's init so that a toy model's embedding still moves visibly with its input.
STD = 0.1


def tiny_arch():  # type: ignore[no-untyped-def]
    """The toy architecture: 4x4 patches of 8 px, width 16, one block per tower, E = 8."""
    from wcbench.metrics.clip.config import ClipArch

    return ClipArch(
        name="tiny",
        embed_dim=8,
        image_size=32,
        patch_size=8,
        vision_width=16,
        vision_layers=1,
        vision_heads=2,
        text_width=16,
        text_layers=1,
        text_heads=2,
        context_length=77,
        vocab_size=512,
        act="quick_gelu",
    )


def tiny_model():  # type: ignore[no-untyped-def]
    """The seeded random-weight toy ClipModel the ONNX files hold (needs torch)."""
    from wcbench.metrics.clip.pytorch.model import ClipModel, randomize_

    return randomize_(ClipModel(tiny_arch()), seed=SEED, std=STD).eval()


def main() -> None:
    """Export both towers next to this script."""
    from wcbench.metrics.clip.pytorch.export import export_onnx

    paths = export_onnx(tiny_model(), HERE)
    paths["visual"].replace(VISUAL)
    paths["text"].replace(TEXT)
    print(f"wrote {VISUAL.name} ({VISUAL.stat().st_size} bytes), {TEXT.name} ({TEXT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
