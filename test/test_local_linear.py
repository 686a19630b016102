"""Tests of the LWPR-family global regressor (learning.regressors.local_linear)."""

import io
import json

import numpy as np
import pytest

import policy_align_ros.learning.regressors.local_linear as regression_module
from policy_align_ros.learning.regressors.local_linear import (
    RIDGE_GRID,
    LocalLinearRegression,
    NotFittedError,
    floored,
    thin_trajectories,
)

W = 0.05  # the paper's toy potential phi(x) = x^T W x, W = 0.05 I


def constrained_trajectories(K, N, n, rng, scale=2.0, rows=1, rate=2 * W):
    """Trajectories descending phi = W ||x||^2 under random constraints (paper IV-B).

    Each trajectory starts uniform in [-scale, scale]^n and follows x += N(-grad phi),
    dt = 1, with ``rows`` random constraint rows re-sampled twice at regular intervals.

    Returns
    -------
    X : ndarray, shape (K * N, n)
    groups : ndarray of int, shape (K * N,)
    """
    T = np.empty((K, N, n))
    for k in range(K):
        x = rng.uniform(-scale, scale, n)
        for seg in np.array_split(np.arange(N), 3):
            A = rng.normal(size=(rows, n))
            P = np.eye(n) - np.linalg.pinv(A) @ A
            for i in seg:
                T[k, i] = x
                x = x - rate * (P @ x)
    return T.reshape(-1, n), np.repeat(np.arange(K), N)


def potential(X):
    return W * np.sum(X**2, axis=1)


def nupe(pi, pi_hat):
    return np.mean(np.sum((pi - pi_hat) ** 2, axis=1)) / np.sum(np.var(pi, axis=0))


def central_differences(fun, X, eps=1e-6):
    cols = [(fun(X + eps * e) - fun(X - eps * e)) / (2 * eps) for e in np.eye(X.shape[1])]
    return np.stack(cols, axis=-1)


@pytest.fixture(scope="module")
def toy():
    """Paper toy: 50 trajectories of 40 samples; the last 10 are held out."""
    rng = np.random.default_rng(0)
    X, g = constrained_trajectories(50, 40, 2, rng)
    held = g >= 40
    return X, potential(X), g, held


@pytest.fixture(scope="module")
def toy_model(toy):
    X, y, g, held = toy
    return LocalLinearRegression(random_state=0).fit(X[~held], y[~held], groups=g[~held])


@pytest.mark.parametrize(
    "n, K, params",
    [(2, 20, {"bandwidth": 0.3}), (22, 20, {"bandwidth": 0.8}), (3, 15, {"smoothing": 2.0})],
)
def test_gradient_equals_central_differences(n, K, params):
    rng = np.random.default_rng(n)
    X, g = constrained_trajectories(K, 30, n, rng, scale=1.0)
    y = np.sin(X).sum(axis=1) + 0.3 * X[:, 0] * X[:, -1]
    reg = LocalLinearRegression(random_state=1, **params).fit(X, y, groups=g)
    Q = X[rng.choice(len(X), 25, replace=False)] + 0.05 * rng.normal(size=(25, n))
    G = reg.gradient(Q)
    assert G.shape == (25, n)
    Gfd = central_differences(reg.predict, Q)
    np.testing.assert_allclose(G, Gfd, rtol=1e-6, atol=1e-8 * np.abs(Gfd).max())
    # Far from every centre the blend widens: still smooth, still the exact gradient.
    far = 4.0 * rng.normal(size=(10, n))
    np.testing.assert_allclose(
        reg.gradient(far), central_differences(reg.predict, far), rtol=1e-5, atol=1e-7
    )


def test_gradient_of_cross_validated_model_equals_central_differences(toy, toy_model):
    X = toy[0][toy[3]]
    G = toy_model.gradient(X)
    Gfd = central_differences(toy_model.predict, X)
    np.testing.assert_allclose(G, Gfd, rtol=1e-6, atol=1e-8 * np.abs(Gfd).max())


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


def test_floored_is_linear_above_the_floor_and_levels_off_below():
    u = np.linspace(-3.0, 2.0, 501)
    phi, dphi = floored(u, -1.0, 0.5)
    above = u >= -1.0
    np.testing.assert_array_equal(phi[above], u[above])
    np.testing.assert_array_equal(dphi[above], 1.0)
    assert np.all(phi > -1.5) and np.all(np.diff(phi) > 0)  # descends by less than w
    eps = 1e-6
    fd = (floored(u + eps, -1.0, 0.5)[0] - floored(u - eps, -1.0, 0.5)[0]) / (2 * eps)
    np.testing.assert_allclose(dphi, fd, atol=1e-6)
    np.testing.assert_array_equal(floored(u, -np.inf, 0.5)[0], u)


