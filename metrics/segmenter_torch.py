"""Torch side of the segmenters: checkpoint reading, ONNX export, a torch-backed ``segment`` callable.

Needs the ``[model]`` extra (torch). The evaluation side never imports this module: it runs the
ONNX files written by :func:`write_segmenter_dir` through :mod:`wcbench.metrics.segmenter_onnx`.

Store layout of one converted segmenter (a folder)::

    model.onnx           input "pixel_values" [B, 3, h, w] float32 (normalised), output "logits"
    weights.safetensors  float32 state dict, hub key names, for the torch backend
    segmenter.json       the SegmenterSpec (arch, variant, input size, mean/std...) + sha256s;
                         written last, so its presence marks a complete conversion
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from wcbench.storage import atomic_path, atomic_write_json, sha256_file

from .segformer import SegFormer
from .segmenter_onnx import SPEC_FILE, LogitsSegmenter, SegmenterSpec, preprocess
from .upernet_convnext import UperNetConvNext

__all__ = [
    "TorchSegmenter",
    "check_variant",
    "convert_checkpoint",
    "export_segmenter_onnx",
    "load_checked_state",
    "load_torch_segmenter",
    "read_state_dict",
    "single_source",
    "variant_of",
    "write_segmenter_dir",
]

#: ONNX opset of the exported graphs (onnxruntime >= 1.17 runs it).
ONNX_OPSET = 17


def single_source(sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]) -> Path:
    """The one checkpoint path of a converter call (the model store passes a list of one).

    Raises
    ------
    ValueError
        When a sequence does not hold exactly one path.
    """
    if isinstance(sources, (str, os.PathLike)):
        return Path(sources)
    items = list(sources)
    if len(items) != 1:
        raise ValueError(f"expected one checkpoint file, got {len(items)}: {items}")
    return Path(items[0])


def read_state_dict(path: str | Path) -> dict[str, torch.Tensor]:
    """Tensors of a ``transformers`` checkpoint (safetensors, sharded safetensors or pytorch_model.bin).

    Parameters
    ----------
    path : str or Path
        A checkpoint file, or a ``save_pretrained`` folder.

    Raises
    ------
    FileNotFoundError
        When the folder holds no known checkpoint file.
    """
    from safetensors.torch import load_file

    path = Path(path)
    if path.is_dir():
        for name in ("model.safetensors", "model.safetensors.index.json", "pytorch_model.bin"):
            if (path / name).is_file():
                path = path / name
                break
        else:
            raise FileNotFoundError(
                f"{path}: no model.safetensors, model.safetensors.index.json or pytorch_model.bin "
                "in this folder"
            )
    if path.name.endswith(".index.json"):
        shards = sorted(set(json.loads(path.read_text(encoding="utf-8"))["weight_map"].values()))
        out: dict[str, torch.Tensor] = {}
        for shard in shards:
            out.update(load_file(str(path.parent / shard)))
        return out
    if path.suffix == ".safetensors":
        return load_file(str(path))
    # weights_only: a .bin is a pickle; refuse anything but tensors
    state = torch.load(path, map_location="cpu", weights_only=True)
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise ValueError(f"{path}: expected a state dict, got {type(state).__name__}")
    return state


def check_variant(path: str | Path, cfg: Any, configs: Mapping[str, Any], variant: str, family: str) -> None:
    """Raise unless ``cfg`` has the hidden sizes and depths of ``configs[variant]``.

    Parameters
    ----------
    path : str or Path
        The checkpoint (named in the error).
    cfg
        The architecture read from the checkpoint (``hidden_sizes``, ``depths``).
    configs : mapping
        The released variants, e.g. ``SEGFORMER_CONFIGS``.
    variant : str
        The variant the caller expects.
    family : str
        Model name for the message, e.g. ``"SegFormer"``.

    Raises
    ------
    ValueError
        On a checkpoint of another variant.
    """
    want = configs[variant]
    if (want.hidden_sizes, want.depths) != (cfg.hidden_sizes, cfg.depths):
        raise ValueError(
            f"{path}: checkpoint has hidden sizes {cfg.hidden_sizes} and depths {cfg.depths}, "
            f"but {family}-{variant} has {want.hidden_sizes} and {want.depths}"
        )


def variant_of(cfg: Any, configs: Mapping[str, Any]) -> str:
    """Name of the released variant with ``cfg``'s hidden sizes and depths, else ``"custom"``."""
    key = (cfg.hidden_sizes, cfg.depths)
    return next((name for name, c in configs.items() if (c.hidden_sizes, c.depths) == key), "custom")


