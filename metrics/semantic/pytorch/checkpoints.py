"""Reading segmentation checkpoints in the Hugging Face ``transformers`` formats (needs torch).

Shared by the architectures (:mod:`.segformer`, :mod:`.upernet_convnext`): the state dict of a
checkpoint file or ``save_pretrained`` folder, its blocks per stage, the check that it is the
expected released variant, and strict loading into our networks.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from torch import nn

__all__ = ["check_variant", "load_checked_state", "read_state_dict", "single_source", "stage_depths", "variant_of"]


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
        index = json.loads(path.read_text(encoding="utf-8"))
        weight_map = index.get("weight_map") if isinstance(index, dict) else None
        if not isinstance(weight_map, dict) or not all(isinstance(v, str) for v in weight_map.values()):
            raise ValueError(f"{path}: expected {{\"weight_map\": {{tensor name: shard file name}}}}")
        shards = sorted(set(weight_map.values()))
        out: dict[str, torch.Tensor] = {}
        for shard in shards:
            # a shard is a file beside the index: a name that leads elsewhere is refused
            target = (path.parent / shard).resolve()
            if Path(shard).name != shard or target.parent != path.parent.resolve():
                raise ValueError(f"{path}: shard {shard!r} is not a file name beside the index")
            out.update(load_file(str(target)))
        return out
    if path.suffix == ".safetensors":
        return load_file(str(path))
    # weights_only: a .bin is a pickle; refuse anything but tensors
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises a zoo of types on foreign files
        # torch's own text advises weights_only=False (arbitrary code execution): never passed on
        raise ValueError(f"{path}: not a PyTorch checkpoint wcbench reads ({type(exc).__name__}); expected "
                         "pytorch_model.bin or model.safetensors of the model's Hugging Face repository") from None
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise ValueError(f"{path}: expected a state dict, got {type(state).__name__}")
    return state


def stage_depths(keys: Collection[str], block_pattern: str) -> tuple[int, ...]:
    r"""Blocks in each of the four encoder stages, counted from a checkpoint's numbered block tensors.

    Parameters
    ----------
    keys : collection of str
        Tensor names of the checkpoint.
    block_pattern : str
        Regular expression matched at the start of a name, with ``{}`` for the stage index and one
        group capturing the block index, e.g. ``r"backbone\.encoder\.stages\.{}\.layers\.(\d+)\."``.

    Returns
    -------
    tuple of int
        One more than the largest block index of each stage; 0 for a stage without blocks.
    """
    depths = []
    for i in range(4):
        pat = re.compile(block_pattern.format(i))
        idx = {int(m.group(1)) for k in keys if (m := pat.match(k))}
        depths.append(max(idx) + 1 if idx else 0)
    return tuple(depths)


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
