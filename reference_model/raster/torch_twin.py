"""Pure-PyTorch twin of the rasterizer: slow, obviously correct, differentiable by autograd.

Mirrors :func:`wcbench.reference_model.rasterize` (the numba path of :mod:`.kernels`:
``_project_kernel`` + binning + ``_render_forward``, and their hand-written backward) with the
same guards and constants from :mod:`.common` and the same precision plan: projection in
float64 (2D means, covariances, culling, boxes), conics rounded to the input dtype, per-pair math
in the input dtype with dx = (px - floor(mx)) + (0.5 - (mx - floor(mx))), compositing sums in
float64. Instead of tiles it lists every
Gaussian-pixel pair explicitly, sorts the pairs by (pixel, depth, index) and composites each pixel's
segment with a float64 cumulative sum of ``log(1 - alpha)``. Gradients come from autograd.

It is the reference in tests (forward and ``autograd.grad`` against the fast path, ``gradcheck`` in
float64) and in the benchmark, where it is also run in float64 on the pair list the float32 fast
path composited (``pairs=``), so that both make the same skip and stop decisions.
"""

from __future__ import annotations

from typing import Any

import torch

from wcbench.reference_model.raster.common import (
    ALPHA_MAX,
    ALPHA_MIN,
    CULL_DEGENERATE,
    CULL_NEAR_FAR,
    CULL_NONFINITE,
    CULL_OFFSCREEN,
    CULL_TRANSPARENT,
    EPS2D,
    MAX_DEPTH,
    MAX_EXTENT,
    QUAT_EPS2,
    SIGMA_EXTENT,
    T_STOP,
    TILE_SIZE,
    RenderOutput,
    check_inputs,
    cull_counts,
    empty_meta,
    expected_depth,
)

__all__ = ["project_torch", "rasterize_torch"]


class _ToFloat64(torch.autograd.Function):
    """``x.double()`` whose backward saturates the gradient at the finite range of ``x``'s dtype.

    A gradient too large for float32 becomes +-3.4e38 instead of Inf (and NaN further on), as in
    the fast path (docs/design.md §9).
    """

    @staticmethod
    def forward(ctx: Any, x: torch.Tensor) -> torch.Tensor:
        ctx.dtype = x.dtype
        return x.double()

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> torch.Tensor:
        big = torch.finfo(ctx.dtype).max
        return grad.clamp(-big, big).to(ctx.dtype)


def _to64(x: torch.Tensor) -> torch.Tensor:
    return _ToFloat64.apply(x)


def _quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """[N, 4] wxyz (any norm) -> [N, 3, 3]; a (near-)zero quaternion gives the identity."""
    sq = (quats * quats).sum(-1, keepdim=True)  # [N, 1]
    ok = sq > QUAT_EPS2
    # Double where: the rsqrt never sees 0, so neither value nor gradient is ever Inf or NaN.
    inv = torch.rsqrt(torch.where(ok, sq, torch.ones_like(sq)))
    identity = torch.zeros_like(quats)
    identity[:, 0] = 1.0
    q = torch.where(ok, quats * inv, identity)
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, -1).reshape(-1, 3, 3)


