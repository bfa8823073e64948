"""Where a `default` training step's time goes on a device (issue 38; the workstation check's
``step_profile``, docs/workstation.md).

The per-phase profile of ``bench model`` reads the wall clock between phases, which on a GPU only
measures how long Python takes to queue the work. This builds the same training as that profile
(pandaset_002 at 480x270, filter2d supervision, the `default` settings, densification off), runs
warm-up steps, then:

1. times ``--steps`` steps between two device synchronisations (ms per step, the real rate);
2. records ``--record`` more under ``torch.profiler``, each part of the step labelled (render,
   rasterizer, decoders, sky, losses, backward, statistics, optimizer, log): per step, the host time
   of each part, the device's busy time (the sum of its kernels) and the number of kernel launches,
   and the operators that cost the most host and device time.

A step whose device busy time is far below its host time is launch-bound: fewer, larger kernels (or
CUDA graphs) are the cure, not faster kernels.

Usage: ``python tools/gpu_step_profile.py --data-root data --device cuda --out step_profile.json``
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from torch.profiler import ProfilerActivity, profile, record_function

import wcbench.reference_model.training.trainer as trainer_module
from wcbench.methods.scene_training import training_inputs
from wcbench.reference_model.training.build import build_model
from wcbench.reference_model.training.config import make_config
from wcbench.reference_model.training.trainer import Trainer
from wcbench.scenes.loaders import load_scene

#: The labelled parts of a step (host time, ms per step, in the JSON's ``parts``).
PARTS = ("render", "rasterizer", "decoders", "sky", "rgb_loss", "opacity_loss", "depth_l1", "backward",
         "accumulate", "optimizer", "log_transfer")


def _labelled(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        with record_function(name):
            return fn(*args, **kwargs)
    return wrapped


@contextlib.contextmanager
def _labels(trainer: Trainer) -> Iterator[None]:
    """Label the step's parts for the profiler (instance and module attributes, restored after)."""
    saved: list[tuple[Any, str, Any]] = []

    def patch(owner: Any, attr: str, label: str) -> None:
        saved.append((owner, attr, getattr(owner, attr)))
        setattr(owner, attr, _labelled(label, getattr(owner, attr)))

    patch(trainer.model, "render", "render")
    patch(trainer, "rasterizer", "rasterizer")
    patch(trainer.model.decoders, "forward", "decoders")
    patch(trainer.model.sky, "forward", "sky")
    for fn in ("rgb_loss", "opacity_loss", "depth_l1"):
        patch(trainer_module, fn, fn)
    patch(trainer, "_accumulate", "accumulate")
    patch(trainer.optimizer, "step", "optimizer")
    patch(torch.Tensor, "backward", "backward")
    patch(torch.Tensor, "tolist", "log_transfer")
    try:
        yield
    finally:
        for owner, attr, value in reversed(saved):
            setattr(owner, attr, value)


def _device_time(event: Any) -> float:
    """An averaged event's own device time (us); the attribute's name changed across torch releases."""
    for attr in ("self_device_time_total", "self_cuda_time_total"):
        if hasattr(event, attr):
            return float(getattr(event, attr))
    return 0.0


