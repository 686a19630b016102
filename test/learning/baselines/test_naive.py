"""Tests of the naive baseline (policy_align_ros.learning.baselines.naive)."""

import json

import numpy as np
import pytest

from policy_align_ros.learning import PolicyAlign, as_trajectories
from policy_align_ros.learning.base import NotFittedError
from policy_align_ros.learning.baselines import LocalLinearRegression
from policy_align_ros.learning.baselines.naive import NaivePolicy, velocity_samples
from policy_align_ros.learning.trajectory import Trajectory

RATE = 0.1  # pi(x) = -RATE x, the gradient flow of phi = 0.05 ||x||^2


def rollouts(K, N, rng, constraint=None, dt=1.0):
    """Trajectories of xdot = N pi(x), Euler steps of dt seconds, starts in [-2, 2]^2."""
    P = np.eye(2) if constraint is None else np.eye(2) - np.outer(constraint, constraint)
    out = []
    for _ in range(K):
        x = rng.uniform(-2, 2, 2)
        xs = [x]
        for _ in range(N - 1):
            x = x + dt * P @ (-RATE * x)
            xs.append(x)
        out.append(np.array(xs))
    return out


def test_velocity_samples_by_forward_differences_and_from_measurements():
    q = np.array([[0.0, 0.0], [1.0, 2.0], [1.5, 2.0]])
    timed = Trajectory(q, times=[0.0, 0.5, 1.5])
    X, V, g = velocity_samples([timed, Trajectory(q)])
    np.testing.assert_array_equal(X, np.vstack([q[:2], q[:2]]))
    np.testing.assert_allclose(V, [[2.0, 4.0], [0.5, 0.0], [1.0, 2.0], [0.5, 0.0]])
    np.testing.assert_array_equal(g, [0, 0, 1, 1])
    v = np.ones_like(q)
    X, V, g = velocity_samples([Trajectory(q, velocities=v)])
    np.testing.assert_array_equal(X, q)  # measured velocities: no sample dropped
    np.testing.assert_array_equal(V, v)


def test_learns_an_unconstrained_policy():
    rng = np.random.default_rng(0)
    model = NaivePolicy(random_state=0).fit(rollouts(30, 30, rng))
    Q = rng.uniform(-1.5, 1.5, (200, 2))
    pi = -RATE * Q
    err = np.mean(np.sum((model.policy(Q) - pi) ** 2, axis=1)) / np.sum(np.var(pi, axis=0))
    assert model.policy(Q).shape == (200, 2)
    assert err < 0.01  # measured 1e-5


