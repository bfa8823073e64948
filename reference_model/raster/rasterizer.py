"""Public API of the differentiable CPU Gaussian rasterizer: :func:`rasterize`.

Two backends compute the same function (docs/design.md §7 guards, constants in :mod:`.common`):

* ``"numba"``, the fast path (:mod:`.kernels`): tile binning, per-tile front-to-back
  compositing with early termination, multithreaded over tiles, hand-written backward; wrapped
  in a ``torch.autograd.Function``. float32 inputs only.
* ``"torch"``, the pure-PyTorch twin (:func:`.torch_twin.rasterize_torch`): slow, obviously
  correct, differentiable by autograd, any float dtype.

``backend="auto"`` takes numba for float32 inputs and the twin for float64 ones (``gradcheck``).
If numba cannot be imported the twin is used and one warning says so.

:func:`rasterize_image` is the same function for renders without gradients (a trained model's
frames): its numba path composites with float32 state and keeps nothing for a backward.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import torch

from wcbench.core.progress import announce
from wcbench.reference_model._numba_backend import load_numba_kernels, numba_error
from wcbench.reference_model.raster.common import T_STOP, RenderOutput, check_inputs, expected_depth
from wcbench.reference_model.raster.torch_twin import rasterize_torch

__all__ = ["RenderOutput", "numba_available", "rasterize", "rasterize_image"]

_BACKENDS = ("auto", "numba", "torch")
_warned = False
_compile_checked = False


def _load_numba() -> ModuleType | None:
    """The numba backend; when it cannot be imported, warn once and use the twin."""
    global _warned
    module = load_numba_kernels("raster.kernels")
    if module is None and not _warned:
        _warned = True
        warnings.warn(f"wcbench rasterizer: numba backend unavailable ({numba_error('raster.kernels')}); "
                      "using the slow pure-torch twin", RuntimeWarning, stacklevel=3)
    return module


def _announce_compile(module: ModuleType) -> None:
    """Say once per process that the kernels compile now when numba has no cache of them beside their
    source (the first render of a fresh install waits about 20 s, silently otherwise)."""
    global _compile_checked
    if _compile_checked:
        return
    _compile_checked = True
    folder = Path(module.__file__ or "").parent / "__pycache__"
    stem = Path(module.__file__ or "").stem
    if not any(folder.glob(f"{stem}.*.nbi")):
        announce("compiling the rasterizer kernels (first run only: numba caches them)")


def numba_available() -> bool:
    """True if the fast numba backend imports (it compiles lazily, on the first render)."""
    return _load_numba() is not None


class _RasterizeFunction(torch.autograd.Function):
    """Tile rasterization of projected Gaussians (numba), with the hand-written backward.

    Inputs that need gradients are the 3D parameters plus two placeholder leaves whose gradients
    are dL/d(means2d) and the AbsGS absolute 2D gradient; the forward computes from ``job`` (a
    :class:`.kernels.RenderJob` holding the numpy views and the projection).
    """

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        means: torch.Tensor,
        quats: torch.Tensor,
        scales: torch.Tensor,
        opacities: torch.Tensor,
        colors: torch.Tensor,
        means2d: torch.Tensor,
        means2d_abs: torch.Tensor,
        job: Any,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        color, alpha, dnum = job.forward()
        ctx.job = job
        return torch.from_numpy(color), torch.from_numpy(alpha), torch.from_numpy(dnum)

    @staticmethod
    def backward(  # type: ignore[override]
        ctx: Any, g_color: torch.Tensor, g_alpha: torch.Tensor, g_dnum: torch.Tensor
    ) -> tuple[torch.Tensor | None, ...]:
        job = ctx.job

        def arr(g: torch.Tensor | None, like: tuple[int, ...]) -> np.ndarray:
            if g is None:
                return np.zeros(like, np.float32)
            return np.ascontiguousarray(g.detach().to(torch.float32).numpy())

        h, w, c = job.height, job.width, job.n_channels
        grads = job.backward(arr(g_color, (h, w, c)), arr(g_alpha, (h, w)), arr(g_dnum, (h, w)))
        need = ctx.needs_input_grad
        out: list[torch.Tensor | None] = []
        for i, g in enumerate(grads):
            out.append(torch.from_numpy(g) if need[i] else None)
        out.append(None)  # job
        return tuple(out)


def rasterize(
    means: torch.Tensor,  # [N, 3] world (metres)
    quats: torch.Tensor,  # [N, 4] rotation, wxyz, any norm (normalised safely inside)
    scales: torch.Tensor,  # [N, 3] standard deviations along the local axes (metres)
    opacities: torch.Tensor,  # [N] in [0, 1]
    colors: torch.Tensor,  # [N, C] colors or features (C free: 3 for RGB)
    viewmat: Any,  # [4, 4] world-to-camera, OpenCV axes (x right, y down, z forward)
    K: Any,  # [3, 3] intrinsics in pixels (pixel centers at +0.5)
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    background: torch.Tensor | None = None,  # [C]
    render_depth: bool = True,
    absgrad: bool = True,
    backend: str = "auto",
) -> RenderOutput:
    """Render 3D Gaussians into an image, differentiably, on the CPU.

    Each Gaussian is projected with the EWA approximation, its 2D covariance dilated by 0.3 px^2,
    and composited front to back over the pixels of its per-axis 3-sigma box (tighter for faint
    Gaussians, where the rest would be skipped anyway). Pixel (i, j) has its center at
    (i + 0.5, j + 0.5), as in gsplat and OpenCV.

    Parameters
    ----------
    means : Tensor [N, 3]
        Centres in world coordinates (metres).
    quats : Tensor [N, 4]
        Rotations as (w, x, y, z) quaternions of any norm; a zero quaternion means identity.
    scales : Tensor [N, 3]
        Standard deviations along the rotated axes (metres).
    opacities : Tensor [N]
        Opacity in [0, 1] (after the sigmoid).
    colors : Tensor [N, C]
        Per-Gaussian colors (float RGB in [0, 1]) or any C-channel features, within +-1e15
        (:data:`~.common.MAX_ABS_COLOR`).
    viewmat : Tensor or ndarray [4, 4]
        World-to-camera transform, OpenCV camera axes.
    K : Tensor or ndarray [3, 3]
        Pinhole intrinsics (fx, fy, cx, cy) in pixels.
    width, height : int
        Image size in pixels.
    near, far : float, keyword-only
        Gaussians whose centre has camera z <= near or >= far are culled (metres), and those
        beyond float32's largest depth, 3.4e38 m (:data:`~.common.MAX_DEPTH`), at any ``far``.
    background : Tensor [C], optional
        Composited behind the Gaussians with weight ``1 - alpha``; zeros when ``None``. Finite,
        within +-1e15.
    render_depth : bool
        Compute the expected-depth image; ``False`` skips that channel (``depth`` is ``None``).
    absgrad : bool
        Provide ``means2d_abs`` whose ``.grad`` is the absolute 2D gradient (AbsGS densification).
    backend : {"auto", "numba", "torch"}
        ``"auto"``: numba for float32 inputs, the torch twin for float64 (or when numba is
        missing, with one warning).

    Returns
    -------
    RenderOutput
        ``color`` [H, W, C], ``alpha`` [H, W], ``depth`` [H, W] or None, per-Gaussian ``means2d``
        [N, 2], ``means2d_abs`` [N, 2], ``radii`` [N, 2], ``depths`` [N], and ``meta`` counters
        (culled Gaussians per reason, visible Gaussians, tile entries, pairs evaluated).

    Raises
    ------
    ValueError
        On wrong shapes, dtypes, devices, non-positive sizes or ``near``/``far``, an unknown
        ``backend``, a background that is not finite or beyond +-1e15, or a finite color beyond
        +-1e15; non-finite per-Gaussian values are not errors: those Gaussians are culled and
        counted in ``meta["culled_nonfinite"]``.

    Notes
    -----
    Gradients flow to ``means``, ``quats``, ``scales``, ``opacities``, ``colors`` and
    ``background``, not to ``viewmat`` or ``K``. Culled Gaussians get exactly zero gradient.
    Numeric guards (docs/design.md §9), the same in both backends: a needle Gaussian (scales such
    as (1e-30, 1e30, 1)) is drawn, its 2D determinant taken from the minors of J V R diag(s)
    rather than as the rounding noise a c - b^2; a gradient whose exact value exceeds float32
    saturates at +-3.4e38 instead of becoming Inf or NaN.
    """
    if backend not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS}, got {backend!r}")
    viewmat_t, K_t, bg = check_inputs(means, quats, scales, opacities, colors, viewmat, K, width, height,
                                      near, far, background)
    use_torch = backend == "torch" or (backend == "auto" and means.dtype != torch.float32)
    if backend == "numba" and means.dtype != torch.float32:
        raise ValueError(f"the numba backend takes float32 inputs, got {means.dtype}; use backend='torch'")
    mod = None if use_torch else _load_numba()
    if mod is None:
        if backend == "numba":
            raise ValueError(f"backend='numba' requested but numba is unavailable ({numba_error('raster.kernels')})")
        return rasterize_torch(means, quats, scales, opacities, colors, viewmat_t, K_t, width, height,
                               near=near, far=far, background=bg, render_depth=render_depth, absgrad=absgrad)

    _announce_compile(mod)
    job = mod.RenderJob(means, quats, scales, opacities, colors, viewmat_t, K_t, int(width), int(height),
                        near=float(near), far=float(far), render_depth=render_depth)
    # The projection's own arrays, not copies: the job only reads them from here on.
    means2d = torch.from_numpy(job.means2d_f32)
    radii = torch.from_numpy(job.radii)
    depths = torch.from_numpy(job.depths)
    params = (means, quats, scales, opacities, colors)
    grads_on = torch.is_grad_enabled() and any(t.requires_grad for t in params)
    means2d_abs = None
    if grads_on:
        means2d.requires_grad_(True)
        if absgrad:
            means2d_abs = means2d.detach().clone().requires_grad_(True)
    holder_abs = means2d_abs if means2d_abs is not None else torch.zeros(0, 2)
    color, alpha, dnum = _RasterizeFunction.apply(*params, means2d, holder_abs, job)
    if bg is not None:
        color = color + (1.0 - alpha)[..., None] * bg
    depth = expected_depth(dnum, alpha) if render_depth else None
    return RenderOutput(color=color, alpha=alpha, depth=depth, means2d=means2d, means2d_abs=means2d_abs,
                        radii=radii, depths=depths, meta=job.meta)


def rasterize_image(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmat: Any,
    K: Any,
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    background: torch.Tensor | None = None,
    render_depth: bool = True,
    absgrad: bool = False,
    backend: str = "auto",
    stop_transmittance: float = T_STOP,
) -> RenderOutput:
    """:func:`rasterize` for a render without gradients (inference): same arguments, same outputs.

    The numba path composites the same tile lists in the same order with the same per-pair float32
    math, but keeps the per-tile transmittance and sums in float32 and stores nothing for a
    backward (``RenderJob.image``). Its images equal :func:`rasterize`'s within float32 rounding
    of the sums (tests/reference_model/raster/test_raster_image.py states the tolerance). Training
    keeps :func:`rasterize`. The torch backend (float64 inputs, or numba missing) runs the twin
    without gradients.

    Parameters
    ----------
    means, quats, scales, opacities, colors, viewmat, K, width, height, near, far, background, render_depth, backend
        As :func:`rasterize` ([N, 3], [N, 4], [N, 3], [N], [N, C]; metres, pixels).
    absgrad : bool
        Accepted for ``rasterize``-compatibility and must be ``False``: no gradient is computed.
    stop_transmittance : float
        A pixel stops compositing before its transmittance would fall below this, in
        [``T_STOP`` (1e-4, the default, :func:`rasterize`'s), 1). A render that reads only the
        front surface (surface maps: normals, fields, depth, each divided by alpha) may stop
        sooner: what it leaves out weighs less than the stop (up to 16 channels; more raise).

    Returns
    -------
    RenderOutput
        As :func:`rasterize`, detached: ``means2d_abs`` is ``None`` and nothing requires grad.

    Raises
    ------
    ValueError
        As :func:`rasterize`; also when ``absgrad`` is ``True``, gradients are enabled for an
        input that requires them (use :func:`rasterize` there), or ``stop_transmittance`` is
        outside [1e-4, 1).
    """
    if backend not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS}, got {backend!r}")
    if absgrad:
        raise ValueError("rasterize_image computes no gradients: absgrad must be False (use rasterize)")
    if not T_STOP <= stop_transmittance < 1.0:
        raise ValueError(f"stop_transmittance must be in [{T_STOP}, 1), got {stop_transmittance!r}")
    params = (means, quats, scales, opacities, colors, background)
    if torch.is_grad_enabled() and any(isinstance(t, torch.Tensor) and t.requires_grad for t in params):
        raise ValueError("rasterize_image computes no gradients, but an input requires grad: use rasterize, "
                         "or call it under torch.no_grad()")
    viewmat_t, K_t, bg = check_inputs(means, quats, scales, opacities, colors, viewmat, K, width, height,
                                      near, far, background)
    use_torch = backend == "torch" or (backend == "auto" and means.dtype != torch.float32)
    if backend == "numba" and means.dtype != torch.float32:
        raise ValueError(f"the numba backend takes float32 inputs, got {means.dtype}; use backend='torch'")
    mod = None if use_torch else _load_numba()
    if mod is None:
        if backend == "numba":
            raise ValueError(f"backend='numba' requested but numba is unavailable ({numba_error('raster.kernels')})")
        with torch.no_grad():
            return rasterize_torch(means, quats, scales, opacities, colors, viewmat_t, K_t, width, height,
                                   near=near, far=far, background=bg, render_depth=render_depth, absgrad=False,
                                   stop_transmittance=stop_transmittance)

    _announce_compile(mod)
    job = mod.RenderJob(means, quats, scales, opacities, colors, viewmat_t, K_t, int(width), int(height),
                        near=float(near), far=float(far), render_depth=render_depth)
    color_np, alpha_np, dnum_np = job.image(stop=float(stop_transmittance))
    color, alpha = torch.from_numpy(color_np), torch.from_numpy(alpha_np)
    if bg is not None:
        color = color + (1.0 - alpha)[..., None] * bg
    depth = expected_depth(torch.from_numpy(dnum_np), alpha) if render_depth else None
    return RenderOutput(color=color, alpha=alpha, depth=depth, means2d=torch.from_numpy(job.means2d_f32),
                        means2d_abs=None, radii=torch.from_numpy(job.radii), depths=torch.from_numpy(job.depths),
                        meta=job.meta)