def load_checked_state(model: nn.Module, state: Mapping[str, torch.Tensor], path: str | Path, family: str) -> None:
    """Load ``state`` (as float32) into ``model``; every tensor must match by name, both ways.

    Raises
    ------
    ValueError
        Naming the first missing and unexpected tensors (batch-norm counters are ignored).
    """
    state = {k: v.float() for k, v in state.items() if not k.endswith("num_batches_tracked")}
    ours = {k for k in model.state_dict() if not k.endswith("num_batches_tracked")}
    missing, unexpected = sorted(ours - state.keys()), sorted(state.keys() - ours)
    if missing or unexpected:
        raise ValueError(
            f"{path}: {family} checkpoint mismatch: missing {missing[:5]}, unexpected {unexpected[:5]}"
        )
    model.load_state_dict(state, strict=False)


def convert_checkpoint(
    sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    out_dir: str | Path,
    entry: Any,
    input_size: tuple[int, int] | None,
    *,
    load: Callable[[Path], SegFormer | UperNetConvNext],
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
        A :class:`~wcbench.metrics.segformer.SegFormer` or
        :class:`~wcbench.metrics.upernet_convnext.UperNetConvNext` in eval mode.
    path : str or Path
        Output ``.onnx`` file, written atomically.
    input_size : (int, int)
        (height, width) of the tracing input.
    """
    x = torch.zeros(1, 3, *input_size)
    with atomic_path(path, suffix=".onnx") as tmp, torch.no_grad(), warnings.catch_warnings():
        # the torch.export-based exporter needs onnxscript; the TorchScript one is deprecated but complete
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        torch.onnx.export(
            model.eval(),
            (x,),
            str(tmp),
            dynamo=False,
            input_names=["pixel_values"],
            output_names=["logits"],
            dynamic_axes={
                "pixel_values": {0: "batch", 2: "height", 3: "width"},
                "logits": {0: "batch", 2: "h", 3: "w"},
            },
            opset_version=ONNX_OPSET,
        )


def write_segmenter_dir(
    model: SegFormer | UperNetConvNext,
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
    from safetensors.torch import save_file

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
        num_classes=int(model.cfg.num_labels),
        input_size=(int(input_size[0]), int(input_size[1])),
        logits_stride=logits_stride,
        architecture={
            k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(model.cfg).items()
        },
    )
    record: dict[str, Any] = spec.to_json()
    record["files"] = {n: sha256_file(out / n) for n in ("model.onnx", "weights.safetensors")}
    if source is not None:
        src = Path(source)
        record["source"] = {"name": src.name, "sha256": sha256_file(src) if src.is_file() else None}
    atomic_write_json(out / SPEC_FILE, record)
    return out


class TorchSegmenter(LogitsSegmenter):
    """``segment(images [B, H, W, 3] float in [0, 1]) -> labels [B, H, W] int64`` with a torch network.

    Same preprocessing and post-processing as
    :class:`~wcbench.metrics.segmenter_onnx.OnnxSegmenter`; only the network runs in torch.

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
        from .segformer import SegFormerConfig, load_segformer

        seg_cfg = SegFormerConfig(**arch) if arch else None
        model = load_segformer(model_dir / "weights.safetensors", config=seg_cfg)
    elif spec.arch == "upernet-convnext":
        from .upernet_convnext import UperNetConvNextConfig, load_upernet_convnext

        up_cfg = UperNetConvNextConfig(**arch) if arch else None
        model = load_upernet_convnext(model_dir / "weights.safetensors", config=up_cfg)
    else:
        raise ValueError(f"{model_dir / SPEC_FILE}: unknown segmenter arch {spec.arch!r}")
    return TorchSegmenter(model, spec, name=name)
