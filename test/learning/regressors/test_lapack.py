"""The trend-kernel model's direct LAPACK solves equal scipy.linalg's to the last bit."""

import numpy as np
import pytest
import scipy.linalg

from policy_align_ros.learning.regressors.trend_kernel.lapack import (
    cho_factor,
    cho_solve,
    cholesky,
    solve_triangular,
)


def _spd(p: int, rng: np.random.Generator) -> np.ndarray:
    A = rng.standard_normal((p + 3, p))
    return A.T @ A + 1e-3 * np.eye(p)


@pytest.mark.parametrize("p", [1, 7, 60])
def test_cholesky_solves_equal_scipy(p):
    rng = np.random.default_rng(p)
    M, b, B = _spd(p, rng), rng.standard_normal(p), rng.standard_normal((p, 3))
    ours, theirs = cho_factor(M), scipy.linalg.cho_factor(M, check_finite=False)
    assert np.array_equal(np.triu(ours[0]), np.triu(theirs[0])) and ours[1] == theirs[1]
    for rhs in (b, B):
        x = cho_solve(ours, rhs)
        assert np.array_equal(x, scipy.linalg.cho_solve(theirs, rhs, check_finite=False))
        assert np.allclose(M @ x, rhs)
    for lower in (True, False):
        assert np.array_equal(cholesky(M, lower),
                              scipy.linalg.cholesky(M, lower=lower, check_finite=False))


@pytest.mark.parametrize("order", ["C", "F"])
@pytest.mark.parametrize("lower", [True, False])
@pytest.mark.parametrize("trans", [0, 1])
def test_solve_triangular_equals_scipy(order, lower, trans):
    rng = np.random.default_rng(3)
    L = np.asarray(cholesky(_spd(9, rng), lower), order=order)
    b = rng.standard_normal((9, 2))
    x = solve_triangular(L, b, lower=lower, trans=trans)
    assert np.array_equal(x, scipy.linalg.solve_triangular(L, b, trans=trans, lower=lower,
                                                           check_finite=False))
    assert np.allclose((L.T if trans else L) @ x, b)


def test_not_positive_definite_raises_linalg_error():
    M = np.diag([1.0, -1.0, 2.0])
    with pytest.raises(np.linalg.LinAlgError):
        cho_factor(M)
    with pytest.raises(np.linalg.LinAlgError):
        cholesky(M, lower=True)
    with pytest.raises(np.linalg.LinAlgError):
        solve_triangular(np.diag([1.0, 0.0]), np.ones(2), lower=True)


def test_empty_systems():
    assert cho_solve(cho_factor(np.zeros((0, 0))), np.zeros(0)).shape == (0,)
    assert cholesky(np.zeros((0, 0)), lower=True).shape == (0, 0)
