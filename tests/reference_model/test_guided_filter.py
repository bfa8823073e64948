"""The colour guided filter (wcbench.reference_model.guided_filter) against its definition written
out in float64 (He, Sun & Tang 2013, Algorithm 1 with a colour guide)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from wcbench.reference_model.guided_filter import guided_filter


def _box(a: np.ndarray, r: int) -> np.ndarray:
    return cv2.boxFilter(a, cv2.CV_64F, (2 * r + 1, 2 * r + 1), normalize=True, borderType=cv2.BORDER_REFLECT)


def _definition(guide: np.ndarray, p: np.ndarray, r: int, eps: float) -> np.ndarray:
    """In float64: per window the regularised least-squares a (3-vector) and b of p ~ a . I + b,
    each pixel the mean of the a and b of the windows holding it."""
    I = guide.astype(np.float64)  # noqa: E741 (the paper's name)
    p = p.astype(np.float64)
    mean_i = np.stack([_box(I[..., c], r) for c in range(3)], -1)
    mean_p = _box(p, r)
    cov_ip = np.stack([_box(I[..., c] * p, r) for c in range(3)], -1) - mean_i * mean_p[..., None]
    sigma = np.empty((*p.shape, 3, 3))
    for i in range(3):
        for j in range(3):
            sigma[..., i, j] = _box(I[..., i] * I[..., j], r) - mean_i[..., i] * mean_i[..., j]
    a = np.linalg.solve(sigma + eps * np.eye(3), cov_ip[..., None])[..., 0]
    b = mean_p - np.einsum("hwc,hwc->hw", a, mean_i)
    return np.einsum("hwc,hwc->hw", np.stack([_box(a[..., c], r) for c in range(3)], -1), I) + _box(b, r)


@pytest.fixture
def street() -> tuple[np.ndarray, np.ndarray]:
    """A frame of two-colour edges (a dark facade, a pale one, a sky), noise, and a mask to filter."""
    rng = np.random.default_rng(0)
    guide = np.zeros((60, 90, 3), np.float32)
    guide[:20] = (0.7, 0.75, 0.85)
    guide[20:, :45] = (0.15, 0.17, 0.2)
    guide[20:, 45:] = (0.8, 0.72, 0.6)
    guide += rng.normal(0.0, 0.01, guide.shape).astype(np.float32)
    mask = (rng.random((60, 90)) < 0.5).astype(np.float32)
    mask[:20] = 1.0
    return np.clip(guide, 0.0, 1.0), mask


@pytest.mark.parametrize("r, eps", [(2, 1e-4), (4, 1e-3), (12, 1e-3), (8, 1e-2)])
def test_the_filter_is_its_definition_at_every_eps(street, r, eps):
    guide, mask = street
    # float32 box sums, the covariance's conditioning growing as 1 / eps
    np.testing.assert_allclose(guided_filter(guide, mask, radius=r, eps=eps), _definition(guide, mask, r, eps),
                               atol=1e-3)


def test_it_keeps_a_two_colour_edge_where_opencvs_on_a_unit_guide_does_not(street):
    guide, _ = street
    step = np.where(np.arange(90) < 45, 30.0, 90.0)[None].repeat(60, 0).astype(np.float32)
    ours = guided_filter(guide, step, radius=12, eps=1e-3)
    # within 2.5 % of the 60 m step (the guide's noise, 0.01, against sqrt(eps) = 0.03)
    np.testing.assert_allclose(ours[30:, :40], 30.0, atol=1.5 * 1.5)
    np.testing.assert_allclose(ours[30:, 50:], 90.0, atol=1.5 * 1.5)
    # the reason this module exists: OpenCV's own call on the [0, 1] guide smooths across the edge
    plain = cv2.ximgproc.guidedFilter(guide, step, 12, 1e-3)
    assert np.abs(plain[40, 40:50] - step[40, 40:50]).max() > 10.0


def test_several_channels_are_filtered_each_alone(street):
    guide, mask = street
    both = guided_filter(guide, np.stack([mask, 1.0 - mask], -1), radius=4, eps=1e-3)
    np.testing.assert_allclose(both[..., 0], guided_filter(guide, mask, radius=4, eps=1e-3), atol=1e-6)
    np.testing.assert_allclose(both[..., 0] + both[..., 1], 1.0, atol=1e-4)


@pytest.mark.parametrize("kwargs, shape", [({"radius": 0, "eps": 1e-3}, (60, 90)),
                                           ({"radius": 2, "eps": 0.0}, (60, 90)),
                                           ({"radius": 2, "eps": 1e-3}, (30, 90))])
def test_bad_arguments_are_refused(street, kwargs, shape):
    guide, _ = street
    with pytest.raises(ValueError, match="radius >= 1 and eps > 0"):
        guided_filter(guide, np.zeros(shape, np.float32), **kwargs)


def test_the_workstations_stand_in_for_ximgproc_gives_the_same(street, monkeypatch):
    """tools/ximgproc_fallback.py gives cv2 an ``ximgproc.guidedFilter`` alone (no
    ``createGuidedFilter``): the channels are then filtered one a call, to the same result."""
    from types import SimpleNamespace

    guide, mask = street
    src = np.stack([mask, 1.0 - mask], -1)
    with_create = guided_filter(guide, src, radius=4, eps=1e-3)
    monkeypatch.setattr(cv2, "ximgproc", SimpleNamespace(guidedFilter=cv2.ximgproc.guidedFilter))
    np.testing.assert_allclose(guided_filter(guide, src, radius=4, eps=1e-3), with_create, atol=1e-6)