def main(argv: list[str] | None = None) -> int:
    """Profile the step (see the module docstring); write the JSON and print a summary."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-root", type=Path, required=True, help="folder holding pandaset_002")
    ap.add_argument("--device", default="cuda", help="cuda or cpu (default cuda)")
    ap.add_argument("--warmup", type=int, default=20, help="steps before any measurement (default 20)")
    ap.add_argument("--steps", type=int, default=100, help="steps timed between two synchronisations")
    ap.add_argument("--record", type=int, default=10, help="steps recorded by the profiler (default 10)")
    ap.add_argument("--placement", choices=("auto", "batched", "per-object"), default="auto",
                    help="how the scene graph places its objects (default auto: batched on a GPU, per object on "
                         "a CPU; batched on a CPU counts the operators it saves)")
    ap.add_argument("--out", type=Path, required=True, help="the JSON to write")
    args = ap.parse_args(argv)
    if min(args.warmup, args.steps, args.record) < 1:
        ap.error("--warmup, --steps and --record must be at least 1")
    scene_dir = args.data_root / "pandaset_002"
    if not scene_dir.is_dir():
        ap.error(f"{scene_dir}: no such folder (a PandaSet camera folder was expected)")
    cuda = args.device.startswith("cuda")

    def sync() -> None:
        if cuda:
            torch.cuda.synchronize()

    t0 = time.perf_counter()
    scene = load_scene(scene_dir, scene_id="pandaset_002")
    config = make_config("default", holdout=(5, 15, 25), checkpoint_interval=10**9, content_weight=0.0)
    inputs = training_inputs(scene, config, supervision="filter2d")
    train_views = [v for v in inputs.views if v.frame not in config.holdout]
    model, _ = build_model(scene, train_views, config, weathers=inputs.trained)
    model.batched_placement = {"auto": None, "batched": True, "per-object": False}[args.placement]
    trainer = Trainer(model, inputs.views, replace(config, densify_from=10**9), hazes=inputs.hazes,
                      device=args.device)
    prepare_s = time.perf_counter() - t0
    for _ in range(args.warmup):
        trainer.step()
    sync()
    t = time.perf_counter()
    for _ in range(args.steps):
        trainer.step()
    sync()
    ms_per_step = 1e3 * (time.perf_counter() - t) / args.steps

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    with _labels(trainer), profile(activities=activities) as prof:
        for _ in range(args.record):
            trainer.step()
        sync()
    events = prof.key_averages()
    n = args.record
    parts: dict[str, float] = {}
    for e in events:  # a label is listed twice on a GPU (its host range and a device annotation, 0 host time)
        if e.key in PARTS:
            parts[e.key] = max(parts.get(e.key, 0.0), round(e.cpu_time_total / 1e3 / n, 3))
    kernels = [e for e in events if _device_time(e) > 0 and not e.key.startswith("cuda")
               and e.key not in PARTS and not e.key.startswith("aten::")]
    busy_ms = sum(_device_time(e) for e in kernels) / 1e3 / n
    launches = sum(e.count for e in events if e.key in ("cudaLaunchKernel", "cuLaunchKernel", "cudaLaunchKernelExC"))
    by_host = sorted((e for e in events if e.key.startswith("aten::")), key=lambda e: -e.self_cpu_time_total)[:25]
    by_device = sorted(kernels, key=lambda e: -_device_time(e))[:25]
    out = {
        "device": str(trainer.device), "gpu": torch.cuda.get_device_name(0) if cuda else None,
        "torch": torch.__version__, "placement": args.placement, "gaussians": model.counts()["total"],
        "size": list(config.size_for(scene.image_size)), "prepare_s": round(prepare_s, 1), "warmup": args.warmup,
        "steps": args.steps, "recorded": n, "ms_per_step": round(ms_per_step, 3),
        "device_busy_ms_per_step": round(busy_ms, 3) if cuda else None,
        "launches_per_step": round(launches / n, 1) if cuda else None,
        # every aten call, nested ones too: on a CPU the proxy of the launches a GPU would make
        "aten_calls_per_step": round(sum(e.count for e in events if e.key.startswith("aten::")) / n, 1),
        "parts_host_ms_per_step": parts,
        "top_host_ops": [{"op": e.key, "calls_per_step": e.count / n, "self_host_ms_per_step":
                          round(e.self_cpu_time_total / 1e3 / n, 3)} for e in by_host],
        "top_kernels": [{"kernel": e.key[:120], "calls_per_step": e.count / n,
                         "device_ms_per_step": round(_device_time(e) / 1e3 / n, 3)} for e in by_device],
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(f"{out['device']}: {ms_per_step:.2f} ms per step over {args.steps} steps "
          f"({out['gaussians']} Gaussians, prepared in {prepare_s:.0f} s); device busy "
          f"{out['device_busy_ms_per_step']} ms, {out['launches_per_step']} launches, "
          f"{out['aten_calls_per_step']} aten calls per step")
    print("host ms per step by part:", json.dumps(parts))
    for row in out["top_host_ops"][:12]:
        print(f"  host {row['self_host_ms_per_step']:8.3f} ms  {row['calls_per_step']:7.1f}x  {row['op']}")
    for row in out["top_kernels"][:12]:
        print(f"  device {row['device_ms_per_step']:8.3f} ms  {row['calls_per_step']:7.1f}x  {row['kernel']}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
