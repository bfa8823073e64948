"""The validity suite's agreement statistic (Spearman with a bootstrap interval)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wcbench.bench.validity import agreement


def _spearman_twin(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson correlation of the ranks (distinct values: ranks are argsort positions)."""
    rx, ry = np.argsort(np.argsort(x)).astype(float), np.argsort(np.argsort(y)).astype(float)
    rx, ry = rx - rx.mean(), ry - ry.mean()
    return float((rx * ry).sum() / math.sqrt((rx * rx).sum() * (ry * ry).sum()))


def test_agreement_matches_the_rank_twin_and_orients() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=40)
    y = x + rng.normal(scale=0.8, size=40)
    rho, low, high = agreement(x, y)
    assert rho == pytest.approx(_spearman_twin(x, y), abs=1e-12)
    assert low < rho < high
    flipped, f_low, f_high = agreement(-x, y, sign=-1.0)  # a lower-is-better proxy, oriented
    assert flipped == pytest.approx(rho, abs=1e-12) and (f_low, f_high) == pytest.approx((low, high))
    assert agreement(x, y) == (rho, low, high)  # seeded


def test_agreement_of_perfect_and_unrelated_series() -> None:
    x = np.arange(10.0)
    assert agreement(x, x ** 3)[0] == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    _, low, high = agreement(rng.normal(size=30), rng.normal(size=30))
    assert low < 0 < high  # the interval says "no evidence either way"


def test_agreement_degenerate_inputs() -> None:
    assert all(math.isnan(v) for v in agreement(np.ones(5), np.arange(5.0)))
    assert all(math.isnan(v) for v in agreement(np.arange(2.0), np.arange(2.0)))
    with pytest.raises(ValueError, match="two series of one length"):
        agreement(np.arange(3.0), np.arange(4.0))
