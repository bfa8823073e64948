"""The CUDA rasterizer backend: gsplat's ``rasterization`` behind :func:`~.rasterizer.rasterize`'s signature.

gsplat (an optional extra, ``pip install "wcbench[cuda]"``) draws the same EWA-projected Gaussians
as our CPU rasterizer (docs/design.md §7: 0.3 px^2 dilation, front-to-back compositing, pixel
centres at +0.5) on a CUDA device. Its guards differ in small ways (boxes of 3.33 instead of 3
sigma, alpha clamped to 0.999 instead of 0.99), so images agree within a tolerance, not bit for bit
(``tests/reference_model/raster/test_gsplat_agreement.py``; docs/workstation.md).
"""

from __future__ import annotations

import importlib.util
from typing import Any

import torch

from wcbench.reference_model.raster.common import RenderOutput

__all__ = ["gsplat_problem", "rasterize_gsplat"]


def gsplat_problem() -> str | None:
    """Why :func:`rasterize_gsplat` cannot run here (gsplat missing, no CUDA device), or ``None``."""
    if importlib.util.find_spec("gsplat") is None:
        return "gsplat is not installed (pip install \"wcbench[cuda]\")"
    if not torch.cuda.is_available():
        return f"torch {torch.__version__} sees no CUDA device"
    return None


def _absgrad_into(holder: torch.Tensor, means2d: torch.Tensor) -> None:
    """Copy gsplat's absolute 2D gradient (``means2d.absgrad``, set by its backward) into
    ``holder.grad`` once the gradient of ``means2d`` is known: where :attr:`RenderOutput.means2d_abs`
    keeps it for the densification."""

    def hook(grad: torch.Tensor) -> torch.Tensor:
        absgrad = getattr(means2d, "absgrad", None)
        if absgrad is not None:
            g = absgrad.detach().reshape(holder.shape)
            holder.grad = g if holder.grad is None else holder.grad + g
        return grad

    means2d.register_hook(hook)


def rasterize_gsplat(
    means: torch.Tensor,  # [N, 3] world (metres), on a CUDA device
    quats: torch.Tensor,  # [N, 4] rotation, wxyz, any norm
    scales: torch.Tensor,  # [N, 3] standard deviations along the local axes (metres)
    opacities: torch.Tensor,  # [N] in [0, 1]
    colors: torch.Tensor,  # [N, C] colors or features
    viewmat: Any,  # [4, 4] world-to-camera, OpenCV axes
    K: Any,  # [3, 3] intrinsics in pixels (pixel centers at +0.5)
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    background: torch.Tensor | None = None,  # [C]
    render_depth: bool = True,
    absgrad: bool = True,
    backend: str = "gsplat",
) -> RenderOutput:
    """Render 3D Gaussians with gsplat on the device of ``means``; the arguments and the output of
    :func:`~wcbench.reference_model.raster.rasterizer.rasterize`.

    Parameters
    ----------
    means, quats, scales, opacities, colors, viewmat, K, width, height
        As :func:`~wcbench.reference_model.raster.rasterizer.rasterize`; ``viewmat`` and ``K`` may
        be on any device (moved to that of ``means``).
    near, far, background, render_depth, absgrad
        As :func:`~wcbench.reference_model.raster.rasterizer.rasterize`.
    backend : str
        Accepted for signature compatibility; only ``"gsplat"``.

    Returns
    -------
    RenderOutput
        ``color`` [H, W, C], ``alpha`` [H, W], ``depth`` [H, W] or None, ``means2d`` [N, 2],
        ``means2d_abs`` [N, 2] (its ``.grad`` after ``backward()``: gsplat's absolute gradient),
        ``radii`` [N, 2] int32, ``depths`` [N] (0 for culled Gaussians), ``meta`` (backend, counts).

    Raises
    ------
    ValueError
        gsplat or CUDA is unavailable (:func:`gsplat_problem`), ``means`` is not on a CUDA device,
        or the shapes disagree.
    """
    problem = gsplat_problem()
    if problem is not None:
        raise ValueError(f"the gsplat backend cannot run: {problem}")
    if means.device.type != "cuda":
        raise ValueError(f"the gsplat backend takes tensors on a CUDA device, means is on {means.device}")
    n = means.shape[0]
    for name, t, shape in (("quats", quats, (n, 4)), ("scales", scales, (n, 3)), ("opacities", opacities, (n,))):
        if tuple(t.shape) != shape:
            raise ValueError(f"{name} must have shape {shape}, got {tuple(t.shape)}")
    if colors.dim() != 2 or colors.shape[0] != n:
        raise ValueError(f"colors must have shape [{n}, C], got {tuple(colors.shape)}")
    from gsplat import rasterization

    dev, dtype = means.device, means.dtype
    viewmats = torch.as_tensor(viewmat, dtype=dtype).to(dev)[None]
    Ks = torch.as_tensor(K, dtype=dtype).to(dev)[None]
    image, alpha, meta = rasterization(
        means, quats, scales, opacities, colors, viewmats, Ks, int(width), int(height),
        near_plane=float(near), far_plane=float(far), eps2d=0.3, packed=False, absgrad=absgrad,
        render_mode="RGB+ED" if render_depth else "RGB", rasterize_mode="classic",
    )
    c = colors.shape[1]
    color, alpha2 = image[0, ..., :c], alpha[0, ..., 0]
    depth = image[0, ..., c] if render_depth else None
    if depth is not None:  # ours: 0 where nothing was drawn (gsplat divides by a clamped alpha too)
        depth = torch.where(alpha2 > 0, depth, torch.zeros_like(depth))
    if background is not None:
        color = color + (1.0 - alpha2)[..., None] * background.to(dev, color.dtype)
    means2d = meta["means2d"]
    radii = meta["radii"][0].to(torch.int32)
    if radii.dim() == 1:  # gsplat < 1.5 returns one radius per Gaussian
        radii = radii[:, None].expand(n, 2)
    visible = (radii > 0).all(dim=1)
    depths = torch.where(visible, meta["depths"][0].detach(), torch.zeros_like(meta["depths"][0]))
    means2d_abs = None
    if means2d.requires_grad:
        means2d.retain_grad()
        if absgrad:
            means2d_abs = torch.zeros((n, 2), dtype=dtype, device=dev)
            _absgrad_into(means2d_abs, means2d)
    return RenderOutput(
        color=color, alpha=alpha2, depth=depth, means2d=means2d[0], means2d_abs=means2d_abs, radii=radii,
        depths=depths, meta={"backend": "gsplat", "n_gaussians": int(n), "n_visible": int(visible.sum())},
    )
