"""CLIP embedders: preprocessing + tokenizer + a backend (ONNX or torch) + the embedding cache.

The metric classes and functions take any object with the :class:`ClipEmbedder` methods, so
tests inject tiny random-weight models. :func:`shared_clip_encoder` hands every metric the same
:class:`ClipEncoder` per (store, model, backend, crop), so a frame is embedded once per process
and, through the disk cache, once per store.

Torch-free: the torch backend is imported only when asked for.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from wcbench.core.models.store import ModelStore
from wcbench.core.models.store_errors import ModelStoreError
from wcbench.metrics.clip.cache import EmbeddingCache, array_key
from wcbench.metrics.clip.onnx_backend import TEXT_FILE, VISUAL_FILE, OnnxClipBackend
from wcbench.metrics.clip.preprocess import ClipPreprocess, uint8_batch
from wcbench.metrics.clip.tokenizer import VOCAB_ENTRY, ClipTokenizer

#: The model CLIP-S / CLIP-DS use unless told otherwise: ViT-B/32, the model of CLIPScore
#: (Hessel et al. 2021), which the paper cites for CLIP-S; the paper does not name its CLIP.
DEFAULT_MODEL = "clip-vit-b32-openai"
BACKENDS = ("onnx", "torch")
_NORM_FLOOR = 1e-12


@runtime_checkable
class ClipBackend(Protocol):
    """Runs the two towers on prepared inputs (see :mod:`wcbench.metrics.clip.onnx_backend`)."""

    backend: str

    @property
    def identity(self) -> str:
        """Changes whenever the weights change."""

    @property
    def image_size(self) -> int:
        """Input side S."""

    def encode_image(self, pixels: np.ndarray) -> np.ndarray:
        """[B, 3, S, S] float32 -> [B, E] unnormalised."""

    def encode_text(self, tokens: np.ndarray) -> np.ndarray:
        """[T, L] int64 -> [T, E] unnormalised."""


class Tokenizer(Protocol):
    """What :class:`ClipEncoder` needs of a tokenizer (:class:`~.clip_tokenizer.ClipTokenizer`)."""

    def tokenize(self, texts: Sequence[str], *, truncate: bool = True) -> np.ndarray:
        """T texts -> [T, L] int64."""


@runtime_checkable
class ClipEmbedder(Protocol):
    """What the CLIP metrics need: unit-norm embeddings and a config to record."""

    def image_embeddings(self, images: np.ndarray) -> np.ndarray:
        """[B, H, W, 3] RGB in [0, 1] (or uint8) -> [B, E] float64, unit L2 norm."""

    def text_embeddings(self, texts: Sequence[str]) -> np.ndarray:
        """T texts -> [T, E] float64, unit L2 norm."""

    def config(self) -> dict[str, Any]:
        """Model, weights hash, backend and preprocessing, as recorded in results."""


def _normalise(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, np.float64)
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), _NORM_FLOOR)


class ClipEncoder:
    """Embeds frames and texts with one CLIP model, caching by content hash.

    Parameters
    ----------
    backend : ClipBackend
        :class:`~wcbench.metrics.clip.onnx_backend.OnnxClipBackend` or
        :class:`~wcbench.metrics.clip.pytorch.model.TorchClipBackend` (or a test double).
    tokenizer : Tokenizer, optional
        Needed for :meth:`text_embeddings` only.
    crop : str
        ``"center"`` or ``"squash"`` (:class:`~wcbench.metrics.clip.preprocess.ClipPreprocess`).
    cache_dir : path-like, optional
        Disk cache root (``None``: memory only).
    batch_size : int
        Frames per backend call.
    name : str
        Model name for the config (e.g. ``"clip-vit-b32-openai"``).
    info : dict, optional
        More facts for the config (weights sha256...).

    Attributes
    ----------
    image_cache, text_cache : EmbeddingCache
    """

    def __init__(
        self,
        backend: ClipBackend,
        *,
        tokenizer: Tokenizer | None = None,
        crop: str = "center",
        cache_dir: str | os.PathLike[str] | None = None,
        batch_size: int = 16,
        name: str = "",
        info: dict[str, Any] | None = None,
    ):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.backend = backend
        self.tokenizer = tokenizer
        self.preprocess = ClipPreprocess(size=backend.image_size, crop=crop)
        self.batch_size = batch_size
        self.name = name
        self.info = dict(info or {})
        ns = f"{name}|{backend.backend}|{backend.identity}"
        self.image_cache = EmbeddingCache(cache_dir, namespace=f"image|{ns}|{self.preprocess.config()}")
        self.text_cache = EmbeddingCache(cache_dir, namespace=f"text|{ns}")

    def config(self) -> dict[str, Any]:
        """Model, backend, weights identity and preprocessing (part of every CLIP score's config)."""
        return {
            "model": self.name,
            "backend": self.backend.backend,
            "weights": self.backend.identity,
            **self.info,
            "preprocess": self.preprocess.config(),
        }

    def image_embeddings(self, images: np.ndarray) -> np.ndarray:
        """Unit-norm image embeddings f(I), each frame computed at most once.

        Parameters
        ----------
        images : ndarray [B, H, W, 3] or [H, W, 3]
            RGB float in [0, 1] or uint8.

        Returns
        -------
        ndarray [B, E] float64
            L2-normalised embeddings.
        """
        # Key on the uint8 frame the model actually sees, so a PNG and its float form share entries.
        u8 = uint8_batch(images)
        if len(u8) == 0:
            return np.zeros((0, 0))
        keys = [array_key(f) for f in u8]
        found: dict[str, np.ndarray] = {}
        todo: list[int] = []
        for i, key in enumerate(keys):
            if key in found:
                continue
            hit = self.image_cache.get(key)
            if hit is None:
                todo.append(i)
                found[key] = np.empty(0)  # placeholder: duplicates in this batch are embedded once
            else:
                found[key] = hit
        for start in range(0, len(todo), self.batch_size):
            idx = todo[start : start + self.batch_size]
            pixels = self.preprocess(np.stack([u8[i] for i in idx]))
            out = np.asarray(self.backend.encode_image(pixels), np.float32)
            if out.ndim != 2 or out.shape[0] != len(idx):
                raise ValueError(f"backend returned {out.shape} for {len(idx)} images")
            for i, vec in zip(idx, out):
                self.image_cache.put(keys[i], vec)
                found[keys[i]] = vec
        return _normalise(np.stack([found[k] for k in keys]))

    def text_embeddings(self, texts: Sequence[str]) -> np.ndarray:
        """Unit-norm text embeddings g(T).

        Parameters
        ----------
        texts : sequence of str
            T texts, each within the context length (77 tokens for CLIP).

        Returns
        -------
        ndarray [T, E] float64

        Raises
        ------
        ValueError
            If a text is too long (no silent truncation of a prompt) or no tokenizer was given.
        """
        if self.tokenizer is None:
            raise ValueError("this encoder has no tokenizer: text embeddings are unavailable")
        if isinstance(texts, str):
            texts = [texts]
        tokens = np.asarray(self.tokenizer.tokenize(list(texts), truncate=False), np.int64)
        keys = [array_key(row) for row in tokens]
        vecs: list[np.ndarray | None] = [self.text_cache.get(k) for k in keys]
        todo = [i for i, v in enumerate(vecs) if v is None]
        if todo:
            out = np.asarray(self.backend.encode_text(tokens[todo]), np.float32)
            for i, vec in zip(todo, out):
                self.text_cache.put(keys[i], vec)
                vecs[i] = vec
        return _normalise(np.stack([v for v in vecs if v is not None]))


class _StoreTokenizer:
    """Loads CLIP's vocabulary from the store on first use."""

    def __init__(self, store: ModelStore):
        self.store = store
        self._tok: Any = None

    def tokenize(self, texts: Sequence[str], *, truncate: bool = True) -> np.ndarray:
        if self._tok is None:
            self._tok = ClipTokenizer(self.store.require(VOCAB_ENTRY))
        out: np.ndarray = self._tok.tokenize(texts, truncate=truncate)
        return out


def load_clip_encoder(
    model: str = DEFAULT_MODEL,
    *,
    store: ModelStore | None = None,
    backend: str = "onnx",
    crop: str = "center",
    batch_size: int = 16,
    threads: int | None = None,
    disk_cache: bool = True,
) -> ClipEncoder:
    """A :class:`ClipEncoder` for an installed model of the store.

    Parameters
    ----------
    model : str
        Model-store entry (``wcbench models list``).
    store : ModelStore, optional
        Default ``ModelStore()``.
    backend : str
        ``"onnx"`` (onnxruntime, no torch) or ``"torch"`` (needs the ``[model]`` extra).
    crop : str
        ``"center"`` or ``"squash"``.
    batch_size : int
        Frames per inference call.
    threads : int, optional
        Intra-op threads for onnxruntime.
    disk_cache : bool
        Cache embeddings under ``store.cache_dir / "clip-embeddings"``.

    Raises
    ------
    ModelMissingError
        If the weights are not installed (the message says how to get them).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    store = store if store is not None else ModelStore()
    weights = store.require(model)
    sha = store.sha256(model) or ""
    cache_dir = store.cache_dir / "clip-embeddings" if disk_cache else None
    impl: ClipBackend
    if backend == "onnx":
        visual, text = store.path(model, VISUAL_FILE), store.path(model, TEXT_FILE)
        if not visual.is_file():
            raise ModelStoreError(
                f"{model}: {visual} is missing; re-run `wcbench models import {model} FILE` "
                "with torch installed to export it"
            )
        ident = f"{model}:{store.sha256(model, VISUAL_FILE)}+{store.sha256(model, TEXT_FILE)}"
        impl = OnnxClipBackend(visual, text if text.is_file() else None, identity=ident, threads=threads)
    else:
        # torch is optional: only this backend needs it, the default ONNX path never imports it
        from wcbench.metrics.clip.pytorch.backend import TorchClipBackend

        impl = TorchClipBackend.from_file(weights, identity=f"{model}:{sha}")
    return ClipEncoder(
        impl,
        tokenizer=_StoreTokenizer(store),
        crop=crop,
        cache_dir=cache_dir,
        batch_size=batch_size,
        name=model,
        info={"weights_sha256": sha, "weights_verified": store.source_verified(model)},
    )


_SHARED: dict[tuple[Any, ...], ClipEncoder] = {}


def shared_clip_encoder(
    model: str = DEFAULT_MODEL,
    *,
    store: ModelStore | None = None,
    backend: str = "onnx",
    crop: str = "center",
    batch_size: int = 16,
) -> ClipEncoder:
    """:func:`load_clip_encoder`, memoised per (store root, model, backend, crop, batch size).

    Every CLIP metric instance of a process shares these encoders and so their in-memory caches.
    """
    store = store if store is not None else ModelStore()
    key = (str(Path(store.root).resolve()), model, backend, crop, batch_size)
    if key not in _SHARED:
        _SHARED[key] = load_clip_encoder(
            model, store=store, backend=backend, crop=crop, batch_size=batch_size
        )
    return _SHARED[key]


def clear_shared_encoders() -> None:
    """Forget the memoised encoders (frees their sessions and in-memory caches)."""
    _SHARED.clear()