@pytest.fixture(scope="module")
def one_sided():
    """Trajectories descending ||x||^2 to the origin, all from the half-plane x_0 > 0."""
    rng = np.random.default_rng(11)
    K, N = 20, 40
    X = np.empty((K, N, 2))
    for k in range(K):
        a = rng.uniform(-0.6, 0.6)
        x = rng.uniform(1.0, 2.0) * np.array([np.cos(a), np.sin(a)])
        for i in range(N):
            X[k, i] = x
            x = 0.8 * x
    X = X.reshape(-1, 2)
    return X, np.sum(X**2, axis=1), np.repeat(np.arange(K), N)


def test_descent_stops_where_the_data_end(one_sided):
    # Linear local models at the minimum, seeing data on one side only, keep sloping
    # down past it: gradient descent left the data (|x| > 20 after 300 steps, from starts
    # at |x| in [1, 2]). Floored, it settled within 0.20 (2 h) of the minimum.
    X, y, g = one_sided
    starts = X[::40][:8]
    final = {}
    for mode in ("linear", "auto"):
        reg = LocalLinearRegression(extrapolation=mode, random_state=0).fit(X, y, groups=g)
        Q = starts.copy()
        for _ in range(300):
            Q = Q - 0.05 * reg.gradient(Q)
        final[mode] = np.linalg.norm(Q, axis=1)
    assert final["linear"].min() > 5.0
    assert final["auto"].max() < 0.25


def test_floors_are_the_lowest_output_of_each_fields_data(one_sided):
    X, y, g = one_sided
    reg = LocalLinearRegression(bandwidth=0.15, random_state=0).fit(X, y, groups=g)
    d2 = np.sum((reg.centers_[:, None, :] - X[None]) ** 2, axis=2)
    inside = d2 < (regression_module.CUTOFF * reg.bandwidth_) ** 2
    lowest = np.where(inside, y[None], np.inf).min(axis=1)
    np.testing.assert_allclose(reg.floors_[:, 0] + reg.intercepts_[:, 0], lowest, atol=1e-12)
    assert np.all(reg.softness_ > 0)


def test_gradient_of_floored_model_equals_central_differences(one_sided):
    X, y, g = one_sided
    reg = LocalLinearRegression(bandwidth=0.15, random_state=0).fit(X, y, groups=g)
    rng = np.random.default_rng(12)
    # Beyond the minimum (x_0 < 0), where the floors are active, and on the data.
    Q = np.vstack([rng.uniform([-1.0, -0.5], [0.1, 0.5], (200, 2)), X[::7]])
    linear = LocalLinearRegression(
        bandwidth=0.15, extrapolation="linear", random_state=0
    ).fit(X, y, groups=g)
    assert np.mean(reg.predict(Q[:200]) > linear.predict(Q[:200]) + 1e-3) > 0.5
    G = reg.gradient(Q)
    Gfd = central_differences(reg.predict, Q)
    np.testing.assert_allclose(G, Gfd, rtol=1e-5, atol=1e-7 * np.abs(Gfd).max())


def test_trajectory_cv_picks_smoother_model_than_pointwise_cv():
    # Potential estimates whose errors drift along each trajectory, as Euler estimates do.
    rng = np.random.default_rng(4)
    X, g = constrained_trajectories(40, 40, 2, rng)
    y = potential(X)
    y = y + 0.02 * y.std() * np.cumsum(rng.normal(size=(40, 40)), axis=1).ravel()
    grid = np.geomspace(0.01, 2.0, 12)
    by_traj = LocalLinearRegression(bandwidth_grid=grid, random_state=0).fit(X, y, groups=g)
    pointwise = LocalLinearRegression(
        bandwidth_grid=grid, cv_criterion="mse", random_state=0
    ).fit(X, y, groups=np.arange(len(X)))
    assert by_traj.bandwidth_ > 2 * grid[0]
    assert by_traj.bandwidth_ > 2 * pointwise.bandwidth_
    pi = -2 * W * X
    # Measured: 0.019 by trajectories, 1.7 point-wise (its gradient is useless).
    assert nupe(pi, -by_traj.gradient(X)) < 0.05
    assert nupe(pi, -pointwise.gradient(X)) > 4 * nupe(pi, -by_traj.gradient(X))


