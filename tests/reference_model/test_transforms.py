"""Quaternion helpers: the vectorised matrix-to-quaternion form against the one-matrix form."""

from __future__ import annotations

import numpy as np

from wcbench.reference_model.transforms import quat_from_matrices, quat_from_matrix, quat_to_matrix


def test_quat_from_matrices_matches_the_one_matrix_form_on_every_branch() -> None:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(200, 4))
    # rotations by ~180 degrees about each axis take the diagonal branches
    q[:3] = [[1e-3, 1.0, 0.0, 0.0], [1e-3, 0.0, 1.0, 0.0], [1e-3, 0.0, 0.0, 1.0]]
    R = quat_to_matrix(q)
    batched = quat_from_matrices(R)
    single = np.stack([quat_from_matrix(r) for r in R])
    sign = np.sign((batched * single).sum(1, keepdims=True))  # q and -q are one rotation
    np.testing.assert_allclose(batched, sign * single, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(batched), R, atol=1e-12)
    assert quat_from_matrices(R[0]).shape == (1, 4)
