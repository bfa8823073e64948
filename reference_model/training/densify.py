"""Adaptive density control driven by the absolute 2D gradient (AbsGS), under a Gaussian budget.

After every step the rasterizer's ``means2d_abs.grad`` (the sum of |dL/dmu_2d| over a Gaussian's
pixels, the AbsGS statistic: it does not cancel where a Gaussian is pulled both ways) is
accumulated per Gaussian over the steps where it is visible. Every ``densify_interval`` steps:

- Gaussians whose mean statistic exceeds ``densify_grad`` are **cloned** (small ones: a copy at the
  same place) or **split** (larger than ``split_scale`` x the scene extent: two Gaussians sampled
  from the original, scales / 1.6), the largest statistics first while the budget allows;
- Gaussians with opacity below ``prune_opacity`` or wider than ``max_scale_m`` (the trainer: 0.3 x the scene extent) are
  **pruned**.

The optimizer's moments follow every change (kept rows keep theirs, new rows start at zero), as
in 3D Gaussian Splatting. Non-rigid nodes keep their Gaussians (their per-frame offsets are sized
to them).

The **lidar fill** (:func:`fill_from_lidar`, ``TrainConfig.lidar_fill``) adds Gaussians where the
gradient cannot: a pixel a trusted static lidar return lands in that the render leaves below half
opacity has no Gaussian worth cloning near it (a wire a pixel wide, a return in a gap), so one is
placed at the return itself (docs/design.md §7, "Beyond the lidar").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch.optim.adam import adam

from wcbench.reference_model.model.gaussians import PARAMETER_NAMES, GaussianParams
from wcbench.reference_model.model.objects import quat_multiply_torch
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud

__all__ = ["FILL_OPACITY", "DensifyStats", "NodeOptimizer", "append_gaussians", "densify_and_prune",
           "fill_from_lidar"]


class NodeOptimizer:
    """Adam over named parameter groups whose tensors can be replaced (densification).

    Parameters
    ----------
    groups : list of (name, Parameter, lr)
    """

    def __init__(self, groups: list[tuple[str, torch.nn.Parameter, float]]):
        # fused: one kernel over every tensor per step instead of a Python loop of small ops
        self.adam = torch.optim.Adam([{"params": [p], "lr": lr, "name": name} for name, p, lr in groups],
                                     eps=1e-15, fused=True)

    def zero_grad(self) -> None:
        """Clear every gradient (set to None)."""
        self.adam.zero_grad(set_to_none=True)

    @torch.no_grad()
    def step(self) -> None:
        """One Adam step: torch's fused Adam, one call per learning rate instead of one per group.

        With a group per named tensor (about 140 with a few dozen objects) ``Adam.step`` pays
        Python and a kernel launch per group; the groups that share a rate share a call here (the
        optimizer phase of a training step: 6.0 -> 4.2-4.6 ms at 2 threads; what remains is memory
        bandwidth, docs/design.md §8). The state (``step``, ``exp_avg``, ``exp_avg_sq`` per tensor, as ``Adam``'s
        own fused path creates it) stays in ``self.adam.state``, so checkpoints are unchanged,
        and the per-tensor arithmetic is the same kernel's: results are bit-identical.
        """
        batches: dict[tuple, tuple[list[torch.Tensor], ...]] = {}
        for g in self.adam.param_groups:
            for p in g["params"]:
                if p.grad is None:
                    continue
                state = self.adam.state[p]
                if not state:
                    state["step"] = torch.zeros((), dtype=torch.float32, device=p.device)
                    state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                    state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                key = (g["lr"], tuple(g["betas"]), g["eps"], g["weight_decay"])  # betas: a list once loaded
                lists = batches.setdefault(key, ([], [], [], [], []))
                for out, t in zip(lists, (p, p.grad, state["exp_avg"], state["exp_avg_sq"], state["step"])):
                    out.append(t)
        for (lr, (beta1, beta2), eps, weight_decay), (params, grads, avgs, avg_sqs, steps) in batches.items():
            adam(params, grads, avgs, avg_sqs, [], steps, fused=True, lr=lr, beta1=beta1, beta2=beta2,
                 eps=eps, weight_decay=weight_decay, amsgrad=False, maximize=False)

    def group(self, name: str) -> dict:
        """The parameter group called ``name``."""
        for g in self.adam.param_groups:
            if g["name"] == name:
                return g
        raise KeyError(name)

    def replace(self, name: str, new: torch.nn.Parameter, index: torch.Tensor) -> None:
        """Swap the group's tensor for ``new``, whose row r was old row ``index[r]`` (-1: a new row).

        Adam's moments are gathered the same way (zeros for new rows).
        """
        g = self.group(name)
        old = g["params"][0]
        state = self.adam.state.pop(old, None)
        g["params"][0] = new
        if state is None:
            return
        keep = index >= 0
        for key in ("exp_avg", "exp_avg_sq"):
            m = state[key]
            out = torch.zeros((len(index), *m.shape[1:]), dtype=m.dtype, device=m.device)
            out[keep] = m[index[keep]]
            state[key] = out
        self.adam.state[new] = state

    def state_dict(self) -> dict:
        """Adam's state (for checkpoints)."""
        return self.adam.state_dict()

    def load_state_dict(self, state: dict) -> None:
        """Restore :meth:`state_dict`."""
        self.adam.load_state_dict(state)


