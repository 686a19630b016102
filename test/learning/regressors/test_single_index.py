"""The single-index trend's maths (learning.regressors.trend_kernel.single_index)."""

import numpy as np
import scipy.optimize

from policy_align_ros.learning.regressors.trend_kernel.single_index import (
    KNEES,
    fit_index,
    increasing,
    index_form,
    levenberg_marquardt,
    profile_basis,
    profile_gradient,
    profile_weights,
)


def _index(n, rng):
    A = rng.standard_normal((n, n))
    return np.linalg.cholesky(A @ A.T / n + 0.5 * np.eye(n)), rng.uniform(-0.5, 0.5, n)


def test_profile_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    L, z0 = _index(4, rng)
    beta = rng.uniform(0.1, 1.0, 1 + 2 * len(KNEES))
    Z = rng.standard_normal((5, 4))

    def value(Z):
        return profile_basis(index_form(Z, L, z0)[1], 0.7)[0] @ beta

    h = 1e-6
    fd = np.stack([(value(Z + h * e) - value(Z - h * e)) / (2 * h) for e in np.eye(4)], 1)
    np.testing.assert_allclose(profile_gradient(Z, L, z0, 0.7, beta), fd, rtol=1e-6,
                               atol=1e-8)


def test_the_basis_derivative_is_the_derivative_of_the_basis():
    q = np.linspace(0.05, 3.0, 7)
    h = 1e-6
    fd = (profile_basis(q + h, 0.5)[0] - profile_basis(q - h, 0.5)[0]) / (2 * h)
    np.testing.assert_allclose(fd, profile_basis(q, 0.5)[1], rtol=1e-6)


def test_a_rising_profile_is_told_from_a_falling_one():
    beta = np.zeros(1 + 2 * len(KNEES))
    beta[0], beta[4] = 1.0, 0.5
    assert increasing(beta, 1.0, 4.0)
    beta[4] = -3.0  # sqrt(q + c^2) with a negative weight wins near q = 0
    assert not increasing(beta, 1.0, 4.0)


def test_variable_projection_recovers_a_cone_index_with_unknown_offsets():
    # u = sqrt(0.04 + q(z)) + b_k: a velocity-limited attractor, each demonstration's
    # values shifted by an unknown offset; started from a wrong metric and goal.
    rng = np.random.default_rng(1)
    n = 3
    L, z0 = _index(n, rng)
    Z = rng.uniform(-1, 1, size=(400, n))
    demo = np.repeat(np.arange(20), 20)
    u = np.sqrt(0.04 + index_form(Z, L, z0)[1]) + rng.standard_normal(20)[demo]
    Lf, zf = fit_index(Z, u, demo, np.eye(n), np.zeros(n), 1.0, max_nfev=100)
    # The index is known up to its scale (the profile absorbs it): compare directions.
    grad_true = index_form(Z, L, z0)[0] @ L.T
    grad_fit = index_form(Z, Lf, zf)[0] @ Lf.T
    cos = np.einsum("ij,ij->i", grad_true, grad_fit) / (
        np.linalg.norm(grad_true, axis=1) * np.linalg.norm(grad_fit, axis=1))
    assert np.min(cos) > 0.999
    np.testing.assert_allclose(zf, z0, atol=1e-3)


def test_every_basis_column_rises_so_non_negative_weights_give_a_rising_profile():
    q = np.geomspace(1e-8, 1e4, 400)
    B, dB = profile_basis(q, 0.8)
    assert B.shape == dB.shape == (400, 1 + 2 * len(KNEES))
    assert np.all(dB > 0.0) and np.all(np.diff(B, axis=0) > 0.0)
    rng = np.random.default_rng(2)
    assert increasing(rng.uniform(0.0, 1.0, B.shape[1]), 0.8, 1e2)
    assert not increasing(np.zeros(B.shape[1]), 0.8, 1e2)  # flat: no minimum


def test_profile_weights_fit_a_steepening_profile_with_unknown_offsets():
    # g(q) = q + q^2 / 4 on q in [0, 4], every demonstration shifted by an unknown offset:
    # non-negative weights on the rising columns reproduce its derivative to a few percent.
    rng = np.random.default_rng(3)
    q = rng.uniform(0.0, 4.0, 300)
    demo = np.repeat(np.arange(15), 20)
    u = q + q**2 / 4 + rng.standard_normal(15)[demo]
    beta = profile_weights(profile_basis(q, 1.0)[0], u, demo)
    assert np.all(beta >= 0.0)
    grid = np.linspace(0.1, 4.0, 40)
    np.testing.assert_allclose(profile_basis(grid, 1.0)[1] @ beta, 1 + grid / 2, rtol=0.05)


def test_levenberg_marquardt_finds_the_least_squares_solution_of_a_curve_fit():
    # y = a exp(-b t) + c, from a start far off: the same optimum as SciPy's solver.
    t = np.linspace(0.0, 4.0, 60)
    rng = np.random.default_rng(0)
    y = 2.0 * np.exp(-1.3 * t) + 0.5 + 0.01 * rng.standard_normal(len(t))

    def residual(p):
        return p[0] * np.exp(-p[1] * t) + p[2] - y

    def jacobian(p):
        e = np.exp(-p[1] * t)
        return np.column_stack([e, -p[0] * t * e, np.ones_like(t)])

    start = np.array([1.0, 0.3, 0.0])
    got = levenberg_marquardt(residual, jacobian, start, 100)
    want = scipy.optimize.least_squares(residual, start, jac=jacobian, xtol=1e-14,
                                        ftol=1e-14, gtol=1e-14).x
    np.testing.assert_allclose(got, want, rtol=1e-5)
    assert np.sum(residual(got) ** 2) < np.sum(residual(start) ** 2)
