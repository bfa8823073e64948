"""A weather's Beer-Lambert haze inside the differentiable training render (docs/design.md §7).

At render time the physics adds each weather's haze to the decoded colors: fog, or the extinction
of rain and snow beyond the particle box, by the exact per-layer form of
:mod:`wcbench.reference_model.weather.fog`:

    I = sum_i w_i c_i t_i + c_fog (A - sum_i w_i t_i) + (1 - A) c_fog,   t_i = exp(-beta max(|mu_i - o| - d0, 0))

(the sky is at infinite distance: behind haze it is the haze colour). An edited frame already shows
its weather's haze, so a decoder fitted to it as it is learns the haze into the colors and the
renderer then adds it a second time. Training therefore composes the same haze into the render it
compares with the edited frames: the decoder learns the appearance behind the haze, and the haze is
applied once, by the physics whose settings the user controls.

Distances are taken from the detached centres: the haze shapes the colors, not the geometry (which
the raw frames, lidar depth and opacity terms fit).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from wcbench.reference_model.weather.conditions import Weather

__all__ = ["Haze", "compose_haze", "haze_transmittance", "hazy_weathers"]


@dataclass(frozen=True)
class Haze:
    """One weather's haze.

    Attributes
    ----------
    beta : float
        Extinction coefficient (m^-1); 0: no haze.
    color : tuple of 3 float
        RGB of the haze in [0, 1].
    offset_m : float
        Distance before which nothing is attenuated (m): the particle box's radius for rain and
        snow, whose particles are drawn one by one inside it.
    """

    beta: float
    color: tuple[float, float, float]
    offset_m: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.beta) and self.beta >= 0):
            raise ValueError(f"beta must be finite and >= 0, got {self.beta}")
        if not (np.isfinite(self.offset_m) and self.offset_m >= 0):
            raise ValueError(f"offset_m must be finite and >= 0, got {self.offset_m}")
        if len(self.color) != 3 or not all(0.0 <= float(c) <= 1.0 for c in self.color):
            raise ValueError(f"color must be 3 numbers in [0, 1], got {self.color!r}")

    @classmethod
    def of(cls, weather: Weather) -> Haze:
        """The haze the renderer applies under ``weather`` (:meth:`Weather.haze`)."""
        beta, color, offset = weather.haze()
        return cls(beta=float(beta), color=(float(color[0]), float(color[1]), float(color[2])),
                   offset_m=float(offset))

    def to_json(self) -> dict[str, Any]:
        """JSON-ready (a training's cache key holds it)."""
        return {"beta": self.beta, "color": list(self.color), "offset_m": self.offset_m}


def haze_transmittance(means: torch.Tensor, camera_center: torch.Tensor, hazes: Sequence[Haze]) -> torch.Tensor:
    """t_i of every Gaussian under each haze.

    Parameters
    ----------
    means : Tensor [N, 3]
        Gaussian centres, world (m); detached here.
    camera_center : Tensor [3]
        Camera centre, world (m).
    hazes : sequence of Haze (K of them)

    Returns
    -------
    Tensor [N, K]
        In [0, 1], the dtype of ``means``.
    """
    dist = (means.detach() - camera_center.to(means.dtype)).norm(dim=1, keepdim=True)  # [N, 1]
    beta = means.new_tensor([h.beta for h in hazes])  # [K]
    offset = means.new_tensor([h.offset_m for h in hazes])  # [K]
    return torch.exp(-beta * (dist - offset).clamp(min=0.0))


def compose_haze(sum_color_t: torch.Tensor, sum_t: torch.Tensor, alpha: torch.Tensor, haze: Haze) -> torch.Tensor:
    """The hazed image from the rasterized sums (beta > 0: the sky shows only haze).

    Parameters
    ----------
    sum_color_t : Tensor [H, W, 3]
        sum_i w_i c_i t_i.
    sum_t : Tensor [H, W]
        sum_i w_i t_i.
    alpha : Tensor [H, W]
        A = sum_i w_i.
    haze : Haze

    Returns
    -------
    Tensor [H, W, 3]
    """
    c_fog = sum_color_t.new_tensor(haze.color)
    # A - sum w t >= 0 exactly; clamp the float round-off as the renderer does
    fog_weight = (alpha - sum_t).clamp(min=0.0) + (1.0 - alpha)
    return sum_color_t + fog_weight[..., None] * c_fog


def hazy_weathers(weathers: Sequence[str], hazes: Mapping[str, Haze] | None) -> dict[str, Haze]:
    """The weathers of ``weathers`` with a haze of beta > 0 in ``hazes``, in order."""
    if not hazes:
        return {}
    return {w: hazes[w] for w in weathers if w in hazes and hazes[w].beta > 0}
