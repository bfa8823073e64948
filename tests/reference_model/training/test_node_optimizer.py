"""NodeOptimizer's batched step against torch's own fused Adam, group by group."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from wcbench.reference_model.training.densify import NodeOptimizer  # noqa: E402

pytestmark = pytest.mark.model


def test_one_call_per_rate_is_bit_identical_to_adam_step_and_keeps_its_state():
    g = torch.Generator().manual_seed(0)
    shapes = [(int(n), 3) for n in torch.randint(1, 400, (40,), generator=g)] + [(7,), (2, 5, 4)]
    rates = [(1e-3, 2e-3, 5e-2)[i % 3] for i in range(len(shapes))]
    ours = [torch.nn.Parameter(torch.randn(s, generator=g)) for s in shapes]
    ref = [torch.nn.Parameter(p.detach().clone()) for p in ours]
    opt = NodeOptimizer([(f"p{i}", p, lr) for i, (p, lr) in enumerate(zip(ours, rates))])
    adam = torch.optim.Adam([{"params": [p], "lr": lr} for p, lr in zip(ref, rates)], eps=1e-15, fused=True)
    for step in range(12):
        for i, (p, q) in enumerate(zip(ours, ref)):
            grad = None if (step < 3 and i == 5) else torch.randn(p.shape, generator=g)  # a late starter
            p.grad, q.grad = (None, None) if grad is None else (grad.clone(), grad.clone())
        if step == 6:  # a rate that changes between steps, as the centres' decay does
            opt.adam.param_groups[1]["lr"] = adam.param_groups[1]["lr"] = 7e-4
        opt.step()
        adam.step()
    for p, q in zip(ours, ref):
        assert torch.equal(p, q)
    ours_state, ref_state = opt.state_dict()["state"], adam.state_dict()["state"]
    assert ours_state.keys() == ref_state.keys()
    for k in ref_state:
        for key in ("step", "exp_avg", "exp_avg_sq"):
            assert torch.equal(ours_state[k][key], ref_state[k][key]), (k, key)
