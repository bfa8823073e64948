"""Choosing a segmenter: a model-store name or a converted folder, run by onnxruntime or torch.

Above both backends: the onnxruntime one (:mod:`.segmenter`) is the scoring default and never
imports torch; the torch one (:mod:`.pytorch.backend`) is imported only when asked for.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.models.store import ModelStore
from wcbench.metrics.semantic.segmenter import OnnxSegmenter

__all__ = ["BACKENDS", "load_segmenter"]

#: How a named segmenter runs: onnxruntime (the scoring default) or torch (the ``[model]`` extra).
BACKENDS = ("onnx", "torch")


def load_segmenter(
    name_or_dir: str | os.PathLike[str],
    *,
    backend: str = "onnx",
    store: Any = None,
    threads: int | None = None,
) -> Callable[[np.ndarray], np.ndarray]:
    """A segmenter from a model-store name (``"segformer-b0-ade"``) or a converted folder.

    The onnxruntime segmenter records in its ``config()`` whether its weights are verified (a
    store entry whose source matched a pinned sha256; never a bare folder).

    Parameters
    ----------
    name_or_dir : str or path-like
        A converted folder, or else a model-store name (``models.toml``).
    backend : {"onnx", "torch"}
        ``"torch"`` needs the ``[model]`` extra and the folder's ``weights.safetensors``.
    store : ModelStore, optional
        Default: ``ModelStore()`` (root from ``WCBENCH_MODELS`` or the user cache).
    threads : int, optional
        onnxruntime intra-op threads.

    Raises
    ------
    wcbench.core.models.store.ModelMissingError
        When the named model is not in the store (the message says how to get it).
    wcbench.core.errors.UnknownNameError
        When ``name_or_dir`` is neither a folder nor a registered model.
    ValueError
        On an unknown backend.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
    key = os.fspath(name_or_dir)
    if Path(key).is_dir():
        # a folder outside the store: nothing pinned its source (docs/design.md §6)
        model_dir, name, verified = Path(key), Path(key).name, False
    else:
        if store is None:
            store = ModelStore()
        model_dir, name = Path(store.require(key)).parent, key  # require() gives the main file, model.onnx
        verified = store.source_verified(key) is True
    if backend == "torch":
        # torch is optional: the evaluation side scores with onnxruntime and never imports it
        from wcbench.metrics.semantic.pytorch.backend import load_torch_segmenter

        return load_torch_segmenter(model_dir, name=name)
    return OnnxSegmenter(model_dir, name=name, threads=threads, weights_verified=verified)
