"""The rasterizer: fast numba path against the pure-torch twin, gradcheck, closed-form renders."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pytest

if TYPE_CHECKING:
    from torch import Tensor

torch = pytest.importorskip("torch")

from raster_scenes import args, look_from, pinhole, random_scene  # noqa: E402

from wcbench.reference_model import RenderOutput, rasterize, rasterize_torch  # noqa: E402
from wcbench.reference_model.raster.common import ALPHA_MIN, CULL_KEYS, EPS2D  # noqa: E402

# Fast vs twin, forward. Both evaluate the same float32 alpha per pair; they differ in exp (a
# Cephes polynomial vs torch's, ~1 ulp) and in how transmittance is formed (a float32 running
# product vs exp of a float64 sum of log(1 - alpha)), a few 1e-7 after tens of layers.
FWD_ATOL = 2e-6
# Expected depth is a weighted mean of camera z (~5 m here): the same relative error times z.
DEPTH_RTOL = 2e-6
# Gradients: float32 lane sums in a different order than autograd's, and conic / covariance
# chains evaluated in float32 by both: 1e-4 of the largest gradient of that parameter.
GRAD_RTOL = 1e-4

W, H = 64, 48
K = pinhole(W, H, 60.0)
V = look_from()


def _loss(out: RenderOutput, seed: int = 0) -> Tensor:
    g = torch.Generator().manual_seed(seed)
    wc = torch.rand(out.color.shape, generator=g)
    wa = torch.rand(out.alpha.shape, generator=g)
    loss = (out.color * wc).sum() + (out.alpha * wa).sum()
    if out.depth is not None:
        loss = loss + 0.1 * (out.depth * torch.rand(out.depth.shape, generator=g)).sum()
    return loss


def _grads(out: RenderOutput, params: list[Tensor]) -> list[Tensor]:
    extra = [out.means2d] + ([out.means2d_abs] if out.means2d_abs is not None else [])
    return list(torch.autograd.grad(_loss(out), params + extra))


def _assert_grads_close(fast: list[Tensor], ref: list[Tensor], names: list[str]) -> None:
    for name, a, b in zip(names, fast, ref):
        scale = max(float(b.abs().max()), 1e-6)
        err = float((a - b).abs().max())
        assert err <= GRAD_RTOL * scale, f"{name}: max |fast - twin| = {err:.3g}, largest gradient {scale:.3g}"


@pytest.mark.parametrize(
    ("seed", "n", "channels", "render_depth", "background"),
    [
        (0, 300, 3, True, False),
        (1, 500, 3, False, True),
        (2, 200, 5, True, True),
        (3, 400, 1, False, False),
        (4, 300, 4, True, True),  # RGB + exact-fog transmittance
        (5, 200, 15, True, False),  # four weathers and three hazes: the largest fused variant in use
        (6, 150, 17, True, True),  # more than _MAX_FUSED channels: the separate per-channel loops
    ],
)
def test_fast_path_matches_twin_forward_and_gradients(
    seed: int, n: int, channels: int, render_depth: bool, background: bool
) -> None:
    params = random_scene(n, seed=seed, channels=channels)
    bg = torch.linspace(0.1, 0.9, channels) if background else None
    outs = {}
    for backend in ("numba", "torch"):
        outs[backend] = rasterize(*args(params), V, K, W, H, background=bg, render_depth=render_depth,
                                  backend=backend)
    fast, ref = outs["numba"], outs["torch"]
    assert fast.meta["backend"] == "numba" and ref.meta["backend"] == "torch"
    torch.testing.assert_close(fast.color, ref.color, atol=FWD_ATOL, rtol=0)
    torch.testing.assert_close(fast.alpha, ref.alpha, atol=FWD_ATOL, rtol=0)
    if render_depth:
        torch.testing.assert_close(fast.depth, ref.depth, rtol=DEPTH_RTOL, atol=1e-6)
    else:
        assert fast.depth is None and ref.depth is None
    torch.testing.assert_close(fast.means2d, ref.means2d, atol=1e-4, rtol=1e-6)
    assert torch.equal(fast.radii, ref.radii)
    for key in ("n_visible", "n_tile_entries", "n_pairs", *CULL_KEYS.values()):
        assert fast.meta[key] == ref.meta[key], key
    names = ["means", "quats", "scales", "opacities", "colors", "means2d", "means2d_abs"]
    _assert_grads_close(_grads(fast, args(params)), _grads(ref, args(params)), names)


@pytest.mark.parametrize("n", [0, 1, 7, 5000])
def test_the_radix_depth_order_is_a_stable_sort_of_the_depth_bits(n) -> None:
    pytest.importorskip("numba")
    from wcbench.reference_model.raster.kernels import depth_order

    rng = np.random.default_rng(n)
    depths = rng.choice(np.float32([0.01, 1.0, 2.5, 1e3, 3.4e38]), n) if n < 10 else \
        np.concatenate([rng.uniform(0.01, 80.0, n - 40).astype(np.float32), np.full(40, 7.0, np.float32)])
    depths = rng.permutation(depths).astype(np.float32)
    bits = depths.view(np.uint32)
    got = depth_order(bits)
    # the twin: numpy's stable sort; ties keep index order, so the order equals sorting (depth, index)
    np.testing.assert_array_equal(got, np.argsort(bits, kind="stable"))
    keys = (bits.astype(np.uint64) << np.uint64(32)) | np.arange(n, dtype=np.uint64)
    np.testing.assert_array_equal(got, (np.sort(keys) & np.uint64(0xFFFFFFFF)).astype(np.int64))
    edge = np.array([0xFFFFFFFF, 0, 0x80000000, 0x7FF, 0x800, 0], np.uint32)  # every 11-bit digit boundary
    np.testing.assert_array_equal(depth_order(edge), np.argsort(edge, kind="stable"))


def test_the_compositing_exp_is_within_one_and_a_half_ulp_of_the_float64_exp() -> None:
    """``_fexp`` (fused multiply-adds) against numpy's float64 exp on its whole clamped range; the
    bound 1.5 ulp sits above the 1.0 measured, far below a wrong constant or reduction step."""
    numba = pytest.importorskip("numba")
    from wcbench.reference_model.raster.kernels import _fexp

    @numba.njit
    def fexp_all(x: np.ndarray, out: np.ndarray) -> None:
        for i in range(x.size):
            out[i] = _fexp(x[i])

    x = np.concatenate([np.linspace(-87.0, 88.0, 1_000_001, dtype=np.float32), np.zeros(1, np.float32)])
    got = np.empty_like(x)
    fexp_all(x, got)
    ref = np.exp(x.astype(np.float64))
    ulp = np.abs(got - ref) / np.spacing(ref.astype(np.float32)).astype(np.float64)
    assert ulp.max() < 1.5, f"largest error {ulp.max():.3f} ulp at x = {x[np.argmax(ulp)]}"
    assert got[-1] == 1.0  # exp(0) exactly: an empty Gaussian centre keeps alpha = opacity


def test_fast_path_is_deterministic_and_thread_count_independent() -> None:
    numba = pytest.importorskip("numba")
    params = random_scene(400, seed=7)
    results = []
    for threads in (1, numba.config.NUMBA_NUM_THREADS):
        numba.set_num_threads(threads)
        try:
            out = rasterize(*args(params), V, K, W, H, backend="numba")
            results.append([out.color, *_grads(out, args(params))])
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    for a, b in zip(*results):
        assert torch.equal(a, b)


def test_gradcheck_twin_float64() -> None:
    torch.manual_seed(0)
    params = random_scene(4, seed=11, depth=3.0, spread=0.3, scale=(0.1, 0.3), dtype=torch.float64)
    with torch.no_grad():
        params["opacities"].clamp_(0.2, 0.8)  # far from the 0.99 clamp, where alpha has a kink

    def render(*p: Tensor) -> tuple[Tensor, ...]:
        out = rasterize_torch(*p, V.double(), pinhole(10, 8, 12.0).double(), 10, 8,
                              background=torch.tensor([0.2, 0.4, 0.6], dtype=torch.float64))
        assert out.depth is not None
        return out.color, out.alpha, out.depth

    # A perturbation of 1e-6 must not cross a skip (alpha = 1/255) or stop decision; the scene is
    # checked for that margin implicitly: gradcheck would fail on a jump.
    assert torch.autograd.gradcheck(render, tuple(args(params)), eps=1e-6, atol=1e-5, rtol=1e-4)


def test_auto_backend_sends_float64_to_the_twin() -> None:
    params = random_scene(20, seed=3, dtype=torch.float64)
    out = rasterize(*args(params), V, K, W, H)
    assert out.meta["backend"] == "torch" and out.color.dtype == torch.float64
    with pytest.raises(ValueError, match="float32"):
        rasterize(*args(params), V, K, W, H, backend="numba")


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_isotropic_gaussian_renders_the_closed_form(backend: str) -> None:
    """A sphere of std s at distance d on the optical axis projects to N(c, (f s / d)^2 + 0.3)."""
    f, s, d, o = 50.0, 0.1, 2.0, 0.9
    w, h = 40, 30
    Kc = torch.tensor([[f, 0.0, 20.3], [0.0, f, 14.6], [0.0, 0.0, 1.0]])
    params = {"means": torch.tensor([[0.0, 0.0, d]]), "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]]),
              "scales": torch.full((1, 3), s), "opacities": torch.tensor([o]),
              "colors": torch.tensor([[1.0, 0.5, 0.25]])}
    out = rasterize(*args(params), V, Kc, w, h, backend=backend)
    var = (f * s / d) ** 2 + EPS2D
    ext = 3.0 * math.sqrt(var)  # 3 sigma (the opacity-aware bound is wider at o = 0.9)
    jj, ii = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64),
                            indexing="ij")
    dx, dy = ii + 0.5 - 20.3, jj + 0.5 - 14.6
    alpha = o * torch.exp(-0.5 * (dx**2 + dy**2) / var)
    inside = (dx.abs() <= ext) & (dy.abs() <= ext) & (alpha >= ALPHA_MIN)
    expected = torch.where(inside, alpha.clamp(max=0.99), 0.0).float()
    torch.testing.assert_close(out.alpha, expected, atol=1e-6, rtol=0)
    torch.testing.assert_close(out.color[..., 1], 0.5 * expected, atol=1e-6, rtol=0)
    assert out.depth is not None
    torch.testing.assert_close(out.depth[inside], torch.full_like(out.depth[inside], d), rtol=1e-6, atol=0)
    assert out.radii.tolist() == [[math.ceil(ext), math.ceil(ext)]]
    assert out.means2d[0].tolist() == pytest.approx([20.3, 14.6], abs=1e-5)


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_two_opaque_layers_composite_in_depth_order(backend: str) -> None:
    red, blue = [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]
    flat = [[2.0, 2.0, 0.01]]
    near = {"means": [[0.0, 0.0, 2.0]], "colors": [red]}
    far = {"means": [[0.0, 0.0, 4.0]], "colors": [blue]}
    results = []
    for first, second in ((near, far), (far, near)):  # input order must not matter
        params = {"means": torch.tensor(first["means"] + second["means"]),
                  "quats": torch.tensor([[1.0, 0, 0, 0]] * 2), "scales": torch.tensor(flat * 2),
                  "opacities": torch.tensor([0.98, 0.9]) if first is near else torch.tensor([0.9, 0.98]),
                  "colors": torch.tensor(first["colors"] + second["colors"])}
        results.append(rasterize(*args(params), V, K, W, H, backend=backend))
    for out in results:
        c = out.color[H // 2, W // 2]
        # At the center both Gaussians have G = exp(-q/2) with q tiny; alphas ~0.98 (front), 0.9.
        a1, a2 = float(out.alpha[H // 2, W // 2]), None
        assert c[0] > 0.97 and c[2] < 0.03 and c[1] == 0.0
        a2 = (a1 - float(c[0])) / (1 - float(c[0]))  # alpha = a_front + (1 - a_front) a_back
        assert 0.85 < a2 <= 0.9
        assert float(c[2]) == pytest.approx((1 - float(c[0])) * a2, abs=1e-6)
        assert out.depth is not None
        expected_depth = (float(c[0]) * 2.0 + float(c[2]) * 4.0) / a1
        assert float(out.depth[H // 2, W // 2]) == pytest.approx(expected_depth, rel=1e-6)
    torch.testing.assert_close(results[0].color, results[1].color, atol=1e-7, rtol=0)


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_depth_of_a_fronto_parallel_plane_is_its_distance(backend: str) -> None:
    d = 7.5
    xs = torch.linspace(-4.0, 4.0, 41)
    gx, gy = torch.meshgrid(xs, xs * 0.75, indexing="xy")
    n = gx.numel()
    params = {"means": torch.stack([gx.flatten(), gy.flatten(), torch.full((n,), d)], -1),
              "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1), "scales": torch.full((n, 3), 0.12),
              "opacities": torch.full((n,), 0.7), "colors": torch.rand(n, 3)}
    out = rasterize(*args(params), V, K, W, H, backend=backend)
    assert out.depth is not None
    assert bool((out.alpha > 0.9).all())
    torch.testing.assert_close(out.depth, torch.full_like(out.depth, d), rtol=1e-6, atol=0)


def test_camera_pose_moves_the_image() -> None:
    """Moving the camera right by dx shifts the image left by f dx / z (world-to-camera convention)."""
    params = random_scene(200, seed=5, spread=0.8)
    base = rasterize(*args(params), V, K, W, H)
    shifted = rasterize(*args(params), look_from(tx=5.0 * 4 / 60.0), K, W, H)  # 4 px at z = 5
    # Only Gaussians near z = 5 shift by exactly 4 px: compare image centroids of alpha.
    xs = torch.arange(W, dtype=torch.float32)
    a0, a1 = base.alpha.detach(), shifted.alpha.detach()
    cx0 = float((a0.sum(0) * xs).sum() / a0.sum())
    cx1 = float((a1.sum(0) * xs).sum() / a1.sum())
    assert cx0 - cx1 == pytest.approx(4.0, abs=1.0)


def test_culled_gaussians_get_zero_gradient_and_are_counted() -> None:
    params = random_scene(50, seed=9)
    with torch.no_grad():
        params["means"][0, 0] = float("nan")
        params["scales"][1, 2] = float("inf")
        params["means"][2, 2] = -1.0  # behind the camera
        params["means"][3] = torch.tensor([100.0, 0.0, 5.0])  # far off screen
        params["opacities"][4] = 0.0
        params["colors"][5, 0] = float("nan")
    for backend in ("numba", "torch"):
        out = rasterize(*args(params), V, K, W, H, backend=backend)
        assert out.meta["culled_nonfinite"] == 3
        assert out.meta["culled_near_far"] == 1
        assert out.meta["culled_offscreen"] >= 1
        assert out.meta["culled_transparent"] == 1
        assert bool(torch.isfinite(out.color).all())
        grads = _grads(out, args(params))
        for g in grads:
            assert bool(torch.isfinite(g).all())
        for i in range(5):
            assert float(grads[0][i].abs().sum()) == 0.0
            assert out.radii[i].tolist() == [0, 0]


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_centres_beyond_float32_depth_are_culled_at_any_far(backend: str) -> None:
    """A finite view that scales z by 3.4e38 puts Gaussians at z = 2 and 4 m at depth 6.8e38 and
    1.4e39: finite in the float64 projection, Inf in the float32 depth image. With ``far = inf``
    they were drawn, with NaN depth (numba) and NaN gradients (both); the hostile-number suite's
    camera cases found it. They are culled as beyond far; a centre at exactly 3.4e38 is drawn."""
    f32_max = float(np.finfo(np.float32).max)
    means = torch.tensor([[0.0, 0.0, 2.0], [0.5, -0.2, 4.0], [0.0, 0.0, 1.0]], requires_grad=True)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 3, requires_grad=True)
    scales = torch.tensor([[0.3, 0.3, 0.3], [1e-3, 0.5, 2.0], [0.3, 0.3, 0.3]], requires_grad=True)
    opacities = torch.tensor([0.8, 0.5, 0.8], requires_grad=True)
    colors = torch.tensor([[0.2, 0.5, 0.9], [1.0, 0.0, 0.3], [0.5, 0.5, 0.5]], requires_grad=True)
    params = [means, quats, scales, opacities, colors]
    view = torch.zeros(4, 4)
    view[2, 2] = f32_max
    intrinsics = torch.tensor([[1e-45, 0.0, 0.0], [0.0, 1e-45, 0.0], [0.0, 0.0, 1.0]])
    out = rasterize(*params, view, intrinsics, 2, 2, near=0.5, far=math.inf, backend=backend)
    # the third Gaussian lands at exactly 3.4e38 m, the float32 maximum: drawn, not culled
    assert out.meta["culled_near_far"] == 2 and out.meta["n_visible"] == 1
    assert out.depth is not None and float(out.depth.detach().max()) == f32_max
    loss = out.color.sum() + out.alpha.sum() + out.depth.sum()
    for g in torch.autograd.grad(loss, params):
        assert bool(torch.isfinite(g).all())


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_bad_inputs_raise_value_errors_naming_the_argument(backend: str) -> None:
    p = args(random_scene(5, seed=0))
    with pytest.raises(ValueError, match="quats"):
        rasterize(p[0], p[1][:, :3], *p[2:], V, K, W, H, backend=backend)
    with pytest.raises(ValueError, match="viewmat"):
        rasterize(*p, V[:3], K, W, H, backend=backend)
    with pytest.raises(ValueError, match="background"):
        rasterize(*p, V, K, W, H, background=torch.zeros(4), backend=backend)
    with pytest.raises(ValueError, match="near"):
        rasterize(*p, V, K, W, H, near=2.0, far=1.0, backend=backend)
    with pytest.raises(ValueError, match="backend"):
        rasterize(*p, V, K, W, H, backend="cuda")


def test_float64_reference_on_the_fast_path_decisions() -> None:
    """The benchmark's reference: the twin in float64 on the pairs the float32 fast path composited."""
    from wcbench.reference_model.raster.kernels import RenderJob

    params = random_scene(300, seed=4)
    out = rasterize(*args(params), V, K, W, H, backend="numba")
    job = RenderJob(*[p.detach() for p in args(params)], V, K, W, H, near=0.01, far=1e10, render_depth=True)
    job.forward()
    gid, pix = job.composited_pairs()
    assert 0 < len(gid) <= out.meta["n_pairs"]
    ref = rasterize_torch(*[p.detach().double() for p in args(params)], V.double(), K.double(), W, H,
                          pairs=(torch.from_numpy(gid), torch.from_numpy(pix)))
    # float32 per-pair math against float64: a few float32 ulps of values in [0, 1].
    torch.testing.assert_close(out.color.double(), ref.color, atol=2e-6, rtol=0)
    torch.testing.assert_close(out.alpha.double(), ref.alpha, atol=2e-6, rtol=0)
    assert out.depth is not None and ref.depth is not None
    # Depth is a weighted mean of z: float32 weight errors (~1e-7 relative per layer) move it by
    # up to ~1e-6 of z when the layers of a pixel span 2-8 m, as in this random cloud.
    torch.testing.assert_close(out.depth.double(), ref.depth, rtol=DEPTH_RTOL, atol=0)


