"""The inference-only compositing (``rasterize_image``) against the training forward and the twin."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from raster_scenes import args, look_from, pinhole, random_scene  # noqa: E402

from wcbench.reference_model import rasterize, rasterize_torch  # noqa: E402
from wcbench.reference_model.raster.common import ALPHA_MIN  # noqa: E402
from wcbench.reference_model.raster.rasterizer import rasterize_image  # noqa: E402

# Against the training forward: the same pairs with the same float32 alpha; the image kernel keeps
# transmittance and sums in float32 where the forward keeps float64, so a sum of tens of layers in
# [0, 1] differs by a few float32 ulps (measured: <= 1e-6 on the pandaset_002 model's frames).
IMAGE_ATOL = 2e-6
# Against the twin: its own ~1 ulp exp and log-sum transmittance come on top (FWD_ATOL of
# test_rasterizer.py, 2e-6).
TWIN_ATOL = 4e-6
DEPTH_RTOL = 4e-6

W, H = 64, 48
K = pinhole(W, H, 60.0)
V = look_from()


def _detached(params: dict) -> list:
    return [p.detach() for p in args(params)]


@pytest.mark.parametrize(
    ("seed", "n", "channels", "render_depth", "background"),
    [
        (0, 300, 3, True, False),
        (1, 500, 3, False, True),
        (2, 200, 1, True, True),
        (3, 400, 4, False, False),  # RGB + exact-fog transmittance: what a rain frame rasterizes
        (4, 200, 15, True, False),  # the largest fused variant in use
        (5, 150, 17, True, True),  # beyond the fused variants: the training forward stands in
    ],
)
def test_image_matches_training_forward_and_twin(seed: int, n: int, channels: int, render_depth: bool,
                                                 background: bool) -> None:
    params = _detached(random_scene(n, seed=seed, channels=channels))
    bg = torch.linspace(0.1, 0.9, channels) if background else None
    img = rasterize_image(*params, V, K, W, H, background=bg, render_depth=render_depth)
    with torch.no_grad():
        fwd = rasterize(*params, V, K, W, H, background=bg, render_depth=render_depth, backend="numba")
        twin = rasterize_torch(*params, V, K, W, H, background=bg, render_depth=render_depth)
    assert float(img.alpha.max()) > 0.5  # the scene covers part of the frame
    torch.testing.assert_close(img.color, fwd.color, atol=IMAGE_ATOL, rtol=0)
    torch.testing.assert_close(img.alpha, fwd.alpha, atol=IMAGE_ATOL, rtol=0)
    torch.testing.assert_close(img.color, twin.color, atol=TWIN_ATOL, rtol=0)
    torch.testing.assert_close(img.alpha, twin.alpha, atol=TWIN_ATOL, rtol=0)
    if render_depth:
        assert img.depth is not None and fwd.depth is not None
        torch.testing.assert_close(img.depth, fwd.depth, rtol=DEPTH_RTOL, atol=1e-6)
    else:
        assert img.depth is None
    for key in ("n_visible", "n_tile_entries", "n_pairs"):  # the same pairs, the same stops
        assert img.meta[key] == fwd.meta[key], key
    assert torch.equal(img.radii, fwd.radii) and torch.equal(img.means2d, fwd.means2d)
    assert img.means2d_abs is None and not img.color.requires_grad


def test_image_against_float64_twin_on_the_composited_pairs() -> None:
    """float32 state against the float64 twin composited over the training forward's pairs."""
    from wcbench.reference_model.raster.kernels import RenderJob

    params = _detached(random_scene(400, seed=7, channels=4))
    img = rasterize_image(*params, V, K, W, H)
    job = RenderJob(*params, V, K, W, H, near=0.01, far=1e10, render_depth=True)
    job.forward()
    gid, pix = job.composited_pairs()
    ref = rasterize_torch(*[p.double() for p in params], V.double(), K.double(), W, H,
                          pairs=(torch.from_numpy(gid), torch.from_numpy(pix)))
    torch.testing.assert_close(img.color.double(), ref.color, atol=IMAGE_ATOL, rtol=0)
    torch.testing.assert_close(img.alpha.double(), ref.alpha, atol=IMAGE_ATOL, rtol=0)
    assert img.depth is not None
    torch.testing.assert_close(img.depth.double(), ref.depth, rtol=DEPTH_RTOL, atol=0)


