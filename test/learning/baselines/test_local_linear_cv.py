"""Tests of the local-linear regression's choice of the width by cross-validation."""

import numpy as np
import pytest
from local_linear_data import W, constrained_trajectories, nupe, potential

from policy_align_ros.learning.baselines.local_linear import LocalLinearRegression


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


def test_fixed_bandwidth_skips_cv_and_groups_are_optional():
    rng = np.random.default_rng(5)
    X, _ = constrained_trajectories(10, 30, 2, rng)
    reg = LocalLinearRegression(bandwidth=0.5).fit(X, potential(X))
    assert reg.bandwidth_ == 0.5 and reg.cv_scores_ is None
    # Without groups, CV holds out contiguous blocks.
    reg = LocalLinearRegression(random_state=0).fit(X, potential(X))
    assert reg.cv_scores_ is not None and np.isfinite(reg.predict(X)).all()


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
