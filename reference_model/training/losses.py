"""The training losses of multi-weather optimisation (docs/design.md §7), in torch.

- RGB: (1 - lambda) L1 + lambda (1 - SSIM), lambda = 0.2, on the raw frame and every edited one.
  SSIM here is the **3DGS training SSIM**: Gaussian 11x11 window, sigma 1.5, *zero padding*, mean
  over all pixels and channels. It is not the evaluation SSIM of ``wcbench.metrics`` (valid
  region, float64, equal to scikit-image), and its numbers differ near the borders. float32
  images take the fused numba kernels (:mod:`.ssim_kernels`); :func:`training_ssim_torch` is
  their twin, and what float64 (``gradcheck``) and a target that needs a gradient take.
- Content: L1 between VGG16 features of each weather's render and of the raw frame, sky masked out
  (the paper uses VGG-19, which no registry ships; docs/design.md §6).
- Depth: L1 between the expected depth and the lidar depth where a return landed.
- Opacity: -sum O log O - sum M_sky log(1 - O) (paper, supplement), per pixel mean; here also the
  non-sky and the lidar-hit pixels pulled toward O = 1 (:func:`opacity_loss`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from wcbench.reference_model._numba_backend import load_numba_kernels, numba_error

__all__ = [
    "LIDAR_OPAQUE",
    "ContentLoss",
    "depth_l1",
    "opacity_loss",
    "psnr",
    "psnr_from_mse",
    "rgb_loss",
    "training_ssim",
    "training_ssim_torch",
]

_SSIM_SIGMA, _SSIM_SIZE = 1.5, 11
_C1, _C2 = 0.01**2, 0.03**2
_EPS = 1e-6


def _gaussian_taps(dtype: torch.dtype, device: torch.device | str = "cpu") -> torch.Tensor:
    x = torch.arange(_SSIM_SIZE, dtype=dtype, device=device) - _SSIM_SIZE // 2
    g = torch.exp(-(x**2) / (2 * _SSIM_SIGMA**2))
    return g / g.sum()


class _FusedSSIM(torch.autograd.Function):
    """:func:`training_ssim` through the fused kernels; gradient to ``a`` only."""

    @staticmethod
    def forward(ctx: Any, a: torch.Tensor, b: torch.Tensor, kernels: Any) -> torch.Tensor:  # type: ignore[override]
        x = np.ascontiguousarray(a.detach().permute(2, 0, 1).numpy())
        y = np.ascontiguousarray(b.detach().permute(2, 0, 1).numpy())
        taps = _gaussian_taps(torch.float32).numpy()
        sums, d_mu, d_xx, d_xy = kernels.ssim_forward(x, y, taps, _C1, _C2)
        ctx.saved = (kernels, x, y, taps, d_mu, d_xx, d_xy)
        return torch.from_numpy((sums / (x.shape[1] * x.shape[2])).astype(np.float32))

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, None, None]:  # type: ignore[override]
        kernels, x, y, taps, d_mu, d_xx, d_xy = ctx.saved
        scale = grad.detach().to(torch.float64).numpy() / (x.shape[1] * x.shape[2])
        dx = kernels.ssim_backward(x, y, taps, d_mu, d_xx, d_xy, scale)
        return torch.from_numpy(dx).permute(1, 2, 0), None, None


def training_ssim(a: torch.Tensor, b: torch.Tensor, *, backend: str = "auto") -> torch.Tensor:
    """3DGS training SSIM per channel of images [H, W, C] in [0, 1]: a tensor [C] (zero-padded window).

    Parameters
    ----------
    a, b : Tensor [H, W, C]
        Same shape; C may stack several RGB images. Gradients flow to ``a``.
    backend : {"auto", "numba", "torch"}, keyword-only
        ``"auto"``: the fused numba kernels (:mod:`.ssim_kernels`) for float32 images when ``b``
        needs no gradient and numba imports, else :func:`training_ssim_torch` (the twin).

    Raises
    ------
    ValueError
        An unknown ``backend``; ``"numba"`` for inputs it cannot take or without numba.
    """
    if backend not in ("auto", "numba", "torch"):
        raise ValueError(f"backend must be 'auto', 'numba' or 'torch', got {backend!r}")
    if a.shape != b.shape or a.dim() != 3:
        raise ValueError(f"training_ssim takes two [H, W, C] images of one shape, got {tuple(a.shape)} and "
                         f"{tuple(b.shape)}")
    # the fused kernels run on CPU tensors; on a GPU the twin (docs/workstation.md)
    fits = a.dtype == torch.float32 and b.dtype == torch.float32 and not b.requires_grad and a.device.type == "cpu"
    if backend == "torch" or (backend == "auto" and not fits):
        return training_ssim_torch(a, b)
    if not fits:
        raise ValueError(f"the numba SSIM takes float32 images and a target without gradient, got {a.dtype} and "
                         f"{b.dtype}, target requires_grad={b.requires_grad}; use backend='torch'")
    kernels = load_numba_kernels("training.ssim_kernels")
    if backend == "numba" and kernels is None:
        raise ValueError(f"the numba SSIM kernels are unavailable ({numba_error('training.ssim_kernels')}); "
                         "use backend='torch'")
    if kernels is None:
        return training_ssim_torch(a, b)
    return _FusedSSIM.apply(a, b, kernels)


def training_ssim_torch(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """3DGS training SSIM per channel of images [H, W, C] in [0, 1]: a tensor [C] (zero-padded window);
    the pure-torch twin of the fused kernels, differentiable by autograd in any float dtype.

    The 11x11 Gaussian window is applied as two 1D passes (it is separable): the same numbers as the
    2D window up to float rounding, at 2 x 11 instead of 121 taps per pixel.

    Parameters
    ----------
    a, b : Tensor [H, W, C]
        Same shape; C may stack several RGB images.
    """
    c = a.shape[-1]
    x, y = a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]
    g = _gaussian_taps(a.dtype, a.device)  # on the images' device (a GPU's twin, docs/workstation.md)
    row = g.view(1, 1, 1, -1).expand(5 * c, 1, 1, _SSIM_SIZE)
    col = g.view(1, 1, -1, 1).expand(5 * c, 1, _SSIM_SIZE, 1)
    pad = _SSIM_SIZE // 2
    # the five blurred maps in one grouped convolution: x, y, x^2, y^2, x y
    stack = torch.cat([x, y, x * x, y * y, x * y], 1)
    blurred = F.conv2d(F.conv2d(stack, row, padding=(0, pad), groups=5 * c), col, padding=(pad, 0), groups=5 * c)
    mx, my, exx, eyy, exy = blurred.split(c, dim=1)
    vx, vy, cxy = exx - mx * mx, eyy - my * my, exy - mx * my
    s = ((2 * mx * my + _C1) * (2 * cxy + _C2)) / ((mx * mx + my * my + _C1) * (vx + vy + _C2))
    return s.mean(dim=(0, 2, 3))


def rgb_loss(render: torch.Tensor, target: torch.Tensor, *, ssim_weight: float = 0.2) -> torch.Tensor:
    """(1 - w) L1 + w (1 - SSIM) per RGB image of stacked images [H, W, 3k]: a tensor [k]."""
    k = render.shape[-1] // 3
    l1 = (render - target).abs().mean(dim=(0, 1)).view(k, 3).mean(1)
    if ssim_weight == 0:
        return l1
    ssim = training_ssim(render, target).view(k, 3).mean(1)
    return (1 - ssim_weight) * l1 + ssim_weight * (1 - ssim)


def depth_l1(depth: torch.Tensor, lidar: torch.Tensor) -> torch.Tensor:
    """Mean |depth - lidar| (m) over pixels with a lidar return (``lidar > 0``); 0 when none."""
    valid = lidar > 0
    if not bool(valid.any()):
        return depth.new_zeros(())
    return (depth[valid] - lidar[valid]).abs().mean()


#: Accumulated opacity above which the lidar term of :func:`opacity_loss` no longer pulls a pixel.
LIDAR_OPAQUE = 0.9


def opacity_loss(alpha: torch.Tensor, sky: torch.Tensor | None, *, solid: bool = False,
                 lidar: torch.Tensor | None = None, lidar_weight: float = 0.0,
                 sky_weight: float = 1.0) -> torch.Tensor:
    """-mean(O log O) - ``sky_weight`` mean(M_sky log(1 - O)) of the accumulated opacity O [H, W]
    (the paper's, with ``sky_weight`` 1), with ``solid`` also -mean((1 - M_sky) log O): the
    Gaussians cover every pixel that is not sky, and with ``lidar`` also -``lidar_weight``
    mean(M_lidar log O): the pixels a lidar return lands in are pulled harder, up to
    :data:`LIDAR_OPAQUE`.

    The paper's two terms leave a non-sky pixel free to be drawn by the sky map; under an edited
    weather's haze the sky is not seen (it lies at infinity), so such a pixel would show the
    airlight instead of the structure (``TrainConfig.opacity_solid``). On a thin structure against
    the sky (a wire, a mast, a sign's edge: a pixel or two wide) the plain pull loses to the sky
    term of the pixels on either side and the sky map draws it; a lidar return there says the pixel
    is solid for certain (``TrainConfig.opacity_lidar``, docs/findings.md).

    Parameters
    ----------
    alpha : Tensor [H, W]
        Accumulated opacity of the Gaussians, in [0, 1].
    sky : Tensor [H, W] bool or None
        Sky pixels (None: the entropy term alone).
    solid : bool
        Pull every non-sky pixel toward opacity 1.
    lidar : Tensor [H, W] bool, optional
        Pixels a lidar return lands in.
    lidar_weight : float
        Weight of their pull (relative to the other terms' 1); >= 0.
    sky_weight : float
        Weight of the sky pixels' push toward 0 (1: the paper's); >= 0.

    Returns
    -------
    Tensor []
    """
    o = alpha.clamp(_EPS, 1 - _EPS)
    entropy = -(o * torch.log(o)).mean()
    out = entropy
    if sky is not None:
        m = sky.to(o.dtype)
        out = out - sky_weight * (m * torch.log(1 - o)).mean()
        if solid:
            out = out - ((1.0 - m) * torch.log(o)).mean()
    if lidar is not None and lidar_weight > 0:
        # a hinge: a pixel this opaque is solid already (sky would be below 0.5); the broad surfaces
        # the lidar covers are left to the colour fit
        held = o.clamp(max=LIDAR_OPAQUE)
        out = out - lidar_weight * (lidar.to(o.dtype) * torch.log(held)).mean()
    return out


class ContentLoss(nn.Module):
    """L1 between VGG16 features of renders and of the raw frame, sky masked out.

    Parameters
    ----------
    features : nn.Module
        ``x [B, 3, h, w] in [0, 1] -> list of feature maps`` (the VGG16 features of
        :mod:`wcbench.core.models.vgg16`, frozen), or any stand-in with that signature.
    size : (int, int)
        (width, height) the images are resized to first: the loss is the costliest term on a
        CPU, so it runs at reduced resolution.
    """

    def __init__(self, features: nn.Module, *, size: tuple[int, int]):
        super().__init__()
        self.features = features.eval()
        for p in self.features.parameters():
            p.requires_grad_(False)
        self.size = (int(size[0]), int(size[1]))
        self._raw_cache: dict[int, list[torch.Tensor]] = {}

    def _prep(self, images: torch.Tensor) -> torch.Tensor:
        x = images.permute(2, 0, 1)  # [3k, H, W]
        x = x.reshape(-1, 3, *x.shape[1:])
        return F.interpolate(x, size=(self.size[1], self.size[0]), mode="bilinear", align_corners=False,
                             antialias=True)

    def raw_features(self, key: int, raw: torch.Tensor) -> list[torch.Tensor]:
        """Features of a raw frame [H, W, 3], computed once per ``key`` (the frame)."""
        if key not in self._raw_cache:
            with torch.no_grad():
                self._raw_cache[key] = [f.detach() for f in self.features(self._prep(raw))]
        return self._raw_cache[key]

    def forward(self, renders: torch.Tensor, raw_key: int, raw: torch.Tensor,
                non_sky: torch.Tensor | None) -> torch.Tensor:
        """Mean over weathers of the masked L1 feature distance.

        Parameters
        ----------
        renders : Tensor [H, W, 3k]
            The renders of k weathers (not the clear one).
        raw_key : int
            Identifies ``raw`` for the feature cache.
        raw : Tensor [H, W, 3]
        non_sky : Tensor [H, W] bool, optional
            Where the loss applies (the sky is masked out).
        """
        target = self.raw_features(raw_key, raw)
        feats = self.features(self._prep(renders))
        total = renders.new_zeros(())
        for f, t in zip(feats, target):
            diff = (f - t).abs().mean(1, keepdim=True)  # [k, 1, h, w]
            if non_sky is not None:
                m = F.interpolate(non_sky[None, None].to(f.dtype), size=f.shape[-2:], mode="area")
                total = total + (diff * m).sum() / (m.sum() * f.shape[0]).clamp_min(1.0)
            else:
                total = total + diff.mean()
        return total / max(len(feats), 1)


def psnr(render: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """PSNR (dB) of RGB in [0, 1] over all pixels, or over ``mask`` [H, W] (``nan`` if empty)."""
    d = (render - target).double() ** 2
    if mask is not None:
        if not bool(mask.any()):
            return float("nan")
        d = d[mask]
    return psnr_from_mse(float(d.mean()))


def psnr_from_mse(mse: float) -> float:
    """PSNR (dB) of a mean squared error of values in [0, 1]; ``inf`` for 0."""
    return 10.0 * math.log10(1.0 / mse) if mse > 0 else float("inf")


def weighted_sum(terms: Sequence[tuple[float, torch.Tensor]]) -> torch.Tensor:
    """sum of weight * term, skipping zero weights."""
    out = None
    for w, t in terms:
        if w:
            out = w * t if out is None else out + w * t
    if out is None:
        raise ValueError("no loss term has a non-zero weight")
    return out