def _project(
    means: torch.Tensor,  # [N, 3] world
    quats: torch.Tensor,  # [N, 4] wxyz
    scales: torch.Tensor,  # [N, 3]
    viewmat: torch.Tensor,  # [4, 4] world-to-camera
    K: torch.Tensor,  # [3, 3]
    width: int,
    height: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """EWA projection: 2D means [N, 2] (px), 2D covariances [N, 3] (a, b, c, dilated), their
    determinants [N] and camera z [N].

    cov2 = T T^T + EPS2D I with T = J V R diag(s); the determinant is the sum of the squared 2x2
    minors of T (Cauchy-Binet) plus the dilation terms, as in the fast path's ``_cov2d``: never the
    rounding noise a c - b^2 leaves for a needle Gaussian (docs/design.md §9).
    """
    Wr, tv = viewmat[:3, :3], viewmat[:3, 3]
    t = means @ Wr.T + tv  # [N, 3] camera coordinates
    x, y, z = t.unbind(-1)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    mx = fx * x / z + cx
    my = fy * y / z + cy
    # The Jacobian is evaluated at most 30 % of the half field of view outside the image (gsplat):
    # far outside, the linearisation would blow a Gaussian up to a huge smear.
    tan_x = 0.5 * width / fx
    tan_y = 0.5 * height / fy
    ux = torch.clamp(x / z, -(cx / fx + 0.3 * tan_x), (width - cx) / fx + 0.3 * tan_x)
    uy = torch.clamp(y / z, -(cy / fy + 0.3 * tan_y), (height - cy) / fy + 0.3 * tan_y)
    zero = torch.zeros_like(z)
    J = torch.stack([fx / z, zero, -fx * ux / z, zero, fy / z, -fy * uy / z], -1).reshape(-1, 2, 3)
    R = _quat_to_rotmat(quats)
    A = J @ (Wr @ R)  # [N, 2, 3], unit-sized; the fast path's association
    T = A * scales[:, None, :]
    a, b, c = (T[:, 0] * T[:, 0]).sum(-1), (T[:, 0] * T[:, 1]).sum(-1), (T[:, 1] * T[:, 1]).sum(-1)
    s0, s1, s2 = scales.unbind(-1)
    m01 = (A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]) * (s0 * s1)
    m02 = (A[:, 0, 0] * A[:, 1, 2] - A[:, 0, 2] * A[:, 1, 0]) * (s0 * s2)
    m12 = (A[:, 0, 1] * A[:, 1, 2] - A[:, 0, 2] * A[:, 1, 1]) * (s1 * s2)
    det = (m01 * m01 + m02 * m02 + m12 * m12) + EPS2D * (a + c) + EPS2D * EPS2D
    cov = torch.stack([a + EPS2D, b, c + EPS2D], -1)
    return torch.stack([mx, my], -1), cov, det, z


