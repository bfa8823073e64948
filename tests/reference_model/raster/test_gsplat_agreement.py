"""Our rasterizer against gsplat (docs/workstation.md): the same Gaussians, the same camera.

On CPU (gsplat installed: its pure-torch projection ``gsplat.cuda._torch_impl`` runs anywhere), the
projection (2D means, conics, depths) and an image composited from gsplat's projection by a dense
front-to-back reference, with the gradients of means, scales and colours; on a CUDA device (marked
``cuda``), gsplat's CUDA rasterizer (:func:`rasterize_gsplat`) against ours, within the 1e-3 mean
absolute difference issue 38 asks for. Skipped, with the reason, without gsplat or without CUDA.
"""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from wcbench.reference_model.raster.common import ALPHA_MAX, ALPHA_MIN  # noqa: E402
from wcbench.reference_model.raster.rasterizer import rasterize  # noqa: E402
from wcbench.reference_model.raster.torch_twin import project_torch  # noqa: E402

pytestmark = pytest.mark.model

W, H = 48, 32
#: The projection in float64: the same EWA formula, so rounding only.
PROJ_ATOL_PX, CONIC_RTOL = 1e-9, 1e-9
#: Image: ours cuts each Gaussian at its 3-sigma box (gsplat at 3.33 sigma, the dense reference
#: nowhere): the tails beyond change a pixel by at most ~0.005 x opacity, rarely.
IMAGE_MEAN_ABS = 1e-3
#: Gradients (float32 numba backward vs autograd through the float64 reference): relative L2 error,
#: the same tails, not rounding, dominate.
GRAD_REL = 0.05


def _gaussians(n: int = 40, seed: int = 0, device: str = "cpu") -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    z = 3.0 + 4.0 * torch.rand(n, generator=g)
    # well inside the frustum: gsplat clamps centres beyond 1.3 x the field of view, we do not
    x = (torch.rand(n, generator=g) - 0.5) * 0.8 * z
    y = (torch.rand(n, generator=g) - 0.5) * 0.5 * z
    out = {
        "means": torch.stack([x, y, z], 1),
        "quats": torch.randn(n, 4, generator=g),
        "scales": 0.05 + 0.15 * torch.rand(n, 3, generator=g),
        "opacities": 0.2 + 0.6 * torch.rand(n, generator=g),
        "colors": torch.rand(n, 3, generator=g),
    }
    return {k: v.to(device) for k, v in out.items()}


def _camera() -> tuple[torch.Tensor, torch.Tensor]:
    K = torch.tensor([[40.0, 0.0, W / 2], [0.0, 40.0, H / 2], [0.0, 0.0, 1.0]])
    return torch.eye(4), K


def _gsplat_torch():
    pytest.importorskip("gsplat", reason="gsplat is not installed (pip install \"wcbench[cuda]\")")
    try:
        from gsplat.cuda import _torch_impl
    except ImportError as exc:  # pragma: no cover - depends on gsplat's layout
        pytest.skip(f"gsplat's pure-torch reference does not import: {exc}")
    return _torch_impl


def _dense_composite(means2d, conics, depths, opacities, colors):
    """Front-to-back compositing of projected Gaussians over every pixel, no box, no early stop:
    the obviously correct image of a projection (float64), with our alpha guards."""
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float64) + 0.5, torch.arange(W, dtype=torch.float64) + 0.5,
                            indexing="ij")
    order = torch.argsort(depths)
    T = torch.ones(H, W, dtype=torch.float64)
    image = torch.zeros(H, W, colors.shape[1], dtype=torch.float64)
    for i in order.tolist():
        dx, dy = xs - means2d[i, 0], ys - means2d[i, 1]
        a, b, c = conics[i]
        alpha = (opacities[i] * torch.exp(-0.5 * (a * dx * dx + 2 * b * dx * dy + c * dy * dy))).clamp(max=ALPHA_MAX)
        alpha = torch.where(alpha < ALPHA_MIN, torch.zeros_like(alpha), alpha)
        image = image + (T * alpha)[..., None] * colors[i]
        T = T * (1 - alpha)
    return image


def test_our_projection_matches_gsplats_pure_torch_projection():
    impl = _gsplat_torch()
    g = {k: v.double() for k, v in _gaussians().items()}
    viewmat, K = (t.double() for t in _camera())
    ours = project_torch(g["means"], g["quats"], g["scales"], g["opacities"], g["colors"], viewmat, K, W, H)
    covars, _ = impl._quat_scale_to_covar_preci(g["quats"], g["scales"], compute_preci=False)
    _, means2d, depths, conics, _ = impl._fully_fused_projection(
        g["means"], covars, viewmat[None], K[None], W, H, eps2d=0.3)
    visible = ours["reason"] == 0
    assert visible.sum() >= 30
    torch.testing.assert_close(ours["means2d"][visible], means2d[0][visible].double(), atol=PROJ_ATOL_PX, rtol=0)
    torch.testing.assert_close(ours["depths"][visible], depths[0][visible], atol=1e-9, rtol=0)
    # gsplat stores the conic's off-diagonal as -(c01 + c10) / 2 / det, ours as -c01 / det: the same number
    torch.testing.assert_close(ours["conics"][visible], conics[0][visible], atol=0, rtol=CONIC_RTOL)