@pytest.mark.parametrize("stop", [1e-2, 0.1, 0.5])
def test_a_sooner_stop_matches_the_twins_and_drops_only_what_lies_past_it(stop: float) -> None:
    # the numba image kernel and the torch twin stop each pixel at the same transmittance; against
    # the full compositing (1e-4) the colour divided by alpha moves by at most the stop's share of
    # the channels' range, and alpha by at most the stop (what is left behind weighs less)
    params = _detached(random_scene(500, seed=13, channels=7))
    img = rasterize_image(*params, V, K, W, H, stop_transmittance=stop)
    with torch.no_grad():
        twin = rasterize_torch(*params, V, K, W, H, stop_transmittance=stop)
    full = rasterize_image(*params, V, K, W, H)
    torch.testing.assert_close(img.color, twin.color, atol=TWIN_ATOL, rtol=0)
    torch.testing.assert_close(img.alpha, twin.alpha, atol=TWIN_ATOL, rtol=0)
    assert img.meta["n_pairs"] == twin.meta["n_pairs"] < full.meta["n_pairs"]
    assert float((full.alpha - img.alpha).min()) >= -IMAGE_ATOL
    assert float((full.alpha - img.alpha).max()) <= stop + IMAGE_ATOL
    covered = img.alpha > 0.5
    assert int(covered.sum()) > 100
    mean_img = img.color[covered] / img.alpha[covered, None]
    mean_full = full.color[covered] / full.alpha[covered, None]
    spread = float(params[4].max() - params[4].min())
    assert float((mean_img - mean_full).abs().max()) <= 2.0 * stop * spread + 1e-5


def test_a_stop_outside_its_range_is_refused() -> None:
    params = _detached(random_scene(20, seed=1, channels=3))
    for bad in (0.0, 1e-5, 1.0, 2.0):
        with pytest.raises(ValueError, match="stop_transmittance"):
            rasterize_image(*params, V, K, W, H, stop_transmittance=bad)


def _wall(n_side: int, *, opacity: float, z: float, x0: float = 0.0, y0: float = 0.0, size: float = 0.6,
          color: tuple[float, ...] = (0.2, 0.5, 0.8)) -> list:
    """A fronto-parallel square of n_side^2 round Gaussians at depth ``z``."""
    g = torch.linspace(-size, size, n_side)
    y, x = torch.meshgrid(g, g, indexing="ij")
    n = n_side * n_side
    means = torch.stack([x.reshape(-1) + x0, y.reshape(-1) + y0, torch.full((n,), z)], 1)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1)
    scales = torch.full((n, 3), 2.0 * size / n_side)
    return [means, quats, scales, torch.full((n,), opacity), torch.tensor([color]).repeat(n, 1)]


