"""Tests of the local-linear kernels, centres and blend: exact gradients, floors, widths."""

import numpy as np
import pytest
from local_linear_data import central_differences, constrained_trajectories, potential

import policy_align_ros.learning.baselines.local_linear.centres as centres_module
from policy_align_ros.learning.baselines.local_linear import LocalLinearRegression
from policy_align_ros.learning.baselines.local_linear.blend import floored
from policy_align_ros.learning.baselines.local_linear.kernels import CUTOFF


@pytest.mark.parametrize(
    "n, K, params",
    [(2, 20, {"bandwidth": 0.3}), (22, 20, {"bandwidth": 0.8})],
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
    inside = d2 < (CUTOFF * reg.bandwidth_) ** 2
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


def test_far_away_queries_are_finite(toy_model):
    far = np.array([[1e6, -1e6], [3e3, 0.0], [-50.0, 80.0]])
    assert np.isfinite(toy_model.predict(far)).all()
    assert np.isfinite(toy_model.gradient(far)).all()


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
    lo, hi = centres_module.ADAPT_CLIP
    assert np.all((reg.widths_ >= lo * 0.2 - 1e-12) & (reg.widths_ <= hi * 0.2 + 1e-12))
    assert LocalLinearRegression(bandwidth=0.2).fit(X, potential(X)).widths_ is None


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
        monkeypatch.setattr(centres_module, "DENSE_FRACTION", dense_fraction)
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
