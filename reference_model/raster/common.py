"""Constants, the output container and input checks shared by both rasterizer backends.

The constants are the gsplat / Inria 3DGS guards of docs/design.md §7. Both backends (the numba fast
path in :mod:`.kernels` and the pure-torch twin in :mod:`.torch_twin`) read them from
here, so a change reaches both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import torch

#: Pixels per tile side. 16 float32 lanes are one AVX-512 register: a tile row is one vector.
TILE_SIZE = 16
#: Screen-space dilation added to the 2D covariance diagonal (px^2), as in gsplat / Inria.
EPS2D = 0.3
#: Half-extent of a Gaussian's pixel box, in standard deviations per axis.
SIGMA_EXTENT = 3.0
#: Pairs with alpha below this are skipped (they change an 8-bit pixel by less than one level).
ALPHA_MIN = 1.0 / 255.0
#: Alpha is clamped to this so that 1 - alpha never reaches 0 (the backward divides by it).
ALPHA_MAX = 0.99
#: Compositing stops before transmittance would fall below this.
T_STOP = 1e-4
#: Floor of alpha when expected depth is normalised by alpha.
DEPTH_EPS = 1e-10
#: Quaternions with a squared norm below this are treated as the identity rotation.
QUAT_EPS2 = 1e-24
#: Largest pixel half-extent we keep as a number (boxes are clipped to the image anyway).
MAX_EXTENT = 1e7
#: Largest |value| of a finite color, feature or background entry (docs/design.md §9). Gradients
#: are linear in the colors and summed over up to millions of pixels in float32: 1e15 leaves ~20
#: orders of magnitude of headroom below float32's 3.4e38 for the geometric factors; colors are
#: RGB in [0, 1] or features of order 1.
MAX_ABS_COLOR = 1e15
#: Largest camera depth drawn (metres): float32's largest value. The depth image and its gradients
#: are float32; a centre beyond it (a finite Gaussian under an extreme view matrix) would be Inf
#: there, so it is culled with those beyond ``far`` (docs/design.md §9).
MAX_DEPTH = 3.4028234663852886e38

#: Names of the per-Gaussian cull counters in ``RenderOutput.meta`` (see :func:`cull_counts`).
CULL_NONFINITE, CULL_NEAR_FAR, CULL_DEGENERATE, CULL_TRANSPARENT, CULL_OFFSCREEN = 1, 2, 3, 4, 5
CULL_KEYS = {
    CULL_NONFINITE: "culled_nonfinite",
    CULL_NEAR_FAR: "culled_near_far",
    CULL_DEGENERATE: "culled_degenerate",
    CULL_TRANSPARENT: "culled_transparent",
    CULL_OFFSCREEN: "culled_offscreen",
}


@dataclass
class RenderOutput:
    """What :func:`rasterize` returns.

    Attributes
    ----------
    color : Tensor [H, W, C]
        Composited colors (features), background included.
    alpha : Tensor [H, W]
        Accumulated opacity ``sum_i w_i`` (= ``1 - T_final``), w_i = alpha_i T_i the blending weights.
    depth : Tensor [H, W] or None
        Expected camera-z depth ``sum(w_i z_i) / max(alpha, 1e-10)`` (metres); 0 where nothing was
        drawn. ``None`` when ``render_depth=False``.
    means2d : Tensor [N, 2]
        Projected centres in pixels (x right, y down, pixel centers at +0.5); 0 for culled
        Gaussians. When gradients are on it is a leaf whose ``.grad`` after ``backward()`` holds
        dL/d(means2d) (the densification signal of 3DGS).
    means2d_abs : Tensor [N, 2] or None
        A leaf with the same values whose ``.grad`` after ``backward()`` holds the per-pixel
        absolute 2D gradient summed over pixels, per axis (AbsGS). ``None`` when gradients are off
        or ``absgrad=False``.
    radii : Tensor [N, 2] int32
        Pixel half-extent of each Gaussian's box per axis (x, y); 0 for culled Gaussians.
    depths : Tensor [N]
        Camera-z of each Gaussian centre (metres); 0 for culled ones.
    meta : dict
        Counters and settings: ``backend``, ``n_gaussians``, ``n_visible``, the cull counters of
        :data:`CULL_KEYS`, ``n_tile_entries`` (Gaussian-tile intersections), ``n_pairs``
        (Gaussian-pixel pairs evaluated, after early termination), ``tile_size``.
    """

    color: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor | None
    means2d: torch.Tensor
    means2d_abs: torch.Tensor | None
    radii: torch.Tensor
    depths: torch.Tensor
    meta: dict[str, Any] = field(default_factory=dict)


def check_inputs(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmat: Any,
    K: Any,
    width: int,
    height: int,
    near: float,
    far: float,
    background: torch.Tensor | None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Validate shapes, dtypes and devices; return ``viewmat``, ``K`` and ``background`` as tensors.

    Raises
    ------
    ValueError
        Naming the argument, its shape or dtype and what was expected.
    """
    for name, t in (("means", means), ("quats", quats), ("scales", scales), ("opacities", opacities),
                    ("colors", colors)):
        if not isinstance(t, torch.Tensor):
            raise ValueError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
        if t.device.type != "cpu":
            raise ValueError(f"{name} is on {t.device}; this rasterizer runs on the CPU")
        if t.dtype not in (torch.float32, torch.float64):
            raise ValueError(f"{name} must be float32 or float64, got {t.dtype}")
    n = means.shape[0] if means.dim() == 2 else -1
    expected = {"means": (means, (n, 3)), "quats": (quats, (n, 4)), "scales": (scales, (n, 3)),
                "opacities": (opacities, (n,))}
    for name, (t, shape) in expected.items():
        if tuple(t.shape) != shape or n < 0:
            raise ValueError(f"{name} must have shape {shape} (N = len(means)), got {tuple(t.shape)}")
    if colors.dim() != 2 or colors.shape[0] != n or colors.shape[1] < 1:
        raise ValueError(f"colors must have shape [N={n}, C >= 1], got {tuple(colors.shape)}")
    if colors.numel():
        # Non-finite colors cull their Gaussian (counted); finite ones beyond the bound are an error.
        # One pass without temporaries in the usual case; the masked pass only if it finds NaN/Inf.
        with torch.no_grad():
            lo, hi = torch.aminmax(colors)
            top = max(-float(lo), float(hi))
            if not math.isfinite(top):
                top = float(torch.where(torch.isfinite(colors), colors.abs(), 0.0).max())
        if top > MAX_ABS_COLOR:
            raise ValueError(f"colors must be within +-{MAX_ABS_COLOR:g} (float32 gradients would overflow), "
                             f"got a finite value of magnitude {top:.3g}")
    dtypes = {t.dtype for t in (means, quats, scales, opacities, colors)}
    if len(dtypes) != 1:
        raise ValueError(f"means, quats, scales, opacities and colors must share one dtype, got {dtypes}")
    dtype = means.dtype
    viewmat_t = torch.as_tensor(viewmat, dtype=dtype)
    K_t = torch.as_tensor(K, dtype=dtype)
    if tuple(viewmat_t.shape) != (4, 4):
        raise ValueError(f"viewmat must be a [4, 4] world-to-camera matrix, got {tuple(viewmat_t.shape)}")
    if tuple(K_t.shape) != (3, 3):
        raise ValueError(f"K must be [3, 3] intrinsics, got {tuple(K_t.shape)}")
    if not (bool(torch.isfinite(viewmat_t).all()) and bool(torch.isfinite(K_t).all())):
        raise ValueError("viewmat and K must be finite")
    if float(K_t[0, 0]) <= 0 or float(K_t[1, 1]) <= 0:
        raise ValueError(f"K must have positive focal lengths, got fx={float(K_t[0, 0])}, fy={float(K_t[1, 1])}")
    if not (_positive_integer(width) and _positive_integer(height)):
        raise ValueError(f"width and height must be positive integers, got {width} x {height}")
    if not (0 < near < far):
        raise ValueError(f"need 0 < near < far, got near={near}, far={far}")
    bg = None
    if background is not None:
        try:
            bg = torch.as_tensor(background, dtype=dtype)
        except (TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f"background must be [C] real numbers, got {background!r}") from exc
        if bg.device.type != "cpu":
            raise ValueError(f"background is on {bg.device}; this rasterizer runs on the CPU")
        if tuple(bg.shape) != (colors.shape[1],):
            raise ValueError(f"background must have shape [C={colors.shape[1]}], got {tuple(bg.shape)}")
        # One background for every pixel: a NaN or Inf there would be in every output and gradient.
        with torch.no_grad():
            finite = bool(torch.isfinite(bg).all())
            mag = float(bg.abs().max())
        if not finite or mag > MAX_ABS_COLOR:
            raise ValueError(f"background must be finite and within +-{MAX_ABS_COLOR:g}, got {bg.detach().tolist()}")
    return viewmat_t, K_t, bg


