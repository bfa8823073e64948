"""The sky lookup's numba forward and backward against PyTorch's ``grid_sample``."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("numba")

import torch.nn.functional as F  # noqa: E402

from wcbench.reference_model.model.sky import SkyModel  # noqa: E402
from wcbench.reference_model.model.sky_kernels import grid_sample_map, grid_sample_map_grad  # noqa: E402

pytestmark = pytest.mark.model


@pytest.mark.parametrize(("channels", "rows", "cols", "h", "w"),
                         [(12, 32, 128, 27, 48), (3, 1, 1, 5, 7), (6, 2, 9, 13, 3), (3, 16, 4, 1, 1)])
def test_map_gradient_matches_grid_sample(channels, rows, cols, h, w):
    g = torch.Generator().manual_seed(rows * 100 + cols)
    # inside, on and beyond the border of [-1, 1], where border padding clips
    grid = torch.rand(1, h, w, 2, generator=g) * 2.6 - 1.3
    grid[0, 0, 0] = torch.tensor([1.0, 1.0])
    grid[0, -1, -1] = torch.tensor([-1.0, -1.0])
    grad_out = torch.randn(1, channels, h, w, generator=g)
    maps = torch.randn(1, channels, rows, cols, generator=g, requires_grad=True)
    F.grid_sample(maps, grid, mode="bilinear", padding_mode="border", align_corners=False).backward(grad_out)
    ours = grid_sample_map_grad(grid[0].numpy(), grad_out[0].numpy(), rows, cols)
    scale = float(np.abs(grad_out.numpy()).sum() / max(1, rows * cols))
    # float32 sums in another order: within 1e-5 of a texel's typical gradient
    np.testing.assert_allclose(ours, maps.grad[0].numpy(), rtol=0, atol=1e-5 * max(scale, 1.0))


@pytest.mark.parametrize(("channels", "rows", "cols", "h", "w"),
                         [(12, 32, 128, 27, 48), (3, 1, 1, 5, 7), (6, 2, 9, 13, 3), (3, 16, 4, 1, 1)])
def test_lookup_matches_grid_sample(channels, rows, cols, h, w):
    g = torch.Generator().manual_seed(rows * 10 + cols)
    grid = torch.rand(1, h, w, 2, generator=g) * 2.6 - 1.3  # inside, on and beyond the border
    grid[0, 0, 0] = torch.tensor([1.0, 1.0])
    grid[0, -1, -1] = torch.tensor([-1.0, -1.0])
    maps = torch.randn(1, channels, rows, cols, generator=g)
    ref = F.grid_sample(maps, grid, mode="bilinear", padding_mode="border", align_corners=False)[0]
    # the same corners; the weights 1 - t rounded once instead of (x0 + 1) - x: a few float32 ulps
    np.testing.assert_allclose(grid_sample_map(maps[0].numpy(), grid[0].numpy()), ref.numpy(), rtol=0, atol=2e-6)


def test_a_non_finite_grid_entry_reads_zero():
    g = torch.Generator().manual_seed(8)
    grid = torch.rand(6, 9, 2, generator=g) * 2 - 1
    grid[2, 4] = torch.tensor([float("nan"), 0.0])
    grid[5, 0] = torch.tensor([float("inf"), float("-inf")])
    out = grid_sample_map(torch.randn(3, 4, 5, generator=g).numpy(), grid.numpy())
    assert np.isfinite(out).all() and (out[:, 2, 4] == 0).all() and (out[:, 5, 0] == 0).all()


def test_a_non_finite_grid_entry_sends_no_gradient():
    g = torch.Generator().manual_seed(7)
    grid = torch.rand(6, 9, 2, generator=g) * 2 - 1
    grad_out = torch.randn(3, 6, 9, generator=g)
    bad = grid.clone()
    bad[2, 4] = torch.tensor([float("nan"), 0.0])
    bad[5, 0] = torch.tensor([float("inf"), float("-inf")])
    quiet = grad_out.clone()
    quiet[:, 2, 4] = 0.0
    quiet[:, 5, 0] = 0.0
    ours = grid_sample_map_grad(bad.numpy(), grad_out.numpy(), 4, 5)
    np.testing.assert_array_equal(ours, grid_sample_map_grad(grid.numpy(), quiet.numpy(), 4, 5))


def test_sky_model_colors_and_gradient_are_the_same_through_the_kernels():
    weathers = ("clear", "rain", "snow", "fog")
    sky = SkyModel(weathers, up=np.array([0.0, 0.0, 1.0]), heading=np.array([1.0, 0.0, 0.0]), rows=8, cols=16,
                   window=(-0.8, 0.8, -0.2, 0.6))
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        sky.logits.normal_(generator=g)
    rays = F.normalize(torch.randn(20, 30, 3, generator=g) * 0.4 + torch.tensor([1.0, 0.0, 0.2]), dim=-1)
    grid = sky.grid(rays)
    weights = torch.rand(20, 30, 12, generator=g)
    colors = sky(grid, weathers)
    (colors * weights).sum().backward()
    ours = sky.logits.grad.clone()
    sky.logits.grad = None
    plain = F.grid_sample(sky.logits.reshape(1, 12, 8, 16), grid, mode="bilinear", padding_mode="border",
                          align_corners=False)
    reference = torch.sigmoid(plain[0].permute(1, 2, 0))
    (reference * weights).sum().backward()
    torch.testing.assert_close(colors, reference, atol=1e-6, rtol=0)
    torch.testing.assert_close(ours, sky.logits.grad, atol=1e-5, rtol=1e-5)
