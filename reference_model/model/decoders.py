"""Per-weather color decoders: Linear(F, H) - ReLU - Linear(H, 3) - Sigmoid on the shared feature.

The paper's decoder (docs/design.md §7; H = 64 in the paper, 32 in the released code). All weathers
are decoded in one batched product, so a frame's colors for every weather cost one pass over the
features. ``shared=True`` is the paper's
"w/o WGS" ablation: one decoder serves every weather, so all weathers get the same colors.

The decoders start as the identity on the first three feature channels for every weather:
colour_c = sigmoid(relu(f_c) - relu(-f_c)) = sigmoid(f_c), so features initialised to logit(colour)
render the lidar initialisation's colours exactly, and each weather starts from the clear scene.

The two layers run as one autograd node over chunks of rows (:class:`_ChunkedMLP`): the
[N, D hidden] hidden layer never exists whole and is recomputed in the backward. Memory traffic,
not arithmetic, bounds this MLP on a CPU, and chunks that stay in cache halve its time
(docs/design.md §8).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch
from torch import nn

__all__ = ["WeatherDecoders", "color_logits", "mlp_colors"]

#: Elements of a chunk's hidden layer (rows x width): 1 MiB of float32, which stays in cache. In a
#: standalone timing of 4 weathers x 114k Gaussians at 2 threads, forward + backward took 45.6 ms
#: with 1 MiB chunks, 51 ms with 4 MiB and 100 ms for the whole-array expression; `bench model`'s
#: profile shows the decoders' forward going from 17.3 to 7.5 ms (docs/design.md §8).
_CHUNK_ELEMENTS = 1 << 18


def color_logits(colors: torch.Tensor, eps: float = 1e-3) -> torch.Tensor:
    """logit of colors [N, 3] in [0, 1] (clamped to [eps, 1 - eps]): the identity decoders' input."""
    c = colors.clamp(eps, 1.0 - eps)
    return torch.log(c) - torch.log1p(-c)


class _ChunkedMLP(torch.autograd.Function):
    """sigmoid(relu(f W1^T + b1) W2^T + b2) over chunks of rows; the backward recomputes the hidden
    layer per chunk and sums the weight gradients over chunks in float64."""

    @staticmethod
    def forward(ctx: Any, features: torch.Tensor, w1: torch.Tensor, b1: torch.Tensor, w2: torch.Tensor,  # type: ignore[override]
                b2: torch.Tensor, rows: int) -> torch.Tensor:
        out = features.new_empty(features.shape[0], w2.shape[0])
        for s in range(0, features.shape[0], rows):
            h = torch.relu(torch.addmm(b1, features[s:s + rows], w1.T))
            torch.sigmoid(torch.addmm(b2, h, w2.T), out=out[s:s + rows])
        ctx.save_for_backward(features, w1, b1, w2, out)
        ctx.rows = rows
        return out

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:  # type: ignore[override]
        features, w1, b1, w2, out = ctx.saved_tensors
        rows, acc = ctx.rows, torch.float64
        g_f = torch.empty_like(features) if ctx.needs_input_grad[0] else None
        dev = w1.device
        g_w1, g_b1 = torch.zeros(w1.shape, dtype=acc, device=dev), torch.zeros(b1.shape, dtype=acc, device=dev)
        g_w2, g_b2 = torch.zeros(w2.shape, dtype=acc, device=dev), torch.zeros(w2.shape[0], dtype=acc, device=dev)
        for s in range(0, features.shape[0], rows):
            f = features[s:s + rows]
            pre = torch.addmm(b1, f, w1.T)
            h = torch.relu(pre)
            o = out[s:s + rows]
            g_z = grad[s:s + rows] * o * (1.0 - o)  # through the sigmoid
            g_w2 += (g_z.T @ h).to(acc)
            g_b2 += g_z.sum(0).to(acc)
            g_h = (g_z @ w2).mul_(pre > 0)  # through the ReLU
            g_w1 += (g_h.T @ f).to(acc)
            g_b1 += g_h.sum(0).to(acc)
            if g_f is not None:
                torch.mm(g_h, w1, out=g_f[s:s + rows])
        dt = w1.dtype
        return g_f, g_w1.to(dt), g_b1.to(dt), g_w2.to(dt), g_b2.to(dt), None


def mlp_colors(features: torch.Tensor, w1: torch.Tensor, b1: torch.Tensor, w2: torch.Tensor, b2: torch.Tensor, *,
               chunk_rows: int | None = None) -> torch.Tensor:
    """sigmoid(relu(features W1^T + b1) W2^T + b2), differentiable, in chunks of rows.

    Parameters
    ----------
    features : Tensor [N, F]
    w1 : Tensor [H, F]
    b1 : Tensor [H]
    w2 : Tensor [C, H]
    b2 : Tensor [C]
    chunk_rows : int, optional
        Rows per chunk; by default as many as make a 1 MiB float32 hidden layer.

    Returns
    -------
    Tensor [N, C]
        Equal to the plain two-layer expression (autograd's) up to float rounding; the weight
        gradients are summed over chunks in float64.
    """
    if chunk_rows is None:
        chunk_rows = max(256, _CHUNK_ELEMENTS // max(1, w1.shape[0]))
    if chunk_rows < 1:
        raise ValueError(f"chunk_rows must be positive, got {chunk_rows}")
    out: torch.Tensor = _ChunkedMLP.apply(features, w1, b1, w2, b2, chunk_rows)
    return out


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
        w1 = self.w1[idx].reshape(d * hidden, -1)  # [D*hidden, F]
        w2 = self.w2[idx[0]] if d == 1 else torch.block_diag(*[self.w2[i] for i in idx])  # [3D, D*hidden]
        return mlp_colors(features, w1, self.b1[idx].reshape(-1), w2, self.b2[idx].reshape(-1))  # [N, 3D]
