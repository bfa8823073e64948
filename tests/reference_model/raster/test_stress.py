"""Degenerate inputs: outputs and gradients stay finite, culled Gaussians are counted (hypothesis)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from torch import Tensor

torch = pytest.importorskip("torch")
hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from wcbench.reference_model import rasterize  # noqa: E402
from wcbench.reference_model.raster.common import CULL_KEYS  # noqa: E402

NAN, INF = math.nan, math.inf
W, H = 8, 6  # tiny images: thousands of cases in seconds; the 16x16 tile is partly outside
K = torch.tensor([[6.0, 0.0, 4.0], [0.0, 6.0, 3.0], [0.0, 0.0, 1.0]])
V = torch.eye(4)
NEAR = 0.01

XY = st.sampled_from([0.0, 0.3, -0.4, 0.66, -0.67, 2.0, -100.0, 1e6, NAN, INF, -INF])
Z = st.sampled_from([-5.0, -1e-3, 0.0, NEAR, NEAR * (1 + 1e-6), 0.05, 1.0, 3.0, 1e5, 1e12, NAN, INF])
Q = st.sampled_from([0.0, 1.0, -1.0, 0.5, 1e-20, 1e-6, 1e20, NAN])
S = st.sampled_from([0.0, 1e-30, 1e-6, 0.01, 0.3, 10.0, 1e6, 1e19, 1e30, -0.1, INF, NAN])
OP = st.sampled_from([0.0, 1e-3, 1 / 255, 0.5, 0.99, 1.0, 1.5, -0.2, NAN])
C = st.sampled_from([0.0, 0.5, 1.0, -1.0, 10.0, NAN])

gaussian = st.tuples(st.tuples(XY, XY, Z), st.tuples(Q, Q, Q, Q), st.tuples(S, S, S), OP, st.tuples(C, C, C))


@pytest.fixture(scope="module", autouse=True)
def _one_numba_thread() -> Iterator[None]:
    """One tile and a handful of Gaussians per render: waking the thread pool costs more than the
    work, and on a busy machine its barrier stalls (10x slower). Results do not depend on the
    thread count (test_rasterizer.py checks that)."""
    numba = pytest.importorskip("numba")
    n = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(n)


def _tensors(gs: list) -> list[Tensor]:
    cols = list(zip(*gs))
    return [torch.tensor(c, dtype=torch.float32).requires_grad_(True) for c in cols]


def _check(params: list[Tensor], backend: str, *, bg: bool = True) -> None:
    out = rasterize(*params, V, K, W, H, backend=backend, near=NEAR,
                    background=torch.tensor([0.1, 0.2, 0.3]) if bg else None)
    n = params[0].shape[0]
    for name in ("color", "alpha", "depth"):
        t = getattr(out, name)
        assert bool(torch.isfinite(t).all()), f"{backend}: non-finite {name}"
    assert bool((out.alpha >= 0).all()) and bool((out.alpha <= 1).all())
    assert bool(torch.isfinite(out.means2d).all()) and bool((out.radii >= 0).all())
    culled = sum(out.meta[k] for k in CULL_KEYS.values())
    assert culled + out.meta["n_visible"] == n
    bad = ~(torch.stack([torch.isfinite(p.detach()).reshape(n, -1).all(-1) for p in params]).all(0))
    assert out.meta["culled_nonfinite"] == int(bad.sum())
    loss = out.color.sum() + out.alpha.sum() + 0.01 * out.depth.sum()  # type: ignore[union-attr]
    grads = torch.autograd.grad(loss, [*params, out.means2d, out.means2d_abs])
    for g in grads:
        assert bool(torch.isfinite(g).all()), f"{backend}: non-finite gradient"
    for g in grads[:5]:  # culled Gaussians get exactly zero gradient
        assert float(g[bad].abs().sum()) == 0.0


@settings(max_examples=1500, deadline=None)
@given(st.lists(gaussian, min_size=1, max_size=6))
def test_fast_path_survives_degenerate_gaussians(gs: list) -> None:
    _check(_tensors(gs), "numba")


@settings(max_examples=400, deadline=None)
@given(st.lists(gaussian, min_size=1, max_size=6))
def test_twin_survives_degenerate_gaussians(gs: list) -> None:
    _check(_tensors(gs), "torch")


@settings(max_examples=300, deadline=None)
@given(st.lists(gaussian, min_size=1, max_size=4), st.booleans())
def test_fast_path_and_twin_cull_the_same_gaussians(gs: list, bg: bool) -> None:
    params = _tensors(gs)
    outs = [rasterize(*params, V, K, W, H, backend=b, near=NEAR) for b in ("numba", "torch")]
    for key in ("n_visible", *CULL_KEYS.values()):
        assert outs[0].meta[key] == outs[1].meta[key], key


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_gaussians_at_the_image_border_and_on_the_near_plane(backend: str) -> None:
    # Centres on the four image edges (x = +-0.667 at z = 1 is the border), one just past the near plane.
    means = [[-0.667, 0.0, 1.0], [0.667, 0.0, 1.0], [0.0, -0.5, 1.0], [0.0, 0.5, 1.0], [0.0, 0.0, NEAR * 1.001]]
    n = len(means)
    params = [torch.tensor(means), torch.tensor([[1.0, 0, 0, 0]] * n), torch.full((n, 3), 0.05),
              torch.full((n,), 0.9), torch.rand(n, 3)]
    params = [p.requires_grad_(True) for p in params]
    _check(params, backend)
    out = rasterize(*params, V, K, W, H, backend=backend, near=NEAR)
    assert out.meta["n_visible"] == n  # the near one is huge on screen but still drawn


def test_a_million_copies_of_one_gaussian() -> None:
    n = 1_000_000
    params = [torch.tensor([[0.0, 0.0, 2.0]]).repeat(n, 1), torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
              torch.full((n, 3), 0.3), torch.full((n,), 0.5), torch.full((n, 3), 0.7)]
    params = [p.requires_grad_(True) for p in params]
    out = rasterize(*params, V, torch.tensor([[6.0, 0, 8.0], [0, 6.0, 8.0], [0, 0, 1]]), 16, 16, backend="numba")
    assert out.meta["n_visible"] == n and out.meta["n_tile_entries"] == n
    # Central pixels stop after a few tens of layers (T < 1e-4); pixels at the rim of the 7x7 box,
    # where alpha < 1/255, are evaluated for every copy and skipped every time.
    assert float(out.alpha.detach()[7:9, 7:9].min()) > 1 - 2e-4
    assert 7 * 7 * 14 < out.meta["n_pairs"] <= 7 * 7 * n
    out.color.sum().backward()
    for p in params:
        assert p.grad is not None and bool(torch.isfinite(p.grad).all())
    assert float(params[4].grad[1000:].abs().sum()) == 0.0  # type: ignore[index]
