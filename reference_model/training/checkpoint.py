"""Checkpoints of a training: every tensor in safetensors, everything else in JSON.

A checkpoint folder holds ``checkpoint.safetensors`` (the model's parameters and buffers, Adam's
moments, the split generator's state) and ``checkpoint.json`` (node structure, settings, the
step, the view-order generator, densification statistics' sizes, the history), written in that
order, each atomically: the JSON names the sha256 of the tensors it goes with, so a torn pair is
never loaded. :func:`load_checkpoint` rebuilds the nodes at their saved sizes (densification
changed them), loads every tensor, and returns a trainer whose next step is the one an
uninterrupted training would have taken.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from wcbench.core.errors import InputError
from wcbench.core.storage import atomic_path, atomic_write_json, sha256_file
from wcbench.reference_model.model.gaussians import PARAMETER_NAMES
from wcbench.reference_model.model.scene_model import WeatherCityModel
from wcbench.reference_model.training.config import TrainConfig
from wcbench.reference_model.training.densify import DensifyStats
from wcbench.reference_model.training.trainer import StepLog, Trainer
from wcbench.reference_model.training.views import TrainingView

__all__ = ["CHECKPOINT_JSON", "CHECKPOINT_TENSORS", "load_checkpoint", "load_model", "read_checkpoint_info",
           "save_checkpoint"]

CHECKPOINT_TENSORS = "checkpoint.safetensors"
CHECKPOINT_JSON = "checkpoint.json"
FORMAT = "wcbench-weathercity-checkpoint-v1"


def save_checkpoint(trainer: Trainer, folder: str | Path, *, extra: dict[str, Any] | None = None) -> Path:
    """Write ``trainer``'s full state into ``folder`` (atomically; see the module docstring)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tensors: dict[str, torch.Tensor] = {f"model.{k}": v.detach().contiguous() for k, v in
                                        trainer.model.state_dict().items()}
    opt = trainer.optimizer.state_dict()
    groups = []
    for _i, group in enumerate(opt["param_groups"]):
        groups.append({k: v for k, v in group.items() if k != "params"} | {"params": group["params"]})
        for pid in group["params"]:
            for key, value in opt["state"].get(pid, {}).items():
                tensors[f"optim.{pid}.{key}"] = torch.as_tensor(value).detach().clone().contiguous()
    for name, st in trainer.stats.items():
        tensors[f"stats.{name}.grad"] = st.grad.contiguous()
        tensors[f"stats.{name}.count"] = st.count.contiguous()
    tensors["rng.split"] = trainer.generator.get_state().contiguous()
    for frame, holes in trainer.holes.items():  # the lidar fill's input since the last densification
        tensors[f"holes.{frame}"] = holes.to(torch.uint8).cpu().contiguous()
    target = folder / CHECKPOINT_TENSORS
    with atomic_path(target, suffix=".safetensors") as tmp:
        save_file(tensors, str(tmp))
    nodes = {name: len(p) for name, p in trainer.model.nodes().items()}
    info = {
        "format": FORMAT,
        "tensors_sha256": sha256_file(target),
        "step": trainer.step_index,
        "config": trainer.config.to_json(),
        "weathers": list(trainer.model.weathers),
        "nodes": nodes,
        "optimizer_groups": groups,
        "view_rng": _jsonable(trainer.rng.bit_generator.state),
        "view_order": [int(i) for i in trainer._order],
        "train_seconds": trainer.train_seconds,
        "history": [asdict(h) for h in trainer.history],
        "densify_log": trainer.densify_log,
        **(extra or {}),
    }
    atomic_write_json(folder / CHECKPOINT_JSON, info)
    return folder


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (np.integer,)):
        return int(obj)
    return obj


