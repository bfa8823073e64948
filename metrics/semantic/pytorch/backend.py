"""A torch-backed segmenter: the networks of a converted folder run in torch (needs the ``[model]`` extra).

Same preprocessing and post-processing as the onnxruntime segmenter of
:mod:`wcbench.metrics.semantic.segmenter` (which scoring uses by default); only the network runs in
torch. The folder is one written by :func:`wcbench.metrics.semantic.pytorch.convert.write_segmenter_dir`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from wcbench.metrics.semantic.pytorch.segformer import SegFormerConfig, load_segformer
from wcbench.metrics.semantic.pytorch.upernet_convnext import UperNetConvNextConfig, load_upernet_convnext
from wcbench.metrics.semantic.segmenter import SPEC_FILE, LogitsSegmenter, SegmenterSpec, preprocess

__all__ = ["TorchSegmenter", "load_torch_segmenter"]


class TorchSegmenter(LogitsSegmenter):
    """``segment(images [B, H, W, 3] float in [0, 1]) -> labels [B, H, W] int64`` with a torch network.

    Same preprocessing and post-processing as
    :class:`~wcbench.metrics.semantic.segmenter.OnnxSegmenter`; only the network runs in torch.

    Parameters
    ----------
    model : nn.Module
        pixel_values [B, 3, h, w] -> logits.
    spec : SegmenterSpec
    name : str, optional
        Recorded in :meth:`config` (default ``"<arch>-<variant>"``).
    """

    def __init__(self, model: nn.Module, spec: SegmenterSpec, *, name: str | None = None):
        self.model = model.eval()
        self.spec = spec
        self.name = name or f"{spec.arch}-{spec.variant}"

    def logits(self, images: np.ndarray) -> np.ndarray:
        """Network logits [B, C, h', w'] (float32) of images [B, H, W, 3] in [0, 1]."""
        x = preprocess(images, size=self.spec.input_size, mean=self.spec.mean, std=self.spec.std)
        with torch.no_grad():
            return self.model(torch.from_numpy(x)).numpy()

    def config(self) -> dict[str, Any]:
        """What produced the labels (recorded with every Sem-CS number)."""
        return {"segmenter": self.name, "backend": "torch", **self.spec.to_json()}


def load_torch_segmenter(model_dir: str | Path, *, name: str | None = None) -> TorchSegmenter:
    """A :class:`TorchSegmenter` from a converted folder (``weights.safetensors`` + ``segmenter.json``)."""
    model_dir = Path(model_dir)
    spec = SegmenterSpec.from_file(model_dir / SPEC_FILE)
    model: nn.Module
    arch: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in spec.architecture.items()}
    if spec.arch == "segformer":
        seg_cfg = SegFormerConfig(**arch) if arch else None
        model = load_segformer(model_dir / "weights.safetensors", config=seg_cfg)
    elif spec.arch == "upernet-convnext":
        up_cfg = UperNetConvNextConfig(**arch) if arch else None
        model = load_upernet_convnext(model_dir / "weights.safetensors", config=up_cfg)
    else:
        raise ValueError(f"{model_dir / SPEC_FILE}: unknown segmenter arch {spec.arch!r}")
    return TorchSegmenter(model, spec, name=name)