def test_cv_scores_and_attributes(toy_model):
    assert isinstance(toy_model.cv_scores_, dict) and len(toy_model.cv_scores_) >= 3
    assert all(v >= 0 for v in toy_model.cv_scores_.values())
    assert min(toy_model.cv_scores_) <= toy_model.bandwidth_ <= max(toy_model.cv_scores_)
    assert toy_model.ridge_ > 0
    assert toy_model.centers_.shape[1] == 2 and len(toy_model.centers_) <= 3000


def test_ridge_chosen_by_cv_from_its_grid(toy):
    X, y, g, _ = toy
    reg = LocalLinearRegression(ridge="cv", random_state=0).fit(X, y, groups=g)
    assert reg.ridge_ in RIDGE_GRID
    fixed = LocalLinearRegression(bandwidth=0.4, ridge="cv", random_state=0).fit(X, y, groups=g)
    assert fixed.bandwidth_ == 0.4 and list(fixed.cv_scores_) == [0.4]


def test_fixed_bandwidth_skips_cv_and_groups_are_optional():
    rng = np.random.default_rng(5)
    X, _ = constrained_trajectories(10, 30, 2, rng)
    reg = LocalLinearRegression(bandwidth=0.5).fit(X, potential(X))
    assert reg.bandwidth_ == 0.5 and reg.cv_scores_ is None
    # Without groups, CV holds out contiguous blocks.
    reg = LocalLinearRegression(random_state=0).fit(X, potential(X))
    assert reg.cv_scores_ is not None and np.isfinite(reg.predict(X)).all()


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


def test_far_away_queries_are_finite(toy_model):
    far = np.array([[1e6, -1e6], [3e3, 0.0], [-50.0, 80.0]])
    assert np.isfinite(toy_model.predict(far)).all()
    assert np.isfinite(toy_model.gradient(far)).all()


def test_state_round_trip_is_exact_and_pickle_free(toy, toy_model):
    arrays, meta = toy_model.get_state()
    meta = json.loads(json.dumps(meta))
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    buffer.seek(0)
    with np.load(buffer, allow_pickle=False) as data:
        loaded = {k: data[k] for k in data.files}
    model = LocalLinearRegression.from_state(loaded, meta)
    assert {"floors", "softness"} <= set(loaded)
    X = np.vstack([toy[0], [[40.0, -7.0]]])
    np.testing.assert_array_equal(model.predict(X), toy_model.predict(X))
    np.testing.assert_array_equal(model.gradient(X), toy_model.gradient(X))
    assert model.bandwidth_ == toy_model.bandwidth_
    assert model.cv_scores_ == toy_model.cv_scores_
    assert model.get_params() == {**toy_model.get_params(), "random_state": 0}


def test_state_with_the_removed_increment_weight_still_loads(toy, toy_model):
    # Model files written before the derivative equations were removed name the parameter.
    arrays, meta = toy_model.get_state()
    old = {**meta, "params": {**meta["params"], "increment_weight": 0.0}}
    model = LocalLinearRegression.from_state(arrays, json.loads(json.dumps(old)))
    assert "increment_weight" not in model.get_params()
    X = np.vstack([toy[0][:50], [[40.0, -7.0]]])
    np.testing.assert_array_equal(model.gradient(X), toy_model.gradient(X))
    with pytest.raises(TypeError):
        LocalLinearRegression(increment_weight=0.5)


def test_from_state_rejects_bad_state(toy_model):
    arrays, meta = toy_model.get_state()
    with pytest.raises(ValueError, match="newer"):
        LocalLinearRegression.from_state(arrays, {**meta, "version": 99})
    with pytest.raises(ValueError, match="slopes"):
        LocalLinearRegression.from_state({**arrays, "slopes": arrays["slopes"][:-1]}, meta)
    with pytest.raises(ValueError, match="missing"):
        LocalLinearRegression.from_state({"centers": arrays["centers"]}, meta)
    with pytest.raises(ValueError, match="together"):
        LocalLinearRegression.from_state({k: v for k, v in arrays.items() if k != "floors"}, meta)
    with pytest.raises(ValueError, match="softness"):
        LocalLinearRegression.from_state({**arrays, "softness": -arrays["softness"]}, meta)