@dataclass
class DensifyStats:
    """Accumulated AbsGS statistics of one node's Gaussians."""

    grad: torch.Tensor = field(default_factory=lambda: torch.zeros(0))
    count: torch.Tensor = field(default_factory=lambda: torch.zeros(0))

    def ensure(self, n: int, *, device: torch.device | str | None = None) -> None:
        """Reset to ``n`` Gaussians (on ``device``, default where they are) if the size changed; move them
        to ``device`` if only that changed."""
        dev = self.grad.device if device is None else torch.device(device)
        if len(self.grad) != n:
            self.grad, self.count = torch.zeros(n, device=dev), torch.zeros(n, device=dev)
        elif self.grad.device != dev:  # a checkpoint's statistics, loaded on the CPU, resumed on a GPU
            self.grad, self.count = self.grad.to(dev), self.count.to(dev)

    def add_masked(self, masked_grad: torch.Tensor, visible: torch.Tensor) -> None:
        """Accumulate one step's |grad| [N], already zero where a Gaussian was not visible, and the
        visibility [N] as 0 / 1 in the statistics' dtype. The trainer masks a frame's rows once for
        every node (dense masked adds, not boolean indexing: no gather or scatter per node and step,
        and the same sums, x + 0 being x for the non-negative statistics), leaving two in-place adds
        per node (on a GPU a step is bound by its launches)."""
        self.grad += masked_grad
        self.count += visible

    def mean(self) -> torch.Tensor:
        """[N] mean statistic over the steps each Gaussian was visible (0 if never)."""
        return self.grad / self.count.clamp_min(1)


def _split_samples(params: GaussianParams, idx: torch.Tensor, generator: torch.Generator) -> dict[str, torch.Tensor]:
    """Two children per split Gaussian: positions sampled from it, scales / 1.6 (3DGS)."""
    scales = params.scales()[idx].detach()
    q = params.quats[idx].detach()
    q = q / q.norm(dim=1, keepdim=True).clamp_min(1e-12)
    # drawn on the CPU generator whatever the device: the same draws on every device
    samples = torch.randn((2, len(idx), 3), generator=generator).to(scales.device) * scales
    # rotate the local samples: v' = q v q*
    zero = torch.zeros((2, len(idx), 1), device=scales.device)
    v = torch.cat([zero, samples], -1)
    conj = q * torch.tensor([1.0, -1.0, -1.0, -1.0], device=q.device)
    rotated = quat_multiply_torch(quat_multiply_torch(q.expand(2, -1, -1), v), conj.expand(2, -1, -1))[..., 1:]
    means = (params.means[idx].detach() + rotated).reshape(-1, 3)
    return {
        "means": means,
        "log_scales": (params.log_scales[idx].detach() - torch.log(torch.tensor(1.6))).repeat(2, 1),
        "quats": params.quats[idx].detach().repeat(2, 1),
        "opacity_logits": params.opacity_logits[idx].detach().repeat(2),
        "features": params.features[idx].detach().repeat(2, 1),
    }