def test_missing_numba_falls_back_to_the_twin_with_one_warning(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys
    import warnings

    import wcbench.reference_model.raster as package
    from wcbench.reference_model import _numba_backend
    from wcbench.reference_model.raster import rasterizer as raster

    monkeypatch.setattr(_numba_backend, "_loaded", {})
    monkeypatch.setattr(_numba_backend, "_failed", {})
    monkeypatch.setattr(raster, "_warned", False)
    monkeypatch.delattr(package, "kernels", raising=False)
    monkeypatch.setitem(sys.modules, "wcbench.reference_model.raster.kernels", None)  # import fails
    params = random_scene(30, seed=1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outs = [rasterize(*args(params), V, K, W, H) for _ in range(2)]
    assert [o.meta["backend"] for o in outs] == ["torch", "torch"]
    assert len([w for w in caught if "numba backend unavailable" in str(w.message)]) == 1
    with pytest.raises(ValueError, match="numba is unavailable"):
        rasterize(*args(params), V, K, W, H, backend="numba")


# ---- numeric guards (docs/design.md §9) -------------------------------------------------------

#: Needles: one axis 1e30 times another. Their 2D covariance determinant a c - b^2 is a difference
#: of ~1e120 numbers; both backends form it from the minors of J V R diag(s) instead.
NEEDLE_SCALES = [(1e-30, 1e30, 1.0), (1e30, 1e-30, 1.0), (1e-30, 1e-30, 1e30), (0.0, 1e10, 0.0), (0.05, 1e19, 0.02),
                 (1e30, 1e30, 1e-30)]


def _needle_scene() -> list[Tensor]:
    g = torch.Generator().manual_seed(5)
    n = len(NEEDLE_SCALES)
    means = torch.rand(n, 3, generator=g) * torch.tensor([1.0, 0.6, 3.0]) + torch.tensor([-0.5, -0.3, 2.0])
    params = [means, torch.randn(n, 4, generator=g), torch.tensor(NEEDLE_SCALES),
              torch.rand(n, generator=g) * 0.5 + 0.2, torch.rand(n, 3, generator=g)]
    return [p.requires_grad_(True) for p in params]


def test_needle_gaussians_are_drawn_by_both_backends_alike() -> None:
    from wcbench.reference_model.raster.torch_twin import _project

    params = _needle_scene()
    w, h, K_n = 32, 24, pinhole(32, 24, 30.0)
    # The test can fail: a c - b^2 of these covariances is rounding noise, <= 0 for some of them.
    with torch.no_grad():
        _, cov, det, _ = _project(*[p.double() for p in params[:3]], V.double(), K_n.double(), w, h)
        naive = cov[:, 0] * cov[:, 2] - cov[:, 1] * cov[:, 1]
    assert bool((naive <= 0).any()) and bool((det > 0).all())
    outs = {b: rasterize(*params, V, K_n, w, h, backend=b) for b in ("numba", "torch")}
    fast, ref = outs["numba"], outs["torch"]
    assert fast.meta["n_visible"] == ref.meta["n_visible"] == len(NEEDLE_SCALES)
    torch.testing.assert_close(fast.color, ref.color, atol=FWD_ATOL, rtol=0)
    torch.testing.assert_close(fast.alpha, ref.alpha, atol=FWD_ATOL, rtol=0)
    names = ["means", "quats", "scales", "opacities", "colors", "means2d", "means2d_abs"]
    _assert_grads_close(_grads(fast, params), _grads(ref, params), names)


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_background_must_be_finite_and_within_the_color_bound(backend: str) -> None:
    from wcbench.reference_model.raster.common import MAX_ABS_COLOR

    p = args(random_scene(5, seed=0))
    for bad in ([math.nan, 0.0, 0.0], [0.0, math.inf, 0.0], [0.0, 0.0, 1e30]):
        with pytest.raises(ValueError, match="background must be finite"):
            rasterize(*p, V, K, W, H, background=torch.tensor(bad), backend=backend)
    with pytest.raises(ValueError, match="background must be"):
        rasterize(*p, V, K, W, H, background=["a", "b", "c"], backend=backend)
    out = rasterize(*p, V, K, W, H, background=torch.full((3,), MAX_ABS_COLOR), backend=backend)
    assert bool(torch.isfinite(out.color).all())


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_huge_colors_are_refused_and_nonfinite_ones_culled(backend: str) -> None:
    p = args(random_scene(6, seed=2))
    huge = p[4].detach().clone()
    huge[3, 1] = 3e38
    with pytest.raises(ValueError, match=r"colors must be within \+-1e\+15"):
        rasterize(*p[:4], huge, V, K, W, H, backend=backend)
    nan = p[4].detach().clone()
    nan[3, 1] = math.nan
    out = rasterize(*p[:4], nan.requires_grad_(True), V, K, W, H, backend=backend)
    assert out.meta["culled_nonfinite"] == 1 and bool(torch.isfinite(out.color).all())
    with pytest.raises(ValueError, match="width and height"):
        rasterize(*p, V, K, math.nan, H, backend=backend)


def test_gradients_beyond_float32_saturate_alike_in_both_backends() -> None:
    """A Gaussian 3.4e38 m long seen almost end-on: its exact gradients exceed float32 (the float64
    twin shows them); both backends give +-3.4e38 there instead of Inf or NaN, the rest as usual."""
    f32_max = float(torch.finfo(torch.float32).max)
    g = [((0.0, 0.0, 1.02139), (-1.0, 0.0, 1e-30, 0.01), (1e-38, 1.0, 3.4028234e38), 1.02139, (0.0, -1.0, -1e15))]
    K_s = torch.tensor([[0.5, 0.0, 4.5], [0.0, 0.5, 7.5], [0.0, 0.0, 1.0]])
    grads = {}
    for dtype, backend in ((torch.float32, "numba"), (torch.float32, "torch"), (torch.float64, "torch")):
        p = [torch.tensor(c, dtype=dtype).requires_grad_(True) for c in zip(*g)]
        out = rasterize(*p, V.to(dtype), K_s.to(dtype), 9, 15, far=10.0, background=torch.zeros(3, dtype=dtype),
                        backend=backend)
        assert out.depth is not None
        loss = out.color.sum() - out.alpha.sum() + out.depth.sum()
        grads[(dtype, backend)] = torch.autograd.grad(loss, p)
    exact = grads[(torch.float64, "torch")]
    assert max(float(e.abs().max()) for e in exact) > f32_max  # the test can fail: there is an overflow
    for key in ((torch.float32, "numba"), (torch.float32, "torch")):
        for got, e in zip(grads[key], exact):
            assert bool(torch.isfinite(got).all()), key
            over = e.abs() > f32_max
            assert torch.equal(got[over].double(), torch.sign(e[over]) * f32_max), key
