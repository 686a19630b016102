"""Fixtures of the tests of the local-linear regression."""

import numpy as np
import pytest
from local_linear_data import constrained_trajectories, potential

from policy_align_ros.learning.baselines.local_linear import LocalLinearRegression


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
