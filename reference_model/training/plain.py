"""The calibration baseline of the WeatherCity training: plain optimisation of the lidar initialisation.

The static Gaussians' centres, scales, rotations, opacities and colors are fitted to the raw frames
with Adam and an L1 loss, nothing else: no densification, no decoders, no sky model (a constant
background color), no depth or opacity terms; moving objects' Gaussians are posed by their tracks
but not trained (docs/design.md §7). ``wcbench bench model`` gives it the same wall clock as the
method and compares held-out PSNR.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from wcbench.reference_model.model.decoders import color_logits
from wcbench.reference_model.raster.rasterizer import rasterize
from wcbench.reference_model.scene_graph.nodes import SceneGaussians
from wcbench.reference_model.training.trainer import evaluate_renders, scene_extent
from wcbench.reference_model.training.views import TrainingView

__all__ = ["PLAIN_LR", "PlainOptimisation"]

#: Adam learning rates (3DGS's, colors as logits); ``means`` is multiplied by the scene extent.
PLAIN_LR = {"means": 1.6e-4, "log_scales": 5e-3, "quats": 1e-3, "opacity_logits": 5e-2, "color_logits": 1e-2}


class PlainOptimisation:
    """Adam on the static Gaussians of a lidar initialisation, L1 on the raw frames.

    Parameters
    ----------
    graph : SceneGaussians
        The lidar initialisation (its static cloud is trained, its moving nodes only posed).
    views : sequence of TrainingView
        Training views (only their ``"clear"`` images are used).
    background : ndarray [3]
        Constant color behind the Gaussians (RGB in [0, 1]).
    seed : int
        Seed of the view order.
    rasterizer : callable
        ``rasterize``-compatible.
    """

    def __init__(self, graph: SceneGaussians, views: Sequence[TrainingView], *, background: np.ndarray,
                 seed: int = 0, rasterizer: Callable[..., Any] = rasterize):
        if not views:
            raise ValueError("no training view")
        self.graph, self.views, self.rasterizer = graph, list(views), rasterizer
        static = graph.static
        self.params = {
            "means": torch.nn.Parameter(torch.from_numpy(static.means.copy())),
            "log_scales": torch.nn.Parameter(torch.from_numpy(np.log(np.maximum(static.scales, 1e-6)))),
            "quats": torch.nn.Parameter(torch.from_numpy(static.quats.copy())),
            "opacity_logits": torch.nn.Parameter(torch.logit(torch.from_numpy(static.opacities).clamp(1e-4, 1 - 1e-4))),
            "color_logits": torch.nn.Parameter(color_logits(torch.from_numpy(static.colors))),
        }
        extent = scene_extent(self.views)
        self.adam = torch.optim.Adam(
            [{"params": [p], "lr": PLAIN_LR[k] * (extent if k == "means" else 1.0)} for k, p in self.params.items()],
            eps=1e-15, fused=True,
        )
        self.background = torch.as_tensor(np.asarray(background, np.float32))
        self.targets = {v.frame: torch.from_numpy(v.images["clear"]) for v in self.views}
        self.rng = np.random.default_rng(seed)
        self._order: list[int] = []
        self.step_index, self.train_seconds = 0, 0.0

    def render(self, view: TrainingView) -> torch.Tensor:
        """The clear image [H, W, 3] of ``view``'s frame (differentiable in the static Gaussians)."""
        p = self.params
        moving = [c for n in self.graph.nodes if (c := n.at_frame(view.frame)) is not None]
        means: torch.Tensor = p["means"]
        quats: torch.Tensor = p["quats"]
        scales, opac = p["log_scales"].exp(), torch.sigmoid(p["opacity_logits"])
        colors = torch.sigmoid(p["color_logits"])
        if moving:
            extra = [c.to_torch() for c in moving]
            means = torch.cat([means, *[e["means"] for e in extra]])
            quats = torch.cat([quats, *[e["quats"] for e in extra]])
            scales = torch.cat([scales, *[e["scales"] for e in extra]])
            opac = torch.cat([opac, *[e["opacities"] for e in extra]])
            colors = torch.cat([colors, *[e["colors"] for e in extra]])
        out = self.rasterizer(means, quats, scales, opac, colors,
                              torch.from_numpy(view.world_to_camera.astype(np.float32)),
                              torch.from_numpy(view.K.astype(np.float32)), view.width, view.height,
                              background=self.background, render_depth=False, absgrad=False)
        return out.color

    def step(self) -> float:
        """One Adam step on the next view (a fresh random order every epoch); returns the L1 loss."""
        start = time.perf_counter()
        if not self._order:
            self._order = list(self.rng.permutation(len(self.views)))
        v = self.views[self._order.pop()]
        loss = (self.render(v) - self.targets[v.frame]).abs().mean()
        loss.backward()
        self.adam.step()
        self.adam.zero_grad(set_to_none=True)
        self.step_index += 1
        self.train_seconds += time.perf_counter() - start
        return float(loss.detach())

    def evaluate(self, views: Sequence[TrainingView]) -> dict[str, Any]:
        """PSNR (dB) of the clear renders of ``views`` (:func:`evaluate_renders`)."""
        return evaluate_renders(self.render, views)