def test_empty_tiles_and_no_gaussians_render_nothing() -> None:
    # a small wall in the top-left corner: every tile it does not reach stays exactly empty
    params = _wall(4, opacity=0.9, z=5.0, x0=-2.0, y0=-1.5, size=0.2)
    img = rasterize_image(*params, V, K, W, H, background=torch.tensor([0.3, 0.3, 0.3]))
    fwd = rasterize(*params, V, K, W, H, background=torch.tensor([0.3, 0.3, 0.3]))
    drawn = img.alpha > 0
    assert 0 < int(drawn.sum()) < W * H // 4
    assert bool((img.alpha[:, W // 2:] == 0).all()) and bool((img.color[:, W // 2:] == 0.3).all())
    torch.testing.assert_close(img.color, fwd.color, atol=IMAGE_ATOL, rtol=0)
    empty = [p[:0] for p in params]
    out = rasterize_image(*empty, V, K, W, H)
    assert out.meta["n_pairs"] == 0 and bool((out.color == 0).all()) and bool((out.alpha == 0).all())
    assert out.depth is not None and bool((out.depth == 0).all())


def test_opaque_layers_stop_early_and_show_the_front_one() -> None:
    # ten opaque walls: 0.99 opacity (the clamp) leaves T = 1e-4 after two, so the third and later
    # ones are never composited, and the front wall's color dominates
    walls = [_wall(12, opacity=1.0, z=4.0 + k, size=1.5, color=(0.1 * k, 1.0 - 0.1 * k, 0.5)) for k in range(10)]
    params = [torch.cat(parts) for parts in zip(*walls)]
    img = rasterize_image(*params, V, K, W, H)
    fwd = rasterize(*params, V, K, W, H)
    inner = (slice(16, 32), slice(16, 48))
    assert float(img.alpha[inner].min()) > 0.999
    assert float((img.color[inner][..., 1] - 1.0).abs().max()) < 0.02  # the front wall's green
    torch.testing.assert_close(img.color, fwd.color, atol=IMAGE_ATOL, rtol=0)
    torch.testing.assert_close(img.alpha, fwd.alpha, atol=IMAGE_ATOL, rtol=0)
    assert img.meta["n_pairs"] == fwd.meta["n_pairs"]
    assert img.meta["n_pairs"] < 0.5 * img.meta["n_tile_entries"] * 256  # the stops skipped most pairs


def test_transparent_gaussians_leave_the_background() -> None:
    params = _wall(8, opacity=0.5 * ALPHA_MIN, z=5.0)  # below 1/255: culled, nothing composited
    bg = torch.tensor([0.25, 0.5, 0.75])
    img = rasterize_image(*params, V, K, W, H, background=bg)
    assert img.meta["n_pairs"] == 0 and img.meta["culled_transparent"] == len(params[0])
    assert bool((img.alpha == 0).all()) and bool((img.color == bg).all())
    faint = _wall(8, opacity=2.0 * ALPHA_MIN, z=5.0)  # drawn only near their centres
    img, fwd = rasterize_image(*faint, V, K, W, H), rasterize(*faint, V, K, W, H)
    assert 0 < float(img.alpha.max()) < 0.2
    torch.testing.assert_close(img.alpha, fwd.alpha, atol=IMAGE_ATOL, rtol=0)


def test_image_is_thread_count_independent() -> None:
    from wcbench.reference_model.raster.threads import max_threads, threads

    params = _detached(random_scene(2000, seed=3, channels=4))
    outs = []
    for n in sorted({1, min(2, max_threads())}):
        with threads(n):
            outs.append(rasterize_image(*params, V, K, W, H))
    assert all(torch.equal(o.color, outs[0].color) and torch.equal(o.alpha, outs[0].alpha) for o in outs)


def test_image_refuses_gradients_and_sends_float64_to_the_twin() -> None:
    params = random_scene(50, seed=1)
    with pytest.raises(ValueError, match="requires grad"):
        rasterize_image(*args(params), V, K, W, H)
    with pytest.raises(ValueError, match="absgrad"):
        rasterize_image(*_detached(params), V, K, W, H, absgrad=True)
    with torch.no_grad():  # under no_grad the inputs' requires_grad does not matter
        rasterize_image(*args(params), V, K, W, H)
    p64 = [p.double() for p in _detached(params)]
    out = rasterize_image(*p64, V.double(), K.double(), W, H)
    ref = rasterize_torch(*p64, V.double(), K.double(), W, H)
    assert out.meta["backend"] == "torch" and out.color.dtype == torch.float64
    assert torch.equal(out.color, ref.color.detach())


def test_renders_of_trained_models_use_the_image_kernel() -> None:
    from wcbench.reference_model.devices import on_device, rasterizer_for

    assert on_device("cpu") is rasterize_image and rasterizer_for("cpu") is rasterize
    assert np.isfinite(IMAGE_ATOL)
