"""The ground's openness as a smooth field over the ground plane (appearance/open_ground.py)."""

from __future__ import annotations

import numpy as np
import pytest

from wcbench.reference_model.appearance.open_ground import CELL_M, SPREAD_M, OpenGround


def _spread_slow(xy: np.ndarray, openness: np.ndarray, queries: np.ndarray, spread_m: float) -> np.ndarray:
    """The Gaussian-weighted mean of the points' openness at each query, point by point (the
    field's continuous twin: no cells, no truncation), 1 where every weight vanishes."""
    out = np.ones(len(queries))
    for q, p in enumerate(queries):
        w = np.exp(-0.5 * np.sum((xy - p) ** 2, axis=1) / spread_m ** 2)
        if w.sum() > 1e-12:
            out[q] = float(w @ openness / w.sum())
    return out


def test_the_field_is_the_gaussian_weighted_mean_of_the_grounds_openness(rng):
    # a 10 x 6 m pavement sampled at 0.1 m with jitter; a crown's shelter in rings: every other
    # 0.3 m strip of its 3 m disc sheltered (half), the rest open, as the lidar's rings sample it
    g = np.stack(np.meshgrid(np.arange(0.0, 10.0, 0.1), np.arange(0.0, 6.0, 0.1)), -1).reshape(-1, 2)
    xy = g + rng.uniform(-0.03, 0.03, g.shape)
    in_crown = np.linalg.norm(xy - [5.0, 3.0], axis=1) < 1.5
    ring = (np.floor(xy[:, 0] / 0.3) % 2) == 0
    openness = np.where(in_crown & ring, 0.5, 1.0)
    field = OpenGround.from_ground(xy, openness)
    queries = rng.uniform([0.5, 0.5], [9.5, 5.5], (300, 2))
    fast, slow = field.at(queries), _spread_slow(xy, openness, queries, SPREAD_M)
    # binning to 0.25 m cells moves a point by up to a cell's half-diagonal (0.18 m), against a
    # spread of 0.5 m: the field stays within 0.03 of the continuous mean
    np.testing.assert_allclose(fast, slow, atol=0.03)
    # the rings are gone under the crown: within 0.8 m of its centre the field varies by < 0.05
    centre = np.linalg.norm(queries - [5.0, 3.0], axis=1) < 0.8
    assert centre.sum() > 5 and np.ptp(fast[centre]) < 0.05
    assert np.all(np.abs(fast[centre] - 0.75) < 0.05)  # half the crown's Gaussians are sheltered by half
    assert np.all(fast[np.linalg.norm(queries - [5.0, 3.0], axis=1) > 3.5] > 0.99)  # open beyond it


def test_a_gap_in_the_ground_takes_the_ground_around_it_and_far_off_is_open(rng):
    # the pavement under a crown (openness 0.5) with a 0.6 m wide band the lidar missed (a trunk's
    # shadow): the band reads the crown's half, not the open sky
    g = np.stack(np.meshgrid(np.arange(0.0, 6.0, 0.1), np.arange(0.0, 4.0, 0.1)), -1).reshape(-1, 2)
    band = np.abs(g[:, 0] - 3.0) < 0.3
    field = OpenGround.from_ground(g[~band], np.full((~band).sum(), 0.5))
    inside = np.column_stack([np.full(20, 3.0), np.linspace(0.5, 3.5, 20)])
    np.testing.assert_allclose(field.at(inside), 0.5, atol=1e-4)
    np.testing.assert_array_equal(field.at(np.array([[40.0, 2.0], [-30.0, -30.0]])), 1.0)  # no ground near
    empty = OpenGround.from_ground(np.zeros((0, 2)), np.zeros(0))
    np.testing.assert_array_equal(empty.at(g[:5]), 1.0)


def test_a_long_drive_gets_larger_cells_and_bad_input_is_refused():
    xy = np.array([[0.0, 0.0], [2000.0, 10.0]])
    field = OpenGround.from_ground(xy, np.array([0.0, 1.0]))
    assert field.cell_m > CELL_M and max(field.field.shape) <= 2049
    with pytest.raises(ValueError, match="one per point"):
        OpenGround.from_ground(xy, np.zeros(3))
    with pytest.raises(ValueError, match="positive"):
        OpenGround.from_ground(xy, np.zeros(2), spread_m=0.0)