def _boxes(
    means2d: torch.Tensor, cov: torch.Tensor, opacities: torch.Tensor, width: int, height: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel boxes [N, 4] int64 (x0, x1, y0, y1 inclusive, clipped) and half-extents [N, 2] (px)."""
    op = opacities.to(torch.float64).clamp_min(ALPHA_MIN)
    # Beyond sqrt(2 ln(255 o)) sigmas o exp(-q / 2) < 1/255 and every pair would be skipped: the box is
    # the smaller of that and SIGMA_EXTENT sigmas.
    k = torch.sqrt(2.0 * torch.log(255.0 * op)).clamp_max(SIGMA_EXTENT)
    ext = torch.stack([k * torch.sqrt(cov[:, 0]), k * torch.sqrt(cov[:, 2])], -1).clamp_max(MAX_EXTENT)
    # Pixel i (center i + 0.5) is in the box when |i + 0.5 - mx| <= ext_x.
    lo = torch.ceil(means2d - ext - 0.5)
    hi = torch.floor(means2d + ext - 0.5)
    x0 = lo[:, 0].clamp(-1, width).to(torch.int64).clamp_min(0)
    x1 = hi[:, 0].clamp(-1, width).to(torch.int64).clamp_max(width - 1)
    y0 = lo[:, 1].clamp(-1, height).to(torch.int64).clamp_min(0)
    y1 = hi[:, 1].clamp(-1, height).to(torch.int64).clamp_max(height - 1)
    return torch.stack([x0, x1, y0, y1], -1), ext


@torch.no_grad()
def _cull(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    near: float,
    far: float,
) -> torch.Tensor:
    """Cull reason per Gaussian [N] int64: 0 visible, else a ``CULL_*`` code (first reason wins)."""
    n = means.shape[0]
    reason = torch.zeros(n, dtype=torch.int64)
    finite = (torch.isfinite(means).all(-1) & torch.isfinite(quats).all(-1) & torch.isfinite(scales).all(-1)
              & torch.isfinite(opacities) & torch.isfinite(colors).all(-1))
    reason[~finite] = CULL_NONFINITE
    safe = _sanitize(means, quats, scales, opacities, colors, finite)
    m2, cov, det, z = _project(safe[0].double(), safe[1].double(), safe[2].double(), viewmat.double(),
                               K.double(), width, height)
    near_far = ~((z > near) & (z < far) & (z <= MAX_DEPTH))
    reason[(reason == 0) & near_far] = CULL_NEAR_FAR
    good = torch.isfinite(cov).all(-1) & torch.isfinite(m2).all(-1) & (det > 0) & torch.isfinite(det)
    reason[(reason == 0) & ~good] = CULL_DEGENERATE
    reason[(reason == 0) & ~(safe[3] >= ALPHA_MIN)] = CULL_TRANSPARENT
    ok = reason == 0
    box, _ = _boxes(torch.where(ok[:, None], m2, 0.0), torch.where(ok[:, None], cov, 1.0),
                    torch.where(ok, safe[3], 1.0), width, height)
    empty = (box[:, 0] > box[:, 1]) | (box[:, 2] > box[:, 3])
    reason[ok & empty] = CULL_OFFSCREEN
    return reason


def _sanitize(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    keep: torch.Tensor,  # [N] bool
) -> tuple[torch.Tensor, ...]:
    """Replace the parameters of Gaussians not in ``keep`` by harmless finite values.

    ``torch.where`` passes a zero gradient to the replaced entries, so culled Gaussians get exactly
    zero gradient and no NaN or Inf ever enters the graph (0 * Inf would be NaN in the backward).
    """
    k = keep[:, None]
    safe_means = torch.where(k, means, torch.tensor([0.0, 0.0, 1.0], dtype=means.dtype))
    safe_quats = torch.where(k, quats, torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=quats.dtype))
    safe_scales = torch.where(k, scales, 1e-3)
    safe_opac = torch.where(keep, opacities, 0.0)
    safe_colors = torch.where(k, colors, 0.0)
    return safe_means, safe_quats, safe_scales, safe_opac, safe_colors


def project_torch(
    means: torch.Tensor,  # [N, 3]
    quats: torch.Tensor,  # [N, 4] wxyz
    scales: torch.Tensor,  # [N, 3]
    opacities: torch.Tensor,  # [N]
    colors: torch.Tensor,  # [N, C]
    viewmat: torch.Tensor,  # [4, 4]
    K: torch.Tensor,  # [3, 3]
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
) -> dict[str, torch.Tensor]:
    """Project Gaussians to the image with every guard of the rasterizer (differentiable).

    Parameters
    ----------
    means, quats, scales, opacities, colors, viewmat, K, width, height, near, far
        As in :func:`rasterize_torch`.

    Returns
    -------
    dict
        ``reason`` [N] int64 (0 visible, else a ``CULL_*`` code), and for all Gaussians (culled ones
        hold harmless placeholder values): ``means2d`` [N, 2] px (float64), ``conics`` [N, 3] (inverse 2D
        covariance a, b, c with ``q = a dx^2 + 2 b dx dy + c dy^2``), ``depths`` [N] camera z,
        ``opacities`` [N], ``colors`` [N, C], ``boxes`` [N, 4] int64 (x0, x1, y0, y1 inclusive),
        ``extents`` [N, 2] px (float64). The rest has the input dtype.
    """
    reason = _cull(means, quats, scales, opacities, colors, viewmat, K, width, height, near, far)
    ok = reason == 0
    m, q, s, o, c = _sanitize(means, quats, scales, opacities, colors, ok)
    dtype = means.dtype
    # float64 per Gaussian (cheap): no float32 rounding of pixel coordinates in the 2D means.
    m2, cov, det, z = _project(_to64(m), _to64(q), _to64(s), viewmat.double(), K.double(), width, height)
    # Culled Gaussians keep a unit covariance so that the inverse below stays finite.
    cov = torch.where(ok[:, None], cov, torch.tensor([1.0, 0.0, 1.0], dtype=cov.dtype))
    det = torch.where(ok, det, 1.0)
    conics = torch.stack([cov[:, 2] / det, -cov[:, 1] / det, cov[:, 0] / det], -1).to(dtype)
    box, ext = _boxes(m2.detach(), cov.detach(), o.detach(), width, height)
    return {"reason": reason, "means2d": torch.where(ok[:, None], m2, 0.0), "conics": conics,
            "depths": torch.where(ok, z, 0.0).to(dtype), "opacities": o, "colors": c, "boxes": box,
            "extents": torch.where(ok[:, None], ext, 0.0)}


class _AbsTap(torch.autograd.Function):
    """Identity on per-pair 2D means whose backward also scatters |grad| per Gaussian (AbsGS)."""

    @staticmethod
    def forward(ctx: Any, m_pairs: torch.Tensor, gid: torch.Tensor, holder: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(gid)
        ctx.n, ctx.dtype = holder.shape[0], holder.dtype
        return m_pairs.view_as(m_pairs)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor, None, torch.Tensor]:
        (gid,) = ctx.saved_tensors
        absgrad = torch.zeros(ctx.n, 2, dtype=grad.dtype).index_add_(0, gid, grad.abs())
        big = torch.finfo(ctx.dtype).max
        return grad, None, absgrad.clamp_max(big).to(ctx.dtype)


def _candidate_pairs(box: torch.Tensor, idx: torch.Tensor, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Every (Gaussian, pixel) pair inside the boxes of Gaussians ``idx``: gid [P], pix [P] (y * W + x)."""
    b = box[idx]
    bw = b[:, 1] - b[:, 0] + 1
    bh = b[:, 3] - b[:, 2] + 1
    cnt = bw * bh
    total = int(cnt.sum())
    gid = torch.repeat_interleave(idx, cnt, output_size=total)
    start = torch.repeat_interleave(torch.cumsum(cnt, 0) - cnt, cnt, output_size=total)
    k = torch.arange(total) - start
    bw_r = torch.repeat_interleave(bw, cnt, output_size=total)
    px = torch.repeat_interleave(b[:, 0], cnt, output_size=total) + k % bw_r
    py = torch.repeat_interleave(b[:, 2], cnt, output_size=total) + k // bw_r
    return gid, py * width + px


def _segment_starts(pix: torch.Tensor) -> torch.Tensor:
    """Index of the first pair of each pair's pixel segment (pairs grouped by pixel) [P]."""
    p = pix.shape[0]
    new = torch.ones(p, dtype=torch.bool)
    if p > 1:
        new[1:] = pix[1:] != pix[:-1]
    first = torch.where(new, torch.arange(p), 0)
    return torch.cummax(first, 0).values


def _any_before(flags: torch.Tensor, start: torch.Tensor) -> torch.Tensor:
    """[P] bool: whether an earlier pair of the same pixel has ``flags`` set (pairs grouped by pixel,
    ``start`` [P] the index of each pair's pixel's first pair)."""
    count = torch.cumsum(flags.to(torch.int64), 0) - flags.to(torch.int64)
    return (count - count[start]) > 0


def rasterize_torch(
    means: torch.Tensor,  # [N, 3] world (metres)
    quats: torch.Tensor,  # [N, 4] wxyz, any norm
    scales: torch.Tensor,  # [N, 3] standard deviations (metres)
    opacities: torch.Tensor,  # [N] in [0, 1]
    colors: torch.Tensor,  # [N, C]
    viewmat: Any,  # [4, 4] world-to-camera, OpenCV axes
    K: Any,  # [3, 3] pixels
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    background: torch.Tensor | None = None,  # [C]
    render_depth: bool = True,
    absgrad: bool = True,
    pairs: tuple[torch.Tensor, torch.Tensor] | None = None,
    stop_transmittance: float = T_STOP,
) -> RenderOutput:
    """Rasterize Gaussians with plain PyTorch ops (the reference twin of :func:`rasterize`).

    Parameters
    ----------
    means, quats, scales, opacities, colors, viewmat, K, width, height, near, far, background,
    render_depth, absgrad
        As in :func:`wcbench.reference_model.rasterize`. Any float dtype works; float64 inputs give
        a float64 render (used by ``gradcheck`` and as the benchmark's reference).
    pairs : (Tensor [P] int64, Tensor [P] int64), optional
        Gaussian index and pixel index (``y * width + x``) of the pairs to composite, grouped by
        pixel and in front-to-back order within a pixel. When given, the skip (alpha < 1/255) and
        stop (T < 1e-4) decisions are not re-made: exactly these pairs are composited. Used to run
        this twin in float64 on the decisions of a float32 run.
    stop_transmittance : float
        Above ``T_STOP`` (1e-4, the default), a pixel also stops once its transmittance has fallen
        below this, the pair that took it there kept: the twin of
        :func:`~wcbench.reference_model.raster.rasterizer.rasterize_image`'s.

    Returns
    -------
    RenderOutput
        Same fields as :func:`rasterize`; ``meta["backend"] == "torch"``.
    """
    viewmat_t, K_t, bg = check_inputs(means, quats, scales, opacities, colors, viewmat, K, width, height,
                                      near, far, background)
    n, n_ch = colors.shape
    dtype = means.dtype
    proj = project_torch(means, quats, scales, opacities, colors, viewmat_t, K_t, width, height,
                         near=near, far=far)
    reason = proj["reason"]
    meta = empty_meta("torch", n)
    meta.update(cull_counts(reason))

    grads_on = torch.is_grad_enabled() and any(
        t.requires_grad for t in (means, quats, scales, opacities, colors))
    m2 = proj["means2d"]  # float64
    means2d = m2.detach().to(dtype)
    means2d_abs = None
    if grads_on:
        means2d.requires_grad_(True)
        # Value unchanged, but dL/dm2 now also lands in means2d.grad.
        m2 = m2 + _to64(means2d - means2d.detach())
        if absgrad:
            means2d_abs = means2d.detach().clone().requires_grad_(True)

    visible = torch.nonzero(reason == 0).flatten()
    box = proj["boxes"]
    tiles_x = (box[visible, 1] // TILE_SIZE) - (box[visible, 0] // TILE_SIZE) + 1
    tiles_y = (box[visible, 3] // TILE_SIZE) - (box[visible, 2] // TILE_SIZE) + 1
    meta["n_tile_entries"] = int((tiles_x * tiles_y).sum())

    if pairs is None:
        gid, pix = _candidate_pairs(box, visible, width)
        # Front-to-back order within a pixel: by depth, ties by index (stable sort).
        order = torch.sort(proj["depths"].detach()[visible], stable=True).indices
        rank = torch.empty(n, dtype=torch.int64)
        rank[visible[order]] = torch.arange(visible.numel())
        perm = torch.sort(pix * max(n, 1) + rank[gid]).indices
        gid, pix = gid[perm], pix[perm]
        with torch.no_grad():
            alpha0, sigma0 = _alpha_from_pairs(proj, m2[gid], gid, pix, width)
            skip = (sigma0 < 0) | (alpha0 < ALPHA_MIN)
            log_t = torch.where(skip, 0.0, torch.log1p(-alpha0))
            start = _segment_starts(pix)
            cs = torch.cumsum(log_t, 0)
            base = (cs - log_t)[start]
            t_incl = torch.exp(cs - base)
            # Stop before T would fall below T_STOP: the stopping pair and all after it are dropped.
            stop = ~skip & (t_incl < T_STOP)
            # a sooner stop (rasterize_image's): the pair that takes T below it kept, those after dropped
            sooner = ~skip & (t_incl < stop_transmittance)
            stopped, ended = (_any_before(flags, start) for flags in (stop, sooner))
            meta["n_pairs"] = int((~stopped & ~ended).sum())
            keep = ~skip & ~stop & ~stopped & ~ended
        gid, pix = gid[keep], pix[keep]
    else:
        gid, pix = pairs[0].to(torch.int64), pairs[1].to(torch.int64)
        if gid.shape != pix.shape or gid.dim() != 1:
            raise ValueError(f"pairs must be two 1-D tensors of equal length, got {gid.shape}, {pix.shape}")
        meta["n_pairs"] = int(gid.numel())

    if means2d_abs is not None:
        mp = _AbsTap.apply(m2[gid], gid, means2d_abs)
    else:
        mp = m2[gid]
    alpha, _ = _alpha_from_pairs(proj, mp, gid, pix, width)

    hw = height * width
    log_t = torch.log1p(-alpha)  # alpha is float64 (see _alpha_from_pairs)
    if pix.numel():
        start = _segment_starts(pix)
        cs = torch.cumsum(log_t, 0)
        excl = cs - log_t
        t_excl = torch.exp(excl - excl[start])
    else:
        t_excl = log_t
    w = t_excl * alpha  # [P] blending weights
    col = _to64(proj["colors"])[gid]
    color = torch.zeros(hw, n_ch, dtype=torch.float64).index_add(0, pix, w[:, None] * col)
    t_final = torch.exp(torch.zeros(hw, dtype=torch.float64).index_add(0, pix, log_t))
    alpha_img = (1.0 - t_final).to(dtype)
    color = color.to(dtype)
    if bg is not None:
        color = color + (1.0 - alpha_img)[:, None] * bg
    depth = None
    if render_depth:
        dnum = torch.zeros(hw, dtype=torch.float64).index_add(0, pix, w * _to64(proj["depths"])[gid])
        depth = expected_depth(dnum.to(dtype), alpha_img)
        depth = depth.reshape(height, width)
    radii = torch.where((reason == 0)[:, None], torch.ceil(proj["extents"]).to(torch.int32), 0)
    return RenderOutput(color=color.reshape(height, width, n_ch), alpha=alpha_img.reshape(height, width),
                        depth=depth, means2d=means2d, means2d_abs=means2d_abs, radii=radii,
                        depths=proj["depths"].detach(), meta=meta)


def _alpha_from_pairs(
    proj: dict[str, torch.Tensor], mp: torch.Tensor, gid: torch.Tensor, pix: torch.Tensor, width: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Clamped alpha [P] (float64 holding values of the input dtype) and sigma = q / 2 [P] (input
    dtype) of pairs whose float64 2D means ``mp`` [P, 2] are gathered.

    dx = (px - a) + (0.5 - (mx - a)) with the integer anchor a = floor(mx): the same value as
    px + 0.5 - mx, without the rounding of a large pixel coordinate to the conic's dtype. Alpha is
    formed as exp(log o - sigma), the fast path's o exp(-sigma) up to rounding: autograd then never
    forms dL/dalpha * o, which overflows float32 for opacities far above 1 (pairs exist only for
    Gaussians with o >= 1/255, so the clamp inside the log changes nothing).

    Precision plan of the fast path: the value is computed in the input dtype, its gradient by
    autograd of the same formula in float64 at the same dx, dy, with the forward's clamp decisions,
    and summed per Gaussian in float64 before :func:`_to64` saturates it. Per-pair terms such as
    dL/dsigma dx^2 exceed float32 for a Gaussian at a depth near 3.4e38 (dL/dalpha ~ z / alpha
    through the expected depth): in the input dtype they were Inf, and NaN further on.
    """
    con = proj["conics"][gid]
    dtype = con.dtype
    anchor = torch.floor(mp.detach())
    off64 = 0.5 - (mp - anchor)
    ix = (pix % width) - anchor[:, 0]
    iy = torch.div(pix, width, rounding_mode="floor") - anchor[:, 1]
    with torch.no_grad():
        offset = off64.to(dtype)
        dx = ix.to(dtype) + offset[:, 0]
        dy = iy.to(dtype) + offset[:, 1]
        sigma = 0.5 * (con[:, 0] * dx * dx + con[:, 2] * dy * dy) + con[:, 1] * dx * dy
        u = torch.log(proj["opacities"].clamp_min(ALPHA_MIN))[gid] - sigma
        # Exponents above 0 give alpha > 1, clamped to ALPHA_MAX anyway: capping them first keeps
        # exp finite (o near float32's max at sigma ~ 0 would be Inf).
        e = torch.exp(u.clamp_max(0.0))
        alpha = torch.clamp(e, max=ALPHA_MAX).double()
    needs_grad = any(t.requires_grad for t in (mp, proj["conics"], proj["opacities"]))
    if not (torch.is_grad_enabled() and needs_grad):
        return alpha, sigma
    # Where the forward's clamps pass the gradient (as torch.clamp_max and torch.clamp do).
    live = (u <= 0.0) & (e <= ALPHA_MAX)
    c64 = _to64(proj["conics"])[gid]
    dx64 = dx.double() + (off64[:, 0] - off64[:, 0].detach())  # the forward's dx, d/d offset = 1
    dy64 = dy.double() + (off64[:, 1] - off64[:, 1].detach())
    sigma64 = 0.5 * (c64[:, 0] * dx64 * dx64 + c64[:, 2] * dy64 * dy64) + c64[:, 1] * dx64 * dy64
    u64 = torch.log(_to64(proj["opacities"].clamp_min(ALPHA_MIN)))[gid] - sigma64
    a64 = torch.exp(torch.where(live, u64, 0.0))  # exp of 0 where clamped: finite, zero gradient
    # The forward's value exactly (x + 0), the float64 formula's gradient.
    return alpha + torch.where(live, a64 - a64.detach(), 0.0), sigma