def _positive_integer(v: Any) -> bool:
    """An integer >= 1, as int or integral float (NaN, Inf and non-numbers are not)."""
    try:
        return float(v).is_integer() and v >= 1
    except (TypeError, ValueError, OverflowError):
        return False


class _ExpectedDepth(torch.autograd.Function):
    """``dnum / max(alpha, DEPTH_EPS)`` saturated at the dtype's finite range, both ways (see
    :func:`expected_depth`)."""

    @staticmethod
    def forward(ctx: Any, dnum: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        ctx.save_for_backward(dnum, alpha)
        big = torch.finfo(dnum.dtype).max
        return (dnum / alpha.clamp_min(DEPTH_EPS)).clamp_(-big, big)

    @staticmethod
    def backward(ctx: Any, g: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # type: ignore[override]
        dnum, alpha = ctx.saved_tensors
        big = torch.finfo(dnum.dtype).max
        a = alpha.clamp_min(DEPTH_EPS)
        g_dnum = (g / a).clamp_(-big, big)
        g_alpha = (dnum / a).div_(a).mul_(g).neg_()  # autograd's -g ((dnum / a) / a), bit for bit
        g_alpha.masked_fill_(alpha < DEPTH_EPS, 0.0)  # where the clamp holds alpha, as torch.clamp_min
        over = ~torch.isfinite(g_alpha)
        if bool(over.any()):
            # -g depth / alpha beyond the dtype (a depth near 3.4e38 at a low alpha): autograd of the
            # plain division gave -Inf there, or 0 * Inf = NaN where g = 0, and NaN in every gradient
            # behind it. Here: the value from float64, saturated; exactly 0 where g is.
            g64, a64 = g[over].double(), a[over].double()
            exact = torch.where(g64 == 0, 0.0, -(g64 * (dnum[over].double() / a64)) / a64)
            g_alpha[over] = exact.clamp(-big, big).to(g_alpha.dtype)
        return g_dnum, g_alpha


def expected_depth(dnum: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Expected depth ``sum(w z) / max(alpha, DEPTH_EPS)`` of both backends, differentiable.

    Saturated at the dtype's largest finite value in the forward (the quotient of two rounded
    float32 sums can pass float32's max for a Gaussian at 3.4e38) and in the backward (dL/dalpha =
    -g depth / alpha exceeds float32 for depths beyond ~1e36 at low alpha): gradients beyond float32
    saturate at +-3.4e38 (docs/design.md §9), and are exactly 0 where the depth's gradient is. Where
    nothing overflows, values and gradients are those of ``dnum / alpha.clamp_min(DEPTH_EPS)``, bit
    for bit.
    """
    return _ExpectedDepth.apply(dnum, alpha)


def empty_meta(backend: str, n: int) -> dict[str, Any]:
    """The meta dict with every counter present and zero."""
    meta: dict[str, Any] = {"backend": backend, "n_gaussians": n, "n_visible": 0, "tile_size": TILE_SIZE,
                            "n_tile_entries": 0, "n_pairs": 0}
    for key in CULL_KEYS.values():
        meta[key] = 0
    return meta


def cull_counts(reason: torch.Tensor) -> dict[str, int]:
    """Count Gaussians per cull reason; ``reason`` [N] int (0 = visible, else a ``CULL_*`` code)."""
    return counts_meta(torch.bincount(reason.to(torch.int64), minlength=len(CULL_KEYS) + 1).tolist())


def counts_meta(counts: list[int]) -> dict[str, int]:
    """The meta counters from ``counts[code]``, the Gaussians per cull code (0 = visible)."""
    out = {key: int(counts[code]) for code, key in CULL_KEYS.items()}
    out["n_visible"] = int(counts[0])
    return out