def test_version_1_state_loads_as_linear_models(toy, toy_model):
    arrays, meta = toy_model.get_state()
    old = {k: v for k, v in arrays.items() if k not in ("floors", "softness")}
    params = {k: v for k, v in meta["params"].items() if k != "extrapolation"}
    model = LocalLinearRegression.from_state(old, {**meta, "version": 1, "params": params})
    assert model.floors_ is None
    linear = LocalLinearRegression(extrapolation="linear", random_state=0)
    linear.fit(toy[0][~toy[3]], toy[1][~toy[3]], groups=toy[2][~toy[3]])
    np.testing.assert_allclose(model.predict(toy[0]), linear.predict(toy[0]), atol=1e-12)


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


def test_thinning_keeps_order_and_every_trajectory():
    rng = np.random.default_rng(9)
    groups = np.repeat(np.arange(30), rng.integers(50, 400, 30))
    idx = thin_trajectories(groups, 3000, rng)
    assert np.all(np.diff(idx) > 0)
    assert set(groups[idx]) == set(range(30))  # thinning is enough: all kept
    assert 1500 <= len(idx) <= 3000
    # Too few points for 25 samples of each trajectory: whole trajectories are dropped.
    idx = thin_trajectories(groups, 300, rng)
    assert len(set(groups[idx])) < 30 and len(idx) <= 300
    np.testing.assert_array_equal(thin_trajectories(groups, 10**6, rng), np.arange(len(groups)))


def test_params_are_stored_untouched():
    grid = [0.1, 0.2]
    reg = LocalLinearRegression(bandwidth_grid=grid, ridge="cv", random_state=3)
    assert reg.get_params()["bandwidth_grid"] is grid
    assert reg.set_params(n_folds=3).n_folds == 3
    with pytest.raises(ValueError, match="unknown parameter"):
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
        ({"smoothing": -1.0}, "smoothing"),
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
    with pytest.raises(ValueError, match="X contains NaN"):
        reg.fit(np.where(X > 2.0, np.nan, X), X[:, 0])
    with pytest.raises(ValueError, match="y contains NaN"):
        reg.fit(X, np.full(50, np.inf))
    with pytest.raises(ValueError, match="X must have shape"):
        reg.fit(X[:, 0], X[:, 0])
    with pytest.raises(ValueError, match="y must have shape"):
        reg.fit(X, X[:-1, 0])
    with pytest.raises(ValueError, match="groups must have shape"):
        reg.fit(X, X[:, 0], groups=np.zeros(3, dtype=int))
    with pytest.raises(ValueError, match="integer"):
        reg.fit(X, X[:, 0], groups=np.zeros(50))
    with pytest.raises(NotFittedError, match="not fitted"):
        reg.predict(X)
    assert issubclass(NotFittedError, ValueError)
    with pytest.raises(ValueError, match=r"shape \(m, 2\)"):
        toy_model.predict(np.zeros((3, 5)))
    with pytest.raises(ValueError, match="NaN"):
        toy_model.gradient(np.array([[0.0, np.nan]]))


@pytest.mark.parametrize("n, bandwidth", [(2, 0.3), (22, 0.8)])
def test_gradient_with_adaptive_widths_equals_central_differences(n, bandwidth):
    rng = np.random.default_rng(n + 2)
    X, g = constrained_trajectories(20, 30, n, rng, scale=1.0)
    y = np.sin(X).sum(axis=1) + 0.3 * X[:, 0] * X[:, -1]
    reg = LocalLinearRegression(bandwidth=bandwidth, widths="adaptive", random_state=1)
    reg.fit(X, y, groups=g)
    assert reg.widths_.shape == (len(reg.centers_),)
    assert np.ptp(reg.widths_) > 0  # the widths do differ
    Q = X[rng.choice(len(X), 25, replace=False)] + 0.05 * rng.normal(size=(25, n))
    Gfd = central_differences(reg.predict, Q)
    np.testing.assert_allclose(reg.gradient(Q), Gfd, rtol=1e-6, atol=1e-8 * np.abs(Gfd).max())
    far = 4.0 * rng.normal(size=(10, n))
    np.testing.assert_allclose(
        reg.gradient(far), central_differences(reg.predict, far), rtol=1e-5, atol=1e-7
    )


