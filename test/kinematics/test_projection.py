"""Tests of policy_align_ros.kinematics.projection (N = I - pinv(A) A)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from policy_align_ros.kinematics import nullspace_projector, nullspace_projectors


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 8), k=st.integers(0, 8))
def test_projector_properties_random(seed: int, n: int, k: int) -> None:
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((k, n))
    N = nullspace_projector(A, n=n)
    np.testing.assert_allclose(A @ N, 0.0, atol=1e-9)
    np.testing.assert_allclose(N @ N, N, atol=1e-9)
    np.testing.assert_allclose(N, N.T, atol=1e-12)
    np.testing.assert_allclose(N, np.eye(n) - np.linalg.pinv(A) @ A, atol=1e-9)
    assert round(np.trace(N)) == n - min(k, n)


def test_rank_deficient_and_empty() -> None:
    row = np.array([[1.0, 2.0, 0.0]])
    A = np.vstack([row, 2 * row, row + 1e-15])  # rank 1 up to round-off
    N = nullspace_projector(A)
    assert round(np.trace(N)) == 2
    np.testing.assert_allclose(A @ N, 0.0, atol=1e-12)
    np.testing.assert_array_equal(nullspace_projector(np.zeros((0, 4))), np.eye(4))
    np.testing.assert_array_equal(nullspace_projector([], n=3), np.eye(3))
    np.testing.assert_array_equal(nullspace_projector(np.zeros((2, 3))), np.eye(3))


def test_bad_input() -> None:
    with pytest.raises(ValueError, match=r"^A\b.*\(3,\)"):
        nullspace_projector(np.ones(3))
    with pytest.raises(ValueError, match="NaN"):
        nullspace_projector(np.array([[np.nan, 1.0]]))
    with pytest.raises(ValueError, match=r"^A\b.*\bn=3\b"):
        nullspace_projector(np.ones((1, 2)), n=3)
    with pytest.raises(ValueError, match=r"^A\b"):
        nullspace_projector([])


def test_vectorised_matches_loop() -> None:
    rng = np.random.default_rng(3)
    As = rng.standard_normal((20, 2, 5))
    As[3, 1] = As[3, 0]  # rank loss in one item
    As[4] = 0.0
    Ns = nullspace_projectors(As)
    for A, N in zip(As, Ns, strict=True):
        np.testing.assert_allclose(N, nullspace_projector(A), atol=1e-12)
    np.testing.assert_array_equal(nullspace_projectors(np.zeros((4, 0, 3))),
                                  np.broadcast_to(np.eye(3), (4, 3, 3)))
