"""The editor's sun visibility laid onto the frame's own shadows (:func:`shadow_edges`): a shadow
map's edge a few pixels off takes a step at the frame's shadow edge, alike on any albedo, through
texture; where the map does not change, nothing the frame shows (a dark patch of asphalt) makes a
shadow."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

from wcbench.reference_model.appearance.editor import shadow_edges
from wcbench.reference_model.appearance.shading import linear_to_srgb

#: The frame's shadow step (column) and the map's, 12 px off; a sunlit surface's light over a
#: shadowed one's (the harder street's ground: about 2.6).
TRUE_EDGE, MAP_EDGE, SUN_RATIO = 100, 112, 2.5


def _frame(rng: np.random.Generator, albedo: float, *, texture: float = 0.15) -> np.ndarray:
    """[60, 200, 3] display RGB of a surface of ``albedo`` (linear, grey, +-``texture`` relative
    noise) lit by the sun right of TRUE_EDGE and in its cast shadow left of it."""
    lin = albedo * (1.0 + texture * rng.uniform(-1.0, 1.0, (60, 200, 1))) * np.ones((1, 1, 3))
    lin[:, :TRUE_EDGE] /= SUN_RATIO
    return linear_to_srgb(lin.astype(np.float32))


def _map(edge: int) -> np.ndarray:
    vis = np.ones((60, 200), np.float32)
    vis[:, :edge] = 0.0
    return vis


def test_a_map_edge_off_by_twelve_pixels_steps_at_the_frames_shadow_edge_on_any_albedo(rng):
    profiles = []
    for albedo in (0.04, 0.15, 0.6):
        out = shadow_edges(_map(MAP_EDGE), _frame(rng, albedo), radius=20).mean(axis=0)
        # a step where the frame's shadow ends, then the map's side of the window's compromise
        assert out[TRUE_EDGE + 1] - out[TRUE_EDGE - 2] > 0.2, out[TRUE_EDGE - 5:MAP_EDGE]
        assert out[TRUE_EDGE + 2:MAP_EDGE - 2].mean() > 0.35  # lit in the frame, shadow in the map
        assert out[:TRUE_EDGE - 5].max() < 0.1 and out[MAP_EDGE + 40:].min() > 0.99
        profiles.append(out)
        # the map as the old 3 px snapping left it: no step at the frame's edge, those columns shadow
        old = shadow_edges(_map(MAP_EDGE), _frame(rng, albedo), radius=3).mean(axis=0)
        assert old[TRUE_EDGE + 1] - old[TRUE_EDGE - 2] < 0.02 and old[TRUE_EDGE + 2:MAP_EDGE - 5].max() < 0.05
    # a shadow is one step in log light, so the dark surface and the bright one move alike
    np.testing.assert_allclose(profiles[0], profiles[2], atol=0.03)


def test_where_the_map_does_not_change_the_frame_makes_no_shadow(rng):
    frame = _frame(rng, 0.2)
    frame[:] = frame[:, -1:]  # all sunlit: one column repeated
    lin_patch = linear_to_srgb(np.full((20, 40, 3), 0.2 / 3.0, np.float32))  # a lit tar patch, 3x darker
    frame[20:40, 60:100] = lin_patch
    out = shadow_edges(np.ones((60, 200), np.float32), frame, radius=20)
    np.testing.assert_allclose(out, 1.0, atol=1e-4)


def test_radius_zero_returns_the_map():
    vis = _map(MAP_EDGE)
    np.testing.assert_array_equal(shadow_edges(vis, np.zeros((60, 200, 3), np.float32), radius=0), vis)
