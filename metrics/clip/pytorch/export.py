"""Export the CLIP towers to ONNX for the torch-free scorer (:mod:`wcbench.metrics.clip.onnx_backend`).

Two graphs per model, so that scoring images never loads the text tower and vice versa:

- ``visual.onnx``: input ``pixels`` [B, 3, S, S] float32 (output of
  :func:`~wcbench.metrics.clip.preprocess.preprocess_images`) -> ``image_embeds`` [B, E] float32;
- ``text.onnx``: input ``tokens`` [B, L] int64 (from
  :meth:`~wcbench.metrics.clip.tokenizer.ClipTokenizer.tokenize`) -> ``text_embeds`` [B, E] float32.

Embeddings are unnormalised, exactly as the torch model returns them. The batch axis is dynamic.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from wcbench.metrics.clip.onnx_backend import TEXT_FILE, VISUAL_FILE
from wcbench.metrics.clip.pytorch.model import ClipModel, ImageTower, TextTower
from wcbench.metrics.onnx_export import ONNX_OPSET
from wcbench.metrics.onnx_export import export_onnx as export_onnx_graph

__all__ = ["export_onnx"]


def export_onnx(model: ClipModel, out_dir: str | os.PathLike[str], *, opset: int = ONNX_OPSET) -> dict[str, Path]:
    """Export both towers of ``model`` to ``out_dir/visual.onnx`` and ``out_dir/text.onnx``.

    Written through :func:`wcbench.metrics.onnx_export.export_onnx` (atomic files).

    Parameters
    ----------
    model : ClipModel
        In eval mode, float32.
    out_dir : path-like
    opset : int

    Returns
    -------
    dict
        ``{"visual": path, "text": path}``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    arch = model.arch
    model = model.eval().float()
    pixels = torch.zeros(2, 3, arch.image_size, arch.image_size)
    tokens = torch.zeros(2, arch.context_length, dtype=torch.long)
    tokens[:, 1] = arch.vocab_size - 1  # any ids work for tracing; the last id plays end-of-text
    jobs: list[tuple[str, torch.nn.Module, torch.Tensor, str, str]] = [
        ("visual", ImageTower(model), pixels, "pixels", "image_embeds"),
        ("text", TextTower(model), tokens, "tokens", "text_embeds"),
    ]
    paths = {}
    for name, module, example, inp, outp in jobs:
        dest = out / (VISUAL_FILE if name == "visual" else TEXT_FILE)
        export_onnx_graph(module, (example,), dest, input_names=[inp], output_names=[outp],
                          dynamic_axes={inp: {0: "batch"}, outp: {0: "batch"}}, opset=opset)
        paths[name] = dest
    return paths