def densify_and_prune(
    name: str,
    params: GaussianParams,
    stats: DensifyStats,
    optimizer: NodeOptimizer,
    *,
    grad_threshold: float,
    split_scale_m: float,
    max_scale_m: float,
    prune_opacity: float,
    room: int,
    generator: torch.Generator,
) -> dict[str, int]:
    """Clone, split and prune one node's Gaussians (see the module docstring).

    Parameters
    ----------
    name : str
        The node's key: its optimizer groups are ``<name>.<parameter>``.
    params : GaussianParams
    stats : DensifyStats
    optimizer : NodeOptimizer
    grad_threshold : float
    split_scale_m, max_scale_m : float
        Clone below / split above ``split_scale_m``; prune wider than ``max_scale_m`` (m).
    prune_opacity : float
    room : int
        How many Gaussians this node may add (the budget left).
    generator : torch.Generator
        Draws the split children (deterministic under the training seed).

    Returns
    -------
    dict
        Counts ``cloned``, ``split``, ``pruned``.
    """
    n = len(params)
    if n == 0:
        return {"cloned": 0, "split": 0, "pruned": 0}
    stats.ensure(n, device=params.means.device)
    score = stats.mean()
    big = params.scales().detach().max(dim=1).values > split_scale_m
    candidates = torch.nonzero(score > grad_threshold).flatten()
    # largest statistic first; a split adds one Gaussian net (two children replace one), a clone one
    candidates = candidates[torch.argsort(score[candidates], descending=True)][: max(room, 0)]
    split_idx = candidates[big[candidates]]
    clone_idx = candidates[~big[candidates]]
    old = {k: v.detach() for k, v in params.tensors().items()}
    children = _split_samples(params, split_idx, generator) if len(split_idx) else None
    keep = torch.ones(n, dtype=torch.bool, device=params.means.device)
    keep[split_idx] = False  # split parents are replaced by their children
    opac = torch.sigmoid(old["opacity_logits"])
    scale_max = torch.exp(old["log_scales"]).max(dim=1).values
    prune = (opac < prune_opacity) | (scale_max > max_scale_m)
    keep &= ~prune
    kept = torch.nonzero(keep).flatten()
    index = torch.cat([kept, clone_idx, torch.full((2 * len(split_idx),), -1, dtype=torch.long,
                                                      device=kept.device)])
    new_values = {}
    for key in PARAMETER_NAMES:
        parts = [old[key][kept], old[key][clone_idx]]
        if children is not None:
            parts.append(children[key])
        new_values[key] = torch.cat(parts)
    params.replace(**new_values)
    for key in PARAMETER_NAMES:
        optimizer.replace(f"{name}.{key}", getattr(params, key), index)
    stats.ensure(len(params), device=params.means.device)
    return {"cloned": len(clone_idx), "split": len(split_idx), "pruned": int(prune.sum())}


#: Opacity of a lidar fill Gaussian: alone it takes its pixel past half (the sky threshold).
FILL_OPACITY = 0.6


def fill_from_lidar(holes: np.ndarray, anchor_depth: np.ndarray, K: np.ndarray, camera_to_world: np.ndarray,
                    image: np.ndarray) -> GaussianCloud:
    """Gaussians at the lidar returns of a view's uncovered pixels.

    Each pixel of ``holes`` with an anchor (``anchor_depth`` > 0) gets an isotropic Gaussian at its
    centre's ray at the anchor's depth (so it projects back to that pixel's centre), half a pixel's
    footprint wide, of opacity :data:`FILL_OPACITY` and the image's colour there.

    Parameters
    ----------
    holes : ndarray [H, W] bool
        Pixels to fill (the trainer: a trusted return there, the render below half opacity).
    anchor_depth : ndarray [H, W] float
        Camera z (m) of the nearest static trusted return per pixel, 0 where none.
    K : ndarray [3, 3]
        Intrinsics at the view's size (pixel centres at +0.5).
    camera_to_world : ndarray [4, 4]
        OpenCV camera (x right, y down, z forward) to world.
    image : ndarray [H, W, 3] float
        The raw frame in [0, 1].

    Returns
    -------
    GaussianCloud
        World means [N, 3] (m), one per filled pixel in row-major order.
    """
    if holes.shape != anchor_depth.shape or image.shape[:2] != holes.shape:
        raise ValueError(f"holes {holes.shape}, anchor_depth {anchor_depth.shape} and image {image.shape[:2]} "
                         "must be the same [H, W]")
    rows, cols = np.nonzero(holes & (anchor_depth > 0))
    z = anchor_depth[rows, cols].astype(np.float64)
    K = np.asarray(K, np.float64)
    x = (cols + 0.5 - K[0, 2]) / K[0, 0] * z
    y = (rows + 0.5 - K[1, 2]) / K[1, 1] * z
    c2w = np.asarray(camera_to_world, np.float64)
    means = np.stack([x, y, z], 1) @ c2w[:3, :3].T + c2w[:3, 3]
    return GaussianCloud.isotropic(means, 0.5 * z / K[0, 0], image[rows, cols], FILL_OPACITY)


def append_gaussians(name: str, params: GaussianParams, optimizer: NodeOptimizer, new: GaussianParams) -> int:
    """Append ``new``'s Gaussians to node ``name``'s ``params``, their Adam moments starting at zero;
    returns how many."""
    n = len(params)
    dev = params.means.device
    params.replace(**{k: torch.cat([getattr(params, k).detach(), getattr(new, k).detach().to(dev)])
                      for k in PARAMETER_NAMES})
    index = torch.cat([torch.arange(n, device=dev), torch.full((len(new),), -1, dtype=torch.long, device=dev)])
    for key in PARAMETER_NAMES:
        optimizer.replace(f"{name}.{key}", getattr(params, key), index)
    return len(new)
