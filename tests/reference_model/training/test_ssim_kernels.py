"""The fused training SSIM (numba) against its pure-torch twin and a float64 reference."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("numba")

from wcbench.reference_model.raster.threads import threads  # noqa: E402
from wcbench.reference_model.training.losses import rgb_loss, training_ssim  # noqa: E402

pytestmark = pytest.mark.model

#: (C, H, W): a training frame, one stacked weather step, and shapes smaller than the window.
SHAPES = [(3, 54, 96), (12, 27, 48), (5, 7, 13), (1, 1, 1), (3, 20, 4), (2, 3, 40)]


def _pair(c: int, h: int, w: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    a = torch.rand(h, w, c, generator=g)
    b = (a + 0.1 * torch.randn(h, w, c, generator=g)).clamp(0.0, 1.0)  # a render near its target
    return a, b


@pytest.mark.parametrize(("c", "h", "w"), SHAPES)
def test_fused_ssim_matches_the_float64_reference_as_closely_as_the_float32_twin(c, h, w):
    a, b = _pair(c, h, w, seed=c * 1000 + h)
    weights = torch.rand(c, generator=torch.Generator().manual_seed(1))
    out = {}
    for backend in ("numba", "torch"):
        x = a.clone().requires_grad_(True)
        value = training_ssim(x, b, backend=backend)
        (value * weights).sum().backward()
        out[backend] = (value.double(), x.grad.double())
    x64 = a.double().requires_grad_(True)
    ref = training_ssim(x64, b.double())  # float64: the twin, by the auto rule
    (ref * weights.double()).sum().backward()
    scale = float(x64.grad.abs().max())
    for backend, (value, grad) in out.items():
        # float32 maps: the SSIM within 3e-7, the gradient within 1e-5 of its largest entry
        torch.testing.assert_close(value, ref.detach(), atol=3e-7, rtol=0, msg=backend)
        torch.testing.assert_close(grad, x64.grad, atol=1e-5 * scale, rtol=0, msg=backend)


def test_fused_ssim_is_the_same_for_any_thread_count():
    a, b = _pair(12, 54, 96, seed=3)
    results = []
    for n in (1, 2):
        with threads(n):
            x = a.clone().requires_grad_(True)
            value = training_ssim(x, b, backend="numba")
            value.sum().backward()
            results.append((value, x.grad))
    assert torch.equal(results[0][0], results[1][0]) and torch.equal(results[0][1], results[1][1])


def test_auto_takes_the_twin_where_the_kernels_do_not_apply():
    a, b = _pair(3, 20, 30, seed=4)
    target = b.clone().requires_grad_(True)  # a target that wants its gradient: only autograd gives it
    x = a.clone().requires_grad_(True)
    (training_ssim(x, target)).sum().backward()
    assert target.grad is not None and x.grad is not None
    with pytest.raises(ValueError, match="target without gradient"):
        training_ssim(a, target, backend="numba")
    with pytest.raises(ValueError, match="float32"):
        training_ssim(a.double(), b.double(), backend="numba")
    with pytest.raises(ValueError, match="backend must be"):
        training_ssim(a, b, backend="cuda")
    with pytest.raises(ValueError, match="one shape"):
        training_ssim(a, b[:-1])


def test_rgb_loss_on_stacked_weathers_uses_the_fused_ssim():
    a, b = _pair(12, 27, 48, seed=5)
    fused = rgb_loss(a, b)
    ssim = training_ssim(a, b, backend="torch").view(4, 3).mean(1)
    l1 = (a - b).abs().mean(dim=(0, 1)).view(4, 3).mean(1)
    torch.testing.assert_close(fused, 0.8 * l1 + 0.2 * (1 - ssim), atol=1e-7, rtol=0)
