"""CLIP in torch behind the backend interface of :mod:`wcbench.metrics.clip.encoder` (``backend="torch"``)."""

from __future__ import annotations

import os

import numpy as np
import torch

from wcbench.metrics.clip.pytorch.convert import load_clip_model
from wcbench.metrics.clip.pytorch.model import ClipModel

__all__ = ["TorchClipBackend"]


class TorchClipBackend:
    """:class:`ClipModel` behind the backend interface of :mod:`wcbench.metrics.clip.encoder`.

    Parameters
    ----------
    model : ClipModel
        Put in eval mode, float32.
    identity : str
        Names the weights in cache keys (e.g. ``"<model name>:<sha256>"``).
    """

    backend = "torch"

    def __init__(self, model: ClipModel, *, identity: str):
        self.model = model.eval().float()
        self.identity = identity
        self.image_size = model.arch.image_size
        self.context_length = model.arch.context_length

    @classmethod
    def from_file(cls, path: str | os.PathLike[str], *, identity: str) -> TorchClipBackend:
        """Load any supported checkpoint (see :func:`wcbench.metrics.clip.pytorch.convert.load_clip_model`)."""
        return cls(load_clip_model(path), identity=identity)

    def encode_image(self, pixels: np.ndarray) -> np.ndarray:
        """[B, 3, S, S] float32 -> [B, E] float32 unnormalised."""
        with torch.inference_mode():
            return self.model.encode_image(torch.from_numpy(np.ascontiguousarray(pixels, np.float32))).numpy()

    def encode_text(self, tokens: np.ndarray) -> np.ndarray:
        """[T, L] int64 -> [T, E] float32 unnormalised."""
        with torch.inference_mode():
            return self.model.encode_text(torch.from_numpy(np.ascontiguousarray(tokens, np.int64))).numpy()