def test_our_image_and_gradients_match_a_composite_of_gsplats_projection():
    impl = _gsplat_torch()
    g32 = _gaussians()
    viewmat, K = _camera()
    leaves = {k: v.clone().requires_grad_(k in ("means", "scales", "colors")) for k, v in g32.items()}
    ours = rasterize(leaves["means"], leaves["quats"], leaves["scales"], leaves["opacities"], leaves["colors"],
                     viewmat, K, W, H, render_depth=False)
    weights = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(1))
    (ours.color * weights).sum().backward()

    ref_leaves = {k: v.double().clone().requires_grad_(k in ("means", "scales", "colors")) for k, v in g32.items()}
    covars, _ = impl._quat_scale_to_covar_preci(ref_leaves["quats"], ref_leaves["scales"], compute_preci=False)
    _, means2d, depths, conics, _ = impl._fully_fused_projection(
        ref_leaves["means"], covars, viewmat.double()[None], K.double()[None], W, H, eps2d=0.3)
    ref = _dense_composite(means2d[0], conics[0], depths[0], ref_leaves["opacities"], ref_leaves["colors"])
    (ref * weights.double()).sum().backward()

    diff = (ours.color.detach().double() - ref.detach()).abs().mean().item()
    assert diff < IMAGE_MEAN_ABS, f"mean |ours - gsplat projection composite| = {diff:.2e}"
    for name in ("means", "scales", "colors"):
        a, b = leaves[name].grad.double(), ref_leaves[name].grad
        rel = ((a - b).norm() / b.norm()).item()
        assert rel < GRAD_REL, f"d/d{name}: relative L2 error {rel:.3f}"


@pytest.mark.cuda
def test_gsplats_cuda_rasterizer_agrees_with_ours_within_1e3():
    from wcbench.reference_model.raster.gsplat_backend import gsplat_problem, rasterize_gsplat

    problem = gsplat_problem()
    if problem is not None:
        pytest.skip(problem)
    viewmat, K = _camera()
    cpu = {k: v.clone().requires_grad_(k in ("means", "scales", "colors")) for k, v in _gaussians().items()}
    gpu = {k: v.detach().cuda().requires_grad_(k in ("means", "scales", "colors")) for k, v in cpu.items()}
    weights = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(1))
    ours = rasterize(cpu["means"], cpu["quats"], cpu["scales"], cpu["opacities"], cpu["colors"], viewmat, K, W, H)
    theirs = rasterize_gsplat(gpu["means"], gpu["quats"], gpu["scales"], gpu["opacities"], gpu["colors"],
                              viewmat, K, W, H)
    (ours.color * weights).sum().backward()
    (theirs.color * weights.cuda()).sum().backward()
    diff = (ours.color.detach() - theirs.color.detach().cpu()).abs().mean().item()
    alpha_diff = (ours.alpha.detach() - theirs.alpha.detach().cpu()).abs().mean().item()
    rel = {name: ((cpu[name].grad - gpu[name].grad.cpu()).norm() / cpu[name].grad.norm()).item()
           for name in ("means", "scales", "colors")}
    # the workstation check's log keeps the measured numbers (pytest -s), not only pass or fail
    print(f"\ngsplat CUDA vs ours: mean |colour diff| {diff:.3e}, mean |alpha diff| {alpha_diff:.3e}, gradients' "
          "relative L2 error " + ", ".join(f"{k} {v:.4f}" for k, v in rel.items()))
    assert diff < 1e-3, f"mean |ours - gsplat CUDA| = {diff:.2e}"
    assert alpha_diff < 1e-3
    assert theirs.means2d_abs is not None and theirs.means2d_abs.grad is not None  # the AbsGS statistic
    for name, value in rel.items():
        assert value < GRAD_REL, f"d/d{name}: relative L2 error {value:.3f}"


def test_the_absolute_gradient_gsplat_sets_in_its_backward_reaches_means2d_abs():
    # gsplat's rasterization sets ``means2d.absgrad`` in its backward (its DefaultStrategy reads it);
    # the backend's hook copies it into ``means2d_abs.grad``, where the trainer reads the AbsGS
    # statistic. A stand-in for gsplat's autograd function, on the CPU:
    from wcbench.reference_model.raster.gsplat_backend import _absgrad_into

    class _Splat(torch.autograd.Function):
        @staticmethod
        def forward(ctx, means2d):
            ctx.save_for_backward(means2d)
            return means2d.sum(-1) * 2.0

        @staticmethod
        def backward(ctx, grad):
            (means2d,) = ctx.saved_tensors
            per_pixel = grad[..., None].expand(*grad.shape, 2) * 2.0
            means2d.absgrad = per_pixel.abs() + 1.0  # what gsplat accumulates per pixel, here a known value
            return per_pixel

    leaf = torch.randn(1, 5, 2, requires_grad=True)
    means2d = leaf * 1.0  # a non-leaf, as gsplat's projected centres are
    holder = torch.zeros(5, 2)
    _absgrad_into(holder, means2d)
    out = _Splat.apply(means2d)
    (out * torch.tensor([[1.0, -2.0, 3.0, -4.0, 5.0]])).sum().backward()
    expected = torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0])[:, None].expand(5, 2) * 2.0 + 1.0
    torch.testing.assert_close(holder.grad, expected)
