"""Per-weather color decoders: Linear(F, H) - ReLU - Linear(H, 3) - Sigmoid on the shared feature.

The paper's decoder (docs/design.md §7; H = 64 in the paper, 32 in the released code). All weathers
are decoded in one batched product, so a frame's colors for every weather cost one pass over the
features. ``shared=True`` is the paper's
"w/o WGS" ablation: one decoder serves every weather, so all weathers get the same colors.

The decoders start as the identity on the first three feature channels for every weather:
colour_c = sigmoid(relu(f_c) - relu(-f_c)) = sigmoid(f_c), so features initialised to logit(colour)
render the lidar initialisation's colours exactly, and each weather starts from the clear scene.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["WeatherDecoders", "color_logits"]


def color_logits(colors: torch.Tensor, eps: float = 1e-3) -> torch.Tensor:
    """logit of colors [N, 3] in [0, 1] (clamped to [eps, 1 - eps]): the identity decoders' input."""
    c = colors.clamp(eps, 1.0 - eps)
    return torch.log(c) - torch.log1p(-c)


class WeatherDecoders(nn.Module):
    """One MLP per weather, evaluated together.

    Parameters
    ----------
    weathers : sequence of str
        Weather names, ``"clear"`` included (the raw scene).
    feature_dim : int
        Size F of the shared feature (32 in the paper).
    hidden : int
        Hidden width H (64 in the paper; the released code and the training default use 32).
    shared : bool
        One decoder for every weather (the "w/o WGS" ablation).
    seed : int
        Seed of the small random part of the initialisation.
    """

    def __init__(self, weathers: Sequence[str], *, feature_dim: int = 32, hidden: int = 32, shared: bool = False,
                 seed: int = 0):
        super().__init__()
        if feature_dim < 3 or hidden < 6:
            raise ValueError(f"need feature_dim >= 3 and hidden >= 6, got {feature_dim}, {hidden}")
        if len(set(weathers)) != len(weathers) or not weathers:
            raise ValueError(f"weathers must be distinct and non-empty, got {list(weathers)}")
        self.weathers = tuple(weathers)
        self.shared = shared
        self.feature_dim, self.hidden = feature_dim, hidden
        n = 1 if shared else len(self.weathers)
        gen = torch.Generator().manual_seed(seed)
        w1 = torch.randn(n, hidden, feature_dim, generator=gen) * (0.1 / math.sqrt(feature_dim))
        w2 = torch.randn(n, 3, hidden, generator=gen) * (0.01 / math.sqrt(hidden))
        eye = torch.eye(3)
        w1[:, :3, :3], w1[:, 3:6, :3] = eye, -eye
        w1[:, :6, 3:] = 0.0  # the identity units read the colour channels only
        w2[:, :, :6] = 0.0
        w2[:, :, :3] += eye
        w2[:, :, 3:6] -= eye
        self.w1 = nn.Parameter(w1)  # [D, hidden, F]
        self.b1 = nn.Parameter(torch.zeros(n, hidden))
        self.w2 = nn.Parameter(w2)  # [D, 3, hidden]
        self.b2 = nn.Parameter(torch.zeros(n, 3))

    def index(self, weathers: Sequence[str]) -> list[int]:
        """Decoder index of each weather (all 0 when shared).

        Raises
        ------
        KeyError
            Naming a weather these decoders were not built for.
        """
        unknown = [w for w in weathers if w not in self.weathers]
        if unknown:
            raise KeyError(f"no decoder for weathers {unknown}; decoders: {list(self.weathers)}")
        return [0 if self.shared else self.weathers.index(w) for w in weathers]

    def forward(self, features: torch.Tensor, weathers: Sequence[str]) -> torch.Tensor:
        """Colors of every Gaussian under every weather.

        Parameters
        ----------
        features : Tensor [N, F]
        weathers : sequence of str
            Weathers to decode, in the order of the output's channel groups.

        Returns
        -------
        Tensor [N, 3 len(weathers)]
            RGB in (0, 1), weather-major: channels 3k..3k+2 are weather k.
        """
        idx = self.index(weathers)
        if self.shared and len(idx) > 1:
            # one decoder: decode once and repeat, so every weather gets bit-identical colors
            # (a block-diagonal product of equal blocks may round differently per block)
            return self.forward(features, weathers[:1]).repeat(1, len(idx))
        d, hidden = len(idx), self.hidden
        # one GEMM for every weather's first layer; the second layer as one GEMM with a
        # block-diagonal matrix: forward + backward of 4 weathers x 174k Gaussians take 351-380 ms
        # against 632-664 ms with a batched product of 3 outputs (2-core CPU)
        w1 = self.w1[idx].reshape(d * hidden, -1)
        h = torch.relu(torch.addmm(self.b1[idx].reshape(-1), features, w1.T))  # [N, D*hidden]
        w2 = self.w2[idx[0]] if d == 1 else torch.block_diag(*[self.w2[i] for i in idx])  # [3D, D*hidden]
        return torch.sigmoid(torch.addmm(self.b2[idx].reshape(-1), h, w2.T))  # [N, 3D], weather-major