def read_checkpoint_info(folder: str | Path) -> dict[str, Any] | None:
    """The checkpoint's JSON if the folder holds a complete checkpoint, else ``None``.

    Raises
    ------
    InputError
        If the files exist but do not belong together or are not a checkpoint.
    """
    folder = Path(folder)
    js, ts = folder / CHECKPOINT_JSON, folder / CHECKPOINT_TENSORS
    if not js.is_file() or not ts.is_file():
        return None
    try:
        info = json.loads(js.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{js}: not a readable checkpoint ({exc})") from None
    if not isinstance(info, dict) or info.get("format") != FORMAT:
        raise InputError(f"{js}: not a {FORMAT} file")
    if info.get("tensors_sha256") != sha256_file(ts):
        raise InputError(f"{ts}: sha256 differs from the one {js} records (a torn or edited checkpoint)")
    return info


def load_model(folder: str | Path, *, model: WeatherCityModel) -> dict[str, Any]:
    """Restore the parameters saved by :func:`save_checkpoint` onto a freshly built ``model``, without
    the training's state (optimizer, statistics, views): a finished model to render.

    Parameters
    ----------
    folder : path-like
    model : WeatherCityModel
        Built the same way as the saved one (same scene, settings and weathers); the images it was
        built from need not carry the supervision, whose only use in the build (the sky maps' warm
        start) the saved parameters replace. Its nodes are resized to the saved counts.

    Returns
    -------
    dict
        The checkpoint's JSON (:func:`read_checkpoint_info`).

    Raises
    ------
    InputError
        If the checkpoint is missing, torn, or of another model structure.
    """
    return _load_model(Path(folder), model)[0]


def _load_model(folder: Path, model: WeatherCityModel) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
    """The checkpoint's JSON and tensors, its parameters loaded into ``model``."""
    info = read_checkpoint_info(folder)
    if info is None:
        raise InputError(f"{folder}: no complete checkpoint ({CHECKPOINT_JSON} + {CHECKPOINT_TENSORS})")
    nodes = model.nodes()
    if set(info["nodes"]) != set(nodes) or list(info["weathers"]) != list(model.weathers):
        raise InputError(f"{folder}: checkpoint of another model structure (nodes or weathers differ)")
    tensors = load_file(str(folder / CHECKPOINT_TENSORS))
    for name, params in nodes.items():
        n = int(info["nodes"][name])
        params.replace(**{k: torch.zeros((n, *getattr(params, k).shape[1:])) for k in PARAMETER_NAMES})
    state = {k[len("model."):]: v for k, v in tensors.items() if k.startswith("model.")}
    model.load_state_dict(state, strict=True)
    return info, tensors


def load_checkpoint(folder: str | Path, *, model: WeatherCityModel, views: Sequence[TrainingView],
                    make_trainer: Callable[[WeatherCityModel], Trainer]) -> Trainer:
    """Restore a training saved by :func:`save_checkpoint` onto a freshly built ``model``.

    Parameters
    ----------
    folder : path-like
    model : WeatherCityModel
        Built the same way as the saved one (same scene, settings and weathers); its nodes are
        resized to the saved counts before the tensors are loaded.
    views : sequence of TrainingView
        Unused beyond what ``make_trainer`` needs (kept for symmetry with a fresh start).
    make_trainer : callable
        ``model -> Trainer`` with the same settings as the saved training.

    Raises
    ------
    InputError
        If the checkpoint is missing, torn, or of another model structure.
    """
    folder = Path(folder)
    info, tensors = _load_model(folder, model)
    trainer = make_trainer(model)
    if TrainConfig.from_json(info["config"]) != trainer.config:
        raise InputError(f"{folder}: checkpoint of other training settings")
    opt_state: dict[str, Any] = {"state": {}, "param_groups": info["optimizer_groups"]}
    for key, value in tensors.items():
        if key.startswith("optim."):
            _, pid, name = key.split(".", 2)
            opt_state["state"].setdefault(int(pid), {})[name] = value
    trainer.optimizer.load_state_dict(opt_state)
    for name in trainer.stats:
        trainer.stats[name] = DensifyStats(tensors[f"stats.{name}.grad"], tensors[f"stats.{name}.count"])
    trainer.generator.set_state(tensors["rng.split"])
    dev = torch.device(trainer.device)
    trainer.holes = {int(k[len("holes."):]): v.to(dev).bool() for k, v in sorted(tensors.items())
                     if k.startswith("holes.")}
    trainer.rng.bit_generator.state = info["view_rng"]
    trainer._order = [int(i) for i in info["view_order"]]
    trainer.step_index = int(info["step"])
    trainer.train_seconds = float(info["train_seconds"])
    trainer.history = [StepLog(**h) for h in info["history"]]
    trainer.densify_log = list(info["densify_log"])
    return trainer
