"""Converting a segmentation checkpoint into a model-store folder, with its ONNX export (needs torch).

Store layout of one converted segmenter (a folder)::

    model.onnx           input "pixel_values" [B, 3, h, w] float32 (normalised), output "logits"
    weights.safetensors  float32 state dict, hub key names, for the torch backend
    segmenter.json       the SegmenterSpec (arch, variant, input size, mean/std...) + sha256s;
                         written last, so its presence marks a complete conversion

The evaluation side runs ``model.onnx`` through :mod:`wcbench.metrics.semantic.segmenter` without torch.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import save_file
from torch import nn

from wcbench.core.storage import atomic_path, atomic_write_json, sha256_file
from wcbench.metrics.onnx_export import export_onnx
from wcbench.metrics.semantic.pytorch.checkpoints import single_source, variant_of
from wcbench.metrics.semantic.segmenter import SPEC_FILE, SegmenterSpec

__all__ = ["convert_checkpoint", "export_segmenter_onnx", "write_segmenter_dir"]


def convert_checkpoint(
    sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    out_dir: str | Path,
    entry: Any,
    input_size: tuple[int, int] | None,
    *,
    load: Callable[[Path], nn.Module],
    configs: Mapping[str, Any],
    arch: str,
    logits_stride: int,
) -> Path:
    """The model-store converters' common body: load one checkpoint, write the segmenter folder.

    ``input_size`` wins over ``entry.options["input_size"]``, which wins over 512x512; the
    variant recorded is :func:`variant_of` the loaded architecture in ``configs``.
    """
    src = single_source(sources)
    size = input_size or tuple(getattr(entry, "options", {}).get("input_size", (512, 512)))
    model = load(src)
    return write_segmenter_dir(
        model,
        out_dir,
        arch=arch,
        variant=variant_of(model.cfg, configs),
        input_size=(int(size[0]), int(size[1])),
        logits_stride=logits_stride,
        source=src,
    )


def export_segmenter_onnx(
    model: nn.Module, path: str | Path, *, input_size: tuple[int, int] = (512, 512)
) -> None:
    """Export ``model`` (pixel_values -> logits) to ONNX with dynamic batch, height and width.

    Parameters
    ----------
    model : nn.Module
        A :class:`~wcbench.metrics.semantic.pytorch.segformer.SegFormer` or
        :class:`~wcbench.metrics.semantic.pytorch.upernet_convnext.UperNetConvNext` in eval mode.
    path : str or Path
        Output ``.onnx`` file, written atomically.
    input_size : (int, int)
        (height, width) of the tracing input.
    """
    export_onnx(
        model.eval(), (torch.zeros(1, 3, *input_size),), path, input_names=["pixel_values"], output_names=["logits"],
        dynamic_axes={"pixel_values": {0: "batch", 2: "height", 3: "width"}, "logits": {0: "batch", 2: "h", 3: "w"}},
    )


def write_segmenter_dir(
    model: nn.Module,
    out_dir: str | Path,
    *,
    arch: str,
    variant: str,
    input_size: tuple[int, int],
    logits_stride: int,
    source: str | Path | None = None,
) -> Path:
    """Write a converted segmenter folder (see the module docstring) and return it.

    Parameters
    ----------
    model : nn.Module
        The loaded torch network (its ``cfg.num_labels`` gives the class count).
    out_dir : str or Path
    arch : {"segformer", "upernet-convnext"}
    variant : str
        "b0".."b5", "tiny".."xlarge" or "custom".
    input_size : (int, int)
        (height, width) the preprocessing resizes every frame to.
    logits_stride : int
        4 when the network returns stride-4 logits (SegFormer), 1 when full input size (UperNet).
    source : str or Path, optional
        The checkpoint converted from (its name and sha256 are recorded).
    """
    cfg: Any = getattr(model, "cfg", None)  # the architecture dataclass of SegFormer / UperNet-ConvNeXt
    if not dataclasses.is_dataclass(cfg) or isinstance(cfg, type) or not hasattr(cfg, "num_labels"):
        raise TypeError(f"{type(model).__name__}: expected a segmentation network with a .cfg dataclass")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    state = {
        k: v.detach().float().contiguous() for k, v in model.state_dict().items() if v.is_floating_point()
    }
    with atomic_path(out / "weights.safetensors", suffix=".safetensors") as tmp:
        save_file(state, str(tmp), metadata={"arch": arch, "variant": variant})
    export_segmenter_onnx(model, out / "model.onnx", input_size=input_size)
    spec = SegmenterSpec(
        arch=arch,
        variant=variant,
        num_classes=int(cfg.num_labels),
        input_size=(int(input_size[0]), int(input_size[1])),
        logits_stride=logits_stride,
        architecture={
            k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(cfg).items()
        },
    )
    record: dict[str, Any] = spec.to_json()
    record["files"] = {n: sha256_file(out / n) for n in ("model.onnx", "weights.safetensors")}
    if source is not None:
        src = Path(source)
        record["source"] = {"name": src.name, "sha256": sha256_file(src) if src.is_file() else None}
    atomic_write_json(out / SPEC_FILE, record)
    return out
