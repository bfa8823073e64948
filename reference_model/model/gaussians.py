"""Trainable weather Gaussians: geometry plus a shared appearance feature (torch parameters).

A Gaussian is (mu, s, r, o, f) with centre mu [3] (m), scale s [3] (m, stored as log), rotation r
[4] (w, x, y, z quaternion, any norm), opacity o in (0, 1) (stored as a logit) and the shared
feature f [F] that the weather decoders turn into colors (docs/design.md §7).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from wcbench.reference_model.model.decoders import color_logits
from wcbench.reference_model.scene_graph.gaussians import GaussianCloud

__all__ = ["PARAMETER_NAMES", "GaussianParams", "activate_opacities", "activate_scales"]

#: The per-Gaussian tensors of a node, in checkpoint and optimizer order.
PARAMETER_NAMES = ("means", "log_scales", "quats", "opacity_logits", "features")


def activate_scales(log_scales: torch.Tensor) -> torch.Tensor:
    """Standard deviations (m) of log-scales [..., 3] (elementwise: nodes may be activated together)."""
    return torch.exp(log_scales)


def activate_opacities(logits: torch.Tensor) -> torch.Tensor:
    """Opacities in (0, 1) of logits [...] (elementwise)."""
    return torch.sigmoid(logits)


class GaussianParams(nn.Module):
    """The Gaussians of one scene-graph node, as trainable tensors.

    Attributes
    ----------
    means : Parameter [N, 3]
        Centres (m) in the node's frame (world for the background, box frame for objects).
    log_scales : Parameter [N, 3]
    quats : Parameter [N, 4]
    opacity_logits : Parameter [N]
    features : Parameter [N, F]
    """

    means: nn.Parameter
    log_scales: nn.Parameter
    quats: nn.Parameter
    opacity_logits: nn.Parameter
    features: nn.Parameter

    def __init__(self, means: torch.Tensor, log_scales: torch.Tensor, quats: torch.Tensor,
                 opacity_logits: torch.Tensor, features: torch.Tensor):
        super().__init__()
        n = means.shape[0]
        shapes = {"means": (n, 3), "log_scales": (n, 3), "quats": (n, 4), "opacity_logits": (n,)}
        for name, value in zip(PARAMETER_NAMES, (means, log_scales, quats, opacity_logits, features)):
            if name in shapes and tuple(value.shape) != shapes[name]:
                raise ValueError(f"{name} must have shape {shapes[name]}, got {tuple(value.shape)}")
            setattr(self, name, nn.Parameter(value.detach().to(torch.float32).contiguous()))
        if features.ndim != 2 or features.shape[0] != n:
            raise ValueError(f"features must have shape ({n}, F), got {tuple(features.shape)}")

    @classmethod
    def from_cloud(cls, cloud: GaussianCloud, *, feature_dim: int = 32, opacity: float | None = None,
                   seed: int = 0) -> GaussianParams:
        """Trainable Gaussians from a (lidar-initialised) cloud.

        The first three feature channels are logit(color), so the identity-initialised decoders
        (:class:`~.decoders.WeatherDecoders`) reproduce the cloud's colors; the others start small
        and random, so every hidden unit of the decoders receives gradient.

        Parameters
        ----------
        cloud : GaussianCloud
        feature_dim : int
        opacity : float, optional
            Initial opacity of every Gaussian; the cloud's own when omitted.
        seed : int
        """
        n = len(cloud)
        gen = torch.Generator().manual_seed(seed)
        features = torch.randn(n, feature_dim, generator=gen) * 0.1
        features[:, :3] = color_logits(torch.from_numpy(cloud.colors))
        opac = np.full(n, opacity, np.float32) if opacity is not None else cloud.opacities
        o = torch.from_numpy(np.clip(opac, 1e-4, 1 - 1e-4).astype(np.float32))
        return cls(
            means=torch.from_numpy(cloud.means),
            log_scales=torch.log(torch.from_numpy(cloud.scales).clamp_min(1e-6)),
            quats=torch.from_numpy(cloud.quats),
            opacity_logits=torch.log(o) - torch.log1p(-o),
            features=features,
        )

    @classmethod
    def empty(cls, feature_dim: int, device: torch.device | str = "cpu") -> GaussianParams:
        """A node with no Gaussians (on ``device``)."""
        return cls(*(torch.zeros(shape, device=device) for shape in ((0, 3), (0, 3), (0, 4), (0,), (0, feature_dim))))

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def feature_dim(self) -> int:
        """Size F of the features."""
        return int(self.features.shape[1])

    def scales(self) -> torch.Tensor:
        """[N, 3] standard deviations (m)."""
        return activate_scales(self.log_scales)

    def opacities(self) -> torch.Tensor:
        """[N] opacities in (0, 1)."""
        return activate_opacities(self.opacity_logits)

    def tensors(self) -> dict[str, nn.Parameter]:
        """The parameters by name, in :data:`PARAMETER_NAMES` order."""
        return {name: getattr(self, name) for name in PARAMETER_NAMES}

    def replace(self, **values: torch.Tensor) -> None:
        """Swap in new tensors (densification, pruning); every parameter must get the same count."""
        counts = {int(v.shape[0]) for v in values.values()}
        if set(values) != set(PARAMETER_NAMES) or len(counts) != 1:
            raise ValueError(f"replace needs all of {PARAMETER_NAMES} with one count, got {sorted(values)}")
        for name, value in values.items():
            setattr(self, name, nn.Parameter(value.detach().contiguous()))

    @staticmethod
    def opacity_logit(opacity: float) -> float:
        """logit of an opacity in (0, 1)."""
        return math.log(opacity / (1.0 - opacity))
