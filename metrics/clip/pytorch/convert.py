"""Build a torch :class:`~.model.ClipModel` from any supported checkpoint, and the model-store converter.

:func:`convert_clip` is what ``wcbench models pull/import clip-*`` runs: any CLIP checkpoint
(formats in :mod:`.checkpoints`) -> ``model.safetensors`` (OpenAI key names, float32) plus the
ONNX towers the torch-free scorer runs (:mod:`.export`).
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from wcbench.core.models.catalogue import ModelEntry
from wcbench.metrics.clip.config import ClipArch, get_arch
from wcbench.metrics.clip.pytorch.checkpoints import (
    CheckpointError,
    check_state_dict,
    infer_arch,
    load_clip_safetensors,
    read_state_dict,
    save_clip_safetensors,
)
from wcbench.metrics.clip.pytorch.export import export_onnx
from wcbench.metrics.clip.pytorch.model import ClipModel

__all__ = ["build_model", "convert_clip", "load_clip_model"]


def build_model(sd: Mapping[str, np.ndarray], arch: ClipArch) -> ClipModel:
    """A :class:`ClipModel` in eval mode holding ``sd`` (needs torch).

    Raises
    ------
    CheckpointError
        If ``sd`` does not match ``arch``.
    """
    check_state_dict(sd, arch)
    model = ClipModel(arch)
    model.load_state_dict({k: torch.from_numpy(np.array(v, np.float32)) for k, v in sd.items()}, strict=True)
    return model.eval()


def load_clip_model(
    path: str | os.PathLike[str], *, arch: ClipArch | str | None = None, act: str | None = None
) -> ClipModel:
    """Load a :class:`ClipModel` from our safetensors or any supported checkpoint (needs torch).

    Parameters
    ----------
    path : path-like
    arch : ClipArch or str, optional
        Expected architecture; default: ours records it, other formats are inferred from shapes.
    act : str, optional
        Activation for formats that do not record it (default ``"quick_gelu"``, OpenAI's).
    """
    sd, fmt = read_state_dict(path)
    if fmt == "wcbench":
        _, recorded = load_clip_safetensors(path)
        return build_model(sd, recorded)
    if isinstance(arch, str):
        arch = get_arch(arch, act=act)
    return build_model(sd, arch or infer_arch(sd, act=act or "quick_gelu"))


def convert_clip(sources: Sequence[Path], out_dir: Path, entry: ModelEntry) -> None:
    """Model-store converter: any CLIP checkpoint -> ``model.safetensors`` + ONNX towers.

    Parameters
    ----------
    sources : sequence of Path
        One checkpoint file (formats: see module docstring).
    out_dir : Path
        Empty folder receiving ``entry.file`` (our safetensors), ``visual.onnx`` and ``text.onnx``.
    entry : ModelEntry
        ``entry.options``: ``arch`` (a name such as ``"ViT-B/32"``, or a table of
        :class:`ClipArch` fields; default: inferred from the shapes), ``act`` (``"quick_gelu"``,
        the default, or ``"gelu"``); ``onnx = false`` skips the ONNX export.

    Raises
    ------
    CheckpointError
        If the checkpoint is not that architecture (the message names keys and shapes).
    """
    if len(sources) != 1:
        raise CheckpointError(f"{entry.name}: expected one checkpoint file, got {len(sources)}")
    options = dict(entry.options)
    if options.get("onnx", True) and importlib.util.find_spec("torch") is None:
        # Fail before reading a large checkpoint: the ONNX export is what scoring runs.
        raise CheckpointError("converting CLIP weights exports ONNX with torch: pip install 'wcbench[model]'")
    sd, fmt = read_state_dict(sources[0])
    act = str(options.get("act", "quick_gelu"))
    spec = options.get("arch")
    if isinstance(spec, Mapping):  # a full shape table (custom or test models)
        arch = ClipArch(**{**spec, "act": act})
    elif spec is not None:
        arch = get_arch(str(spec), act=act)
    else:
        arch = infer_arch(sd, act=act)
    check_state_dict(sd, arch)
    save_clip_safetensors(out_dir / entry.file, sd, arch, source_format=fmt)
    if options.get("onnx", True):
        export_onnx(build_model(sd, arch), out_dir)
