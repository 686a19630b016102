"""Tests of the global model's helpers (policy_align_ros.learning.global_model)."""

import math

import numpy as np

from policy_align_ros.learning.global_model import (
    cv_error,
    cv_score,
    fixed_copy,
    level_free,
    training_set,
)
from policy_align_ros.learning.regressors import TrendKernelRegression
from policy_align_ros.learning.trajectory import Trajectory


def _bowl_data(seed=0, k=6):
    rng = np.random.default_rng(seed)
    X, y, g = [], [], []
    for j in range(k):
        x = rng.uniform(-1, 1, 2) * np.linspace(1.0, 0.05, 40)[:, None]
        X.append(x)
        y.append(np.sum(x**2, axis=1) + 0.3 * j)  # each demonstration at its own level
        g.append(np.full(40, j))
    return np.concatenate(X), np.concatenate(y), np.concatenate(g)


def test_a_fixed_copy_scores_the_same_data_as_the_cv_pick():
    X, y, g = _bowl_data()
    fitted = TrendKernelRegression(n_folds=3, offset_ridge=0.0).fit(X, y, groups=g)
    fixed = fixed_copy(fitted)
    assert fixed.n_folds == 3 and not hasattr(fixed, "cv_best_")
    assert fixed_copy(fitted, n_folds=2).n_folds == 2
    refit = fixed.fit(X, y, groups=g)
    assert refit.kernel_ridge_ == fitted.kernel_ridge_
    if math.isfinite(fitted.kernel_ridge_):  # the length scale of a residual it has
        assert refit.length_scale_ == fitted.length_scale_
    np.testing.assert_allclose(refit.predict(X), fitted.predict(X), rtol=1e-9, atol=1e-12)
    assert math.isclose(cv_score(refit), cv_score(fitted), rel_tol=1e-6, abs_tol=1e-12)
    assert math.isfinite(cv_error(refit))


def test_no_cv_score_without_a_cv_choice():
    X, y, g = _bowl_data()
    model = TrendKernelRegression(n_folds=3, trend_form="quadratic", trend_ridge=1.0,
                                  length_scale=1.0, kernel_ridge=1.0, offset_ridge=0.0)
    assert cv_score(object()) is None and math.isnan(cv_error(object()))
    assert cv_score(model) is None  # not fitted: nothing chosen
    assert fixed_copy(model).get_params() == model.get_params()  # nothing to fix


def test_training_set_stacks_the_training_samples_of_the_kept_trajectories():
    trajs = [Trajectory(positions=np.full((4, 2), float(k))) for k in range(3)]
    masks = [np.array([True, False, True, True])] * 3
    potentials = [np.arange(4.0) + 10 * k for k in range(3)]
    X, y, g, extra = training_set(trajs, masks, np.array([0, 2]), potentials,
                                  np.zeros(0, dtype=int), TrendKernelRegression())
    assert X.shape == (6, 2) and set(g) == {0, 2}
    np.testing.assert_array_equal(y, [0, 2, 3, 20, 22, 23])
    assert extra == {}


def test_an_anchored_training_set_carries_each_samples_step_and_drop():
    # With a goal, the regressor is given each training sample's step and the potential's
    # change over it, from the whole trajectory (the masked sample's neighbours count).
    trajs = [Trajectory(positions=np.column_stack([np.arange(4.0) * (k + 1), np.zeros(4)]))
             for k in range(2)]
    masks = [np.array([True, False, True, True])] * 2
    potentials = [np.array([9.0, 5.0, 2.0, 1.0]) * (k + 1) for k in range(2)]
    _, _, _, extra = training_set(trajs, masks, np.array([0, 1]), potentials,
                                  np.zeros(0, dtype=int), TrendKernelRegression(),
                                  goal=np.zeros(2))
    np.testing.assert_array_equal(extra["goal"], np.zeros(2))
    np.testing.assert_allclose(extra["motion"][:, 0], [1, 1, 1, 2, 2, 2])
    np.testing.assert_allclose(extra["drops"], [-4, -2, -1, -8, -4, -2])


def test_level_free_moves_free_trajectories_to_the_model():
    class Flat:
        def predict(self, X):
            return np.full(len(X), 5.0)

    trajs = [Trajectory(positions=np.zeros((3, 1))) for _ in range(2)]
    masks = [np.ones(3, dtype=bool)] * 2
    offsets, pots = level_free(np.zeros(2), [np.zeros(3), np.ones(3)], np.array([1]),
                               Flat(), trajs, masks)
    np.testing.assert_allclose(offsets, [0.0, 4.0])
    np.testing.assert_allclose(pots[1], 5.0)
    np.testing.assert_allclose(pots[0], 0.0)
