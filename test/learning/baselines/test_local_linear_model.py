"""Tests of the LWPR-family regressor LocalLinearRegression (fit, prediction, parameters)."""

import numpy as np
import pytest
from local_linear_data import W, constrained_trajectories, nupe

from policy_align_ros.learning.base import NotFittedError
from policy_align_ros.learning.baselines.local_linear import LocalLinearRegression


def test_recovers_quadratic_value_and_gradient_on_held_out_trajectories(toy, toy_model):
    X, y, _, held = toy
    err = toy_model.predict(X[held]) - y[held]
    err -= err.mean()  # a potential is defined up to a constant
    # Measured: nMSE 0.021 and nUPE 0.062 (pi = -grad phi = -2 W x) on these 10 held-out
    # whole trajectories; the paper reports nUPE 0.049 for this set-up on held-out points.
    assert np.mean(err**2) / np.var(y[held]) < 0.05
    assert nupe(-2 * W * X[held], -toy_model.gradient(X[held])) < 0.1


def test_reproduces_a_linear_function_where_data_spread():
    rng = np.random.default_rng(3)
    X = rng.uniform(-1, 1, (2000, 3))
    a = np.array([0.5, -1.0, 2.0])
    y = X @ a + 1.0
    linear = LocalLinearRegression(
        bandwidth=0.4, ridge=0.0, extrapolation="linear", random_state=0
    ).fit(X, y)
    Q = rng.uniform(-0.8, 0.8, (200, 3))
    np.testing.assert_allclose(linear.predict(Q), Q @ a + 1.0, atol=1e-6)
    np.testing.assert_allclose(linear.gradient(Q), np.tile(a, (200, 1)), atol=1e-6)
    # Floors only touch fields blended in beyond their data, with tiny weights, here.
    reg = LocalLinearRegression(bandwidth=0.4, ridge=0.0, random_state=0).fit(X, y)
    assert reg.floors_ is not None
    np.testing.assert_allclose(reg.predict(Q), Q @ a + 1.0, atol=1e-3)
    # The default penalty shrinks slopes only slightly where the data spread.
    reg = LocalLinearRegression(bandwidth=0.4, random_state=0).fit(X, y)
    np.testing.assert_allclose(reg.gradient(Q), np.tile(a, (200, 1)), rtol=0.02)


def test_multi_output_shapes_and_per_output_equivalence():
    rng = np.random.default_rng(6)
    X, g = constrained_trajectories(15, 30, 3, rng, scale=1.0)
    Y = np.stack([np.sin(X[:, 0]), X[:, 1] * X[:, 2]], axis=1)
    reg = LocalLinearRegression(bandwidth=0.5, random_state=0).fit(X, Y, groups=g)
    assert reg.predict(X[:7]).shape == (7, 2)
    assert reg.gradient(X[:7]).shape == (7, 2, 3)
    assert reg.floors_ is None  # "auto" floors a scalar output (a potential) only
    for mode in ("linear", "floor"):
        multi = LocalLinearRegression(bandwidth=0.5, extrapolation=mode, random_state=0)
        multi.fit(X, Y, groups=g)
        single = LocalLinearRegression(bandwidth=0.5, extrapolation=mode, random_state=0)
        single.fit(X, Y[:, 1], groups=g)
        assert single.predict(X[:7]).shape == (7,)
        assert single.gradient(X[:7]).shape == (7, 3)
        Q = np.vstack([X[:50], X[:50] * 3.0])
        np.testing.assert_allclose(multi.predict(Q)[:, 1], single.predict(Q), atol=1e-12)
        np.testing.assert_allclose(multi.gradient(Q)[:, 1], single.gradient(Q), atol=1e-12)


def test_same_seed_same_model(toy):
    X, y, g, _ = toy
    a = LocalLinearRegression(random_state=7).fit(X, y, groups=g)
    b = LocalLinearRegression(random_state=7).fit(X, y, groups=g)
    np.testing.assert_array_equal(a.centers_, b.centers_)
    np.testing.assert_array_equal(a.predict(X[:20]), b.predict(X[:20]))


def test_center_cap_is_respected():
    rng = np.random.default_rng(8)
    X = rng.normal(size=(3000, 4))
    reg = LocalLinearRegression(bandwidth=0.05, max_centers=40).fit(X, X[:, 0])
    assert len(reg.centers_) <= 40
    assert np.isfinite(reg.gradient(X[:10])).all()


def test_params_are_stored_untouched():
    grid = [0.1, 0.2]
    reg = LocalLinearRegression(bandwidth_grid=grid, ridge=0.01, random_state=3)
    assert reg.get_params()["bandwidth_grid"] is grid
    assert reg.set_params(n_folds=3).n_folds == 3
    with pytest.raises(ValueError, match="'width'"):
        reg.set_params(width=1.0)
    with pytest.raises(TypeError):
        LocalLinearRegression(0.5)  # keyword-only


@pytest.mark.parametrize(
    "params, match",
    [
        ({"bandwidth": -1.0}, "bandwidth"),
        ({"bandwidth": "auto"}, "bandwidth"),
        ({"bandwidth_grid": [0.1, -0.2]}, "bandwidth_grid"),
        ({"n_folds": 1}, "n_folds"),
        ({"ridge": -0.1}, "ridge"),
        ({"max_centers": 0}, "max_centers"),
        ({"ridge": "cv"}, "ridge"),
        ({"cv_criterion": "r2"}, "cv_criterion"),
        ({"extrapolation": "quadratic"}, "extrapolation"),
        ({"widths": "local"}, "widths"),
    ],
)
def test_bad_parameters_raise_value_error(params, match):
    X = np.random.default_rng(0).normal(size=(50, 2))
    with pytest.raises(ValueError, match=match):
        LocalLinearRegression(**params).fit(X, X[:, 0])


def test_bad_inputs_raise_clear_errors(toy_model):
    X = np.random.default_rng(0).normal(size=(50, 2))
    reg = LocalLinearRegression(bandwidth=0.5)
    row = int(np.argwhere(X > 2.0)[0, 0])  # the first row the NaN is in
    with pytest.raises(ValueError, match=rf"^X\b.*\brow {row}\b"):
        reg.fit(np.where(X > 2.0, np.nan, X), X[:, 0])
    with pytest.raises(ValueError, match=r"^y\b.*\brow 0\b"):
        reg.fit(X, np.full(50, np.inf))
    with pytest.raises(ValueError, match=r"^X\b.*\(50,\)"):
        reg.fit(X[:, 0], X[:, 0])
    with pytest.raises(ValueError, match=r"^y\b.*\(50,\).*\(49,\)"):
        reg.fit(X, X[:-1, 0])
    with pytest.raises(ValueError, match=r"^groups\b.*\(50,\).*\(3,\)"):
        reg.fit(X, X[:, 0], groups=np.zeros(3, dtype=int))
    with pytest.raises(ValueError, match=r"^groups\b.*float64"):
        reg.fit(X, X[:, 0], groups=np.zeros(50))
    with pytest.raises(NotFittedError):
        reg.predict(X)
    assert issubclass(NotFittedError, ValueError)
    with pytest.raises(ValueError, match=r"shape \(m, 2\)"):
        toy_model.predict(np.zeros((3, 5)))
    with pytest.raises(ValueError, match=r"^X\b.*\brow 0\b"):
        toy_model.gradient(np.array([[0.0, np.nan]]))
