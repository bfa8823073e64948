"""LPIPS v0.1 (Zhang et al. 2018) in torch, with its ONNX export for the torch-free scorer.

Mirrors ``lpips.LPIPS(net=..., version="0.1")`` of richzhang/PerceptualSimilarity at inference:
inputs scaled to [-1, 1], then its ScalingLayer ``(x - shift) / scale`` with shift
(-0.030, -0.088, -0.188) and scale (0.458, 0.448, 0.450); features of five ReLU layers (AlexNet
relu1..relu5, or VGG16 relu1_2, relu2_2, relu3_3, relu4_3, relu5_3); each unit-normalised over
channels (``x / (||x|| + 1e-10)``); squared difference weighted per channel by the learned
linear layer ``w_l`` (a 1x1 conv, no bias), averaged over space, summed over layers:

    LPIPS = sum_l mean_hw( sum_c w_lc (n0_lchw - n1_lchw)^2 )

Needs the ``[model]`` extra; :mod:`wcbench.metrics.perceptual.lpips` runs the exported graph (or its numpy
twin) without torch.
"""

from __future__ import annotations

import os

import torch
from torch import nn

from wcbench.core.models.vgg16 import VGG16Features, frozen_with_weights
from wcbench.metrics.onnx_export import export_onnx
from wcbench.metrics.perceptual.spec import CHANNELS, LPIPS_SCALE, LPIPS_SHIFT, NETS, NORM_EPS, VGG_LAYERS

__all__ = ["AlexNetFeatures", "LPIPSNet", "export_lpips_onnx", "load_lpips_torch"]



class AlexNetFeatures(nn.Module):
    """torchvision's ``alexnet().features`` up to relu5, returning relu1..relu5.

    Submodule names (``features.0`` ... ``features.11``) match torchvision's state dict.
    """

    def __init__(self) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, 64, 11, stride=4, padding=2), nn.ReLU(),  # 0, 1 -> relu1
            nn.MaxPool2d(3, 2),
            nn.Conv2d(64, 192, 5, padding=2), nn.ReLU(),  # 3, 4 -> relu2
            nn.MaxPool2d(3, 2),
            nn.Conv2d(192, 384, 3, padding=1), nn.ReLU(),  # 6, 7 -> relu3
            nn.Conv2d(384, 256, 3, padding=1), nn.ReLU(),  # 8, 9 -> relu4
            nn.Conv2d(256, 256, 3, padding=1), nn.ReLU(),  # 10, 11 -> relu5
        )  # fmt: skip

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """relu1..relu5 activations of ``x`` [B, 3, H, W]."""
        out = []
        for i, mod in enumerate(self.features):
            x = mod(x)
            if i in (1, 4, 7, 9, 11):
                out.append(x)
        return out


class LPIPSNet(nn.Module):
    """LPIPS v0.1 distance network.

    Parameters
    ----------
    net : {"alex", "vgg"}
    """

    shift: torch.Tensor
    scale: torch.Tensor

    def __init__(self, net: str = "alex"):
        super().__init__()
        if net not in NETS:
            raise ValueError(f"net must be 'alex' or 'vgg', got {net!r}")
        self.net_name = net
        self.net: nn.Module = (
            AlexNetFeatures() if net == "alex" else VGG16Features(VGG_LAYERS, imagenet_normalize=False)
        )
        for k, c in enumerate(CHANNELS[net]):
            self.add_module(f"lin{k}", nn.Conv2d(c, 1, 1, bias=False))
        self.register_buffer("shift", torch.tensor(LPIPS_SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(LPIPS_SCALE).view(1, 3, 1, 1), persistent=False)

    def forward(self, img0: torch.Tensor, img1: torch.Tensor) -> torch.Tensor:
        """Distances [B] between RGB ``img0`` and ``img1`` [B, 3, H, W] in [0, 1]."""
        n = img0.shape[0]
        x = (torch.cat([img0, img1]) * 2 - 1 - self.shift) / self.scale  # both images in one pass
        total = torch.zeros(n, dtype=x.dtype, device=x.device)
        for k, f in enumerate(self.net(x)):
            f = f / (torch.sqrt(torch.sum(f * f, dim=1, keepdim=True)) + NORM_EPS)
            d = (f[:n] - f[n:]) ** 2
            lin: nn.Module = getattr(self, f"lin{k}")
            total = total + lin(d).mean(dim=(1, 2, 3))
        return total


def load_lpips_torch(path: str | os.PathLike[str], *, net: str = "alex") -> LPIPSNet:
    """:class:`LPIPSNet` from a converted ``weights.safetensors`` (or its folder), eval mode, frozen.

    Also accepts the official LPIPS linear-layer names (``lin0.model.1.weight``).
    """
    from safetensors.torch import load_file

    p = os.fspath(path)
    if os.path.isdir(p):
        p = os.path.join(p, "weights.safetensors")
    model = LPIPSNet(net)
    state = {k.replace(".model.1.", "."): v for k, v in load_file(p).items()}
    state = {f"net.{k}" if k.startswith("features.") else k: v for k, v in state.items()}
    return frozen_with_weights(model, state, f"{p}: LPIPS-{net}")


def export_lpips_onnx(
    weights: str | os.PathLike[str], onnx_path: str | os.PathLike[str], *, net: str = "alex"
) -> None:
    """Export LPIPS to ONNX: inputs ``img0``, ``img1`` [B, 3, H, W] in [0, 1], output ``distance`` [B].

    Batch, height and width are dynamic (H, W >= 32 for AlexNet's strides and pools).
    """
    model = load_lpips_torch(weights, net=net)
    # two distinct tensors: the tracer would fuse one tensor passed twice into a single input
    x0, x1 = torch.rand(1, 3, 64, 64), torch.rand(1, 3, 64, 64)
    export_onnx(
        model, (x0, x1), onnx_path, input_names=["img0", "img1"], output_names=["distance"],
        dynamic_axes={n: {0: "batch", 2: "height", 3: "width"} for n in ("img0", "img1")} | {"distance": {0: "batch"}},
    )
