"""CLIP towers as ONNX files run by onnxruntime (torch-free); :mod:`.pytorch.export` writes them.

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
from typing import Any

import numpy as np

from wcbench.core.storage import atomic_path, sha256_file

VISUAL_FILE, TEXT_FILE = "visual.onnx", "text.onnx"
class OnnxClipBackend:
    """CLIP towers run by onnxruntime on CPU.

    Parameters
    ----------
    visual : path-like
        ``visual.onnx``.
    text : path-like, optional
        ``text.onnx`` (only needed for text embeddings).
    identity : str, optional
        Names the weights in cache keys; default the sha256 of the ONNX files (hashed on first use).
    threads : int, optional
        onnxruntime intra-op threads (default: onnxruntime's choice, all cores).

    Attributes
    ----------
    image_size : int
        Input side S, read from the graph.
    """

    backend = "onnx"

    def __init__(
        self,
        visual: str | os.PathLike[str],
        text: str | os.PathLike[str] | None = None,
        *,
        identity: str | None = None,
        threads: int | None = None,
    ):
        self.visual_path = Path(visual)
        self.text_path = Path(text) if text is not None else None
        for p in (self.visual_path, self.text_path):
            if p is not None and not p.is_file():
                raise FileNotFoundError(f"{p}: ONNX file not found")
        self._identity = identity
        self._threads = threads
        self._sessions: dict[str, Any] = {}

    def _session(self, which: str) -> Any:
        if which not in self._sessions:
            import onnxruntime as ort

            path = self.visual_path if which == "visual" else self.text_path
            if path is None:
                raise ValueError("this backend has no text.onnx: text embeddings are unavailable")
            opts = ort.SessionOptions()
            if self._threads:
                opts.intra_op_num_threads = self._threads
            self._sessions[which] = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        return self._sessions[which]

    def __getstate__(self) -> dict[str, Any]:
        # onnxruntime sessions do not pickle; they are reopened on first use
        return {**self.__dict__, "_sessions": {}}

    @property
    def identity(self) -> str:
        """A string that changes whenever the weights change (cache key component)."""
        if self._identity is None:
            files = [self.visual_path] + ([self.text_path] if self.text_path else [])
            self._identity = "onnx:" + "+".join(sha256_file(p) for p in files)
        return self._identity

    @property
    def image_size(self) -> int:
        """Side S of the square input the visual graph expects."""
        shape = self._session("visual").get_inputs()[0].shape
        return int(shape[-1])

    @property
    def context_length(self) -> int:
        """Token row length L of the text graph."""
        return int(self._session("text").get_inputs()[0].shape[-1])

    def encode_image(self, pixels: np.ndarray) -> np.ndarray:
        """Image embeddings.

        Parameters
        ----------
        pixels : ndarray [B, 3, S, S] float32
            Preprocessed (normalised) images.

        Returns
        -------
        ndarray [B, E] float32
            Unnormalised embeddings.
        """
        sess = self._session("visual")
        s = self.image_size
        if pixels.ndim != 4 or pixels.shape[1:] != (3, s, s):
            raise ValueError(f"pixels: expected [B, 3, {s}, {s}], got {pixels.shape}")
        out = sess.run(None, {sess.get_inputs()[0].name: np.ascontiguousarray(pixels, np.float32)})[0]
        return np.asarray(out, np.float32)

    def encode_text(self, tokens: np.ndarray) -> np.ndarray:
        """Text embeddings.

        Parameters
        ----------
        tokens : ndarray [T, L] int64

        Returns
        -------
        ndarray [T, E] float32
            Unnormalised embeddings.
        """
        sess = self._session("text")
        if tokens.ndim != 2 or tokens.shape[1] != self.context_length:
            raise ValueError(f"tokens: expected [T, {self.context_length}], got {tokens.shape}")
        out = sess.run(None, {sess.get_inputs()[0].name: np.ascontiguousarray(tokens, np.int64)})[0]
        return np.asarray(out, np.float32)


def quantize_int8(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> Path:
    """Dynamic int8 quantisation of an ONNX tower (weights int8, activations quantised per batch).

    Smaller and faster on CPU but not the same numbers: never mix scores from a quantised model
    with fp32 ones (the backend identity differs, so caches do not mix). Needs the ``onnx`` package.

    Parameters
    ----------
    src, dst : path-like
        fp32 input model and quantised output (written atomically).
    """
    from onnxruntime.quantization import QuantType, quantize_dynamic

    with atomic_path(dst, suffix=".onnx") as tmp:
        quantize_dynamic(str(src), str(tmp), weight_type=QuantType.QInt8)
    return Path(dst)