def test_adaptive_widths_are_narrower_where_data_are_denser():
    rng = np.random.default_rng(11)
    # Dense cluster at the origin, sparse ring around it.
    dense = 0.05 * rng.normal(size=(2000, 2))
    angle = rng.uniform(0, 2 * np.pi, 400)
    sparse = np.column_stack([np.cos(angle), np.sin(angle)]) * rng.uniform(0.5, 2.0, (400, 1))
    X = np.vstack([dense, sparse])
    reg = LocalLinearRegression(bandwidth=0.2, widths="adaptive", random_state=0)
    reg.fit(X, potential(X))
    radius = np.linalg.norm(reg.centers_, axis=1)
    inner, outer = reg.widths_[radius < 0.1], reg.widths_[radius > 0.5]
    assert len(inner) and len(outer)
    assert inner.max() < outer.min()
    lo, hi = regression_module.ADAPT_CLIP
    assert np.all((reg.widths_ >= lo * 0.2 - 1e-12) & (reg.widths_ <= hi * 0.2 + 1e-12))
    assert LocalLinearRegression(bandwidth=0.2).fit(X, potential(X)).widths_ is None


def test_state_round_trip_with_adaptive_widths(toy):
    X, y, g, _ = toy
    reg = LocalLinearRegression(widths="adaptive", random_state=4).fit(X, y, groups=g)
    arrays, meta = reg.get_state()
    assert arrays["widths"].shape == (len(reg.centers_),)
    model = LocalLinearRegression.from_state(arrays, json.loads(json.dumps(meta)))
    np.testing.assert_array_equal(model.widths_, reg.widths_)
    Q = np.vstack([X[:50], [[40.0, -7.0]]])
    np.testing.assert_array_equal(model.gradient(Q), reg.gradient(Q))
    with pytest.raises(ValueError, match="widths"):
        LocalLinearRegression.from_state({**arrays, "widths": arrays["widths"][:-1]}, meta)
    with pytest.raises(ValueError, match="widths"):
        LocalLinearRegression.from_state({**arrays, "widths": -arrays["widths"]}, meta)


def test_version_2_state_loads_with_the_global_width(toy):
    X, y, g, _ = toy
    reg = LocalLinearRegression(widths="global", random_state=0).fit(X, y, groups=g)
    arrays, meta = reg.get_state()
    assert "widths" not in arrays
    params = {k: v for k, v in meta["params"].items() if k != "widths"}
    model = LocalLinearRegression.from_state(arrays, {**meta, "version": 2, "params": params})
    assert model.widths_ is None and model.widths == "cv"
    np.testing.assert_array_equal(model.predict(X), reg.predict(X))


@pytest.mark.parametrize("n", [2, 22])
def test_cv_widths_fit_the_model_of_the_chosen_option(n):
    rng = np.random.default_rng(n + 3)
    X, g = constrained_trajectories(30, 30, n, rng, scale=1.0)
    y = potential(X)
    reg = LocalLinearRegression(widths="cv", random_state=2).fit(X, y, groups=g)
    chosen = "global" if reg.widths_ is None else "adaptive"
    same = LocalLinearRegression(widths=chosen, random_state=2).fit(X, y, groups=g)
    assert same.bandwidth_ == reg.bandwidth_
    np.testing.assert_array_equal(same.gradient(X[:40]), reg.gradient(X[:40]))


@pytest.mark.parametrize(
    "n, bandwidth, dense_fraction",
    [(2, 0.3, None), (22, 0.8, -1.0), (22, 0.8, 2.0)],
    ids=["kd-tree", "dense-blocks", "sparse-blocks"],
)
def test_equal_per_field_widths_blend_as_the_global_width(
    monkeypatch, n, bandwidth, dense_fraction
):
    # One neighbour search serves both; with a common width it keeps H^2 per point, per
    # field it folds dH_j^2/dt into every weight and bounds the support more loosely.
    if dense_fraction is not None:  # every block dense, or every block sparse
        monkeypatch.setattr(regression_module, "DENSE_FRACTION", dense_fraction)
    rng = np.random.default_rng(n + 4)
    X, g = constrained_trajectories(20, 30, n, rng, scale=1.0)
    y = np.sin(X).sum(axis=1) + 0.3 * X[:, 0] * X[:, -1]
    reg = LocalLinearRegression(bandwidth=bandwidth, widths="global", random_state=1)
    reg.fit(X, y, groups=g)
    arrays, meta = reg.get_state()
    arrays["widths"] = np.full(len(reg.centers_), bandwidth)
    equal = LocalLinearRegression.from_state(arrays, meta)
    Q = np.vstack([
        X[rng.choice(len(X), 40, replace=False)] + 0.05 * rng.normal(size=(40, n)),
        4.0 * rng.normal(size=(10, n)),
    ])
    np.testing.assert_allclose(equal.predict(Q), reg.predict(Q), rtol=1e-12, atol=1e-14)
    G = reg.gradient(Q)
    np.testing.assert_allclose(equal.gradient(Q), G, rtol=1e-10, atol=1e-12 * np.abs(G).max())