def test_learns_the_constrained_motion_not_the_policy():
    # Every demonstration moves only along x2: the naive model reproduces that motion
    # and cannot recover the x1 component of pi, which is what PolicyAlign is for.
    rng = np.random.default_rng(1)
    trajs = rollouts(30, 30, rng, constraint=np.array([1.0, 0.0]))
    model = NaivePolicy(random_state=0).fit(trajs)
    X = np.vstack([t[:-1] for t in trajs])
    pred = model.policy(X)
    np.testing.assert_allclose(pred[:, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(pred[:, 1], -RATE * X[:, 1], atol=0.02 * np.abs(X[:, 1]).max())
    assert np.mean((pred[:, 0] + RATE * X[:, 0]) ** 2) > 0.5 * np.mean((RATE * X[:, 0]) ** 2)


def test_times_give_velocities_per_second():
    rng = np.random.default_rng(2)
    arrays = rollouts(20, 30, rng, dt=0.5)
    timed = [Trajectory(q, times=0.5 * np.arange(len(q))) for q in arrays]
    fixed = LocalLinearRegression(bandwidth=0.5, cv_criterion="mse", random_state=0)
    per_step = NaivePolicy(regressor=fixed).fit(arrays)
    per_second = NaivePolicy(regressor=fixed).fit(timed)
    Q = rng.uniform(-1, 1, (20, 2))
    np.testing.assert_allclose(per_second.policy(Q), 2.0 * per_step.policy(Q), rtol=1e-9)


def test_state_round_trip():
    rng = np.random.default_rng(3)
    model = NaivePolicy(random_state=0).fit(rollouts(15, 20, rng))
    arrays, meta = model.get_state()
    meta = json.loads(json.dumps(meta))
    loaded = NaivePolicy.from_state({k: v.copy() for k, v in arrays.items()}, meta)
    Q = rng.normal(size=(30, 2))
    np.testing.assert_array_equal(loaded.policy(Q), model.policy(Q))
    with pytest.raises(ValueError, match="naive"):
        NaivePolicy.from_state(arrays, {**meta, "kind": "policy_align"})
    with pytest.raises(ValueError, match=r"\b99\b"):
        NaivePolicy.from_state(arrays, {**meta, "version": 99})


def test_bad_input():
    with pytest.raises(NotFittedError):
        NaivePolicy().policy(np.zeros((1, 2)))
    with pytest.raises(ValueError):
        NaivePolicy().fit([])
    with pytest.raises(ValueError, match="trajectory 1"):
        NaivePolicy().fit([np.zeros((5, 2)), np.zeros((5, 3))])
    fixed = LocalLinearRegression(bandwidth=0.5, cv_criterion="mse")
    model = NaivePolicy(regressor=fixed).fit([np.cumsum(np.ones((6, 2)), axis=0)] * 2)
    with pytest.raises(ValueError, match=r"\(m, 2\)"):
        model.policy(np.zeros((2, 3)))


def test_default_regressor_and_parameters():
    # The default regressor is the multi-output LocalLinearRegression scoring plain squared
    # errors in CV, seeded by random_state, whose default is PolicyAlign's.
    assert NaivePolicy().random_state == PolicyAlign().random_state == 0
    rng = np.random.default_rng(4)
    trajs = rollouts(15, 20, rng)
    model = NaivePolicy(random_state=3).fit(trajs)
    same = LocalLinearRegression(cv_criterion="mse", random_state=3)
    X, V, g = velocity_samples(as_trajectories(trajs))
    Q = rng.normal(size=(30, 2))
    np.testing.assert_array_equal(model.policy(Q), same.fit(X, V, groups=g).predict(Q))
    given = LocalLinearRegression(bandwidth=0.5, cv_criterion="mse")
    naive = NaivePolicy(regressor=given)
    assert naive.get_params()["regressor__bandwidth"] == 0.5
    naive.fit(trajs)
    assert naive.regressor_ is not given and not hasattr(given, "centers_")
    assert repr(naive).startswith("NaivePolicy(regressor=LocalLinearRegression(")


def test_state_of_a_given_regressor_round_trips():
    rng = np.random.default_rng(5)
    given = LocalLinearRegression(bandwidth=0.5, cv_criterion="mse", random_state=1)
    model = NaivePolicy(regressor=given).fit(rollouts(15, 20, rng))
    arrays, meta = model.get_state()
    loaded = NaivePolicy.from_state(arrays, json.loads(json.dumps(meta)))
    assert loaded.regressor.get_params() == given.get_params()
    Q = rng.normal(size=(30, 2))
    np.testing.assert_array_equal(loaded.policy(Q), model.policy(Q))
    default = NaivePolicy().fit(rollouts(15, 20, rng))
    assert NaivePolicy.from_state(*default.get_state()).regressor is None


@pytest.mark.parametrize("smoothing", [None, 0.0])
def test_version_1_state_loads(smoothing):
    # Version 1 headers hold the regressor's parameters in the naive policy's own.
    rng = np.random.default_rng(6)
    model = NaivePolicy(random_state=0).fit(rollouts(15, 20, rng))
    arrays, meta = model.get_state()
    old_params = {"bandwidth": "cv", "bandwidth_grid": None, "n_folds": 5, "ridge": None,
                  "max_centers": None, "smoothing": smoothing, "random_state": 0}
    reg_meta = {**meta["regressor"],
                "params": {**meta["regressor"]["params"], "smoothing": smoothing or 0.0}}
    old = {"version": 1, "kind": "naive", "params": old_params, "regressor": reg_meta}
    loaded = NaivePolicy.from_state(arrays, json.loads(json.dumps(old)))
    assert loaded.regressor is None and loaded.random_state == 0
    Q = rng.normal(size=(30, 2))
    np.testing.assert_array_equal(loaded.policy(Q), model.policy(Q))
    old["params"] = {**old_params, "bandwidth": 0.5}
    reg_meta["params"]["bandwidth"] = 0.5
    loaded = NaivePolicy.from_state(arrays, json.loads(json.dumps(old)))
    assert loaded.regressor.bandwidth == 0.5
