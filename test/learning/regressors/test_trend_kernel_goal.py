"""A goal-centred TrendKernelRegression: stationary exactly at the goal it is given."""


import copy
import math

import numpy as np
import pytest

from policy_align_ros.learning.anchor import goal_curvature
from policy_align_ros.learning.regressors import TrendKernelRegression, takes_drops, takes_goal
from policy_align_ros.learning.regressors.trend_kernel.features import (
    _gaussian,
    _kernel,
    _kernel_directions,
    _kernel_gradient,
    _kernel_jacobian,
    _kernel_value_gradient,
)
from policy_align_ros.learning.regressors.trend_kernel.grams import (
    _MEMO,
    along_motion,
    direction_bases,
    direction_rows,
    shared_sums,
)


def _bowl_data(goal, n_demos=8, seed=0):
    # Values of a skewed bowl with a bump, sampled along straight demonstrations.
    rng = np.random.default_rng(seed)
    H = np.array([[2.0, 0.5], [0.5, 1.0]])
    X, y, g = [], [], []
    for k in range(n_demos):
        start = goal + rng.uniform(-2.0, 2.0, 2)
        s = np.linspace(0.0, 1.0, 40)[:, None]
        P = start + s * (goal - start)
        d = P - goal
        X.append(P)
        y.append(np.einsum("ij,jk,ik->i", d, H, d) + 0.3 * np.exp(-np.sum((P - goal - 1.0)
                                                                         ** 2, axis=1)))
        g.append(np.full(len(P), k))
    return np.concatenate(X), np.concatenate(y), np.concatenate(g)


def test_gradient_vanishes_at_the_goal_and_matches_finite_differences():
    goal = np.array([0.4, -0.7])
    X, y, g = _bowl_data(goal)
    model = TrendKernelRegression().fit(X, y, groups=g, goal=goal)
    assert takes_goal(model)
    assert np.allclose(model.gradient(goal[None]), 0.0, atol=1e-9)
    rng = np.random.default_rng(1)
    Q = goal + rng.normal(size=(20, 2))
    h = 1e-6
    numeric = np.stack([(model.predict(Q + h * e) - model.predict(Q - h * e)) / (2 * h)
                        for e in np.eye(2)], axis=1)
    assert np.allclose(model.gradient(Q), numeric, atol=1e-5 * np.abs(numeric).max())


def test_goal_is_a_minimum_that_descent_reaches():
    goal = np.array([0.4, -0.7])
    X, y, g = _bowl_data(goal)
    model = TrendKernelRegression().fit(X, y, groups=g, goal=goal)
    x = goal + np.array([1.5, -1.0])
    for _ in range(4000):
        x = x - 0.01 * model.gradient(x[None])[0]
    assert np.linalg.norm(x - goal) < 1e-3


def test_goal_round_trips_and_states_without_it_load():
    goal = np.array([0.4, -0.7])
    X, y, g = _bowl_data(goal)
    model = TrendKernelRegression().fit(X, y, groups=g, goal=goal)
    arrays, meta = model.get_state()
    copy = TrendKernelRegression.from_state(arrays, meta)
    Q = np.random.default_rng(2).normal(size=(10, 2))
    assert np.array_equal(copy.gradient(Q), model.gradient(Q))
    plain = TrendKernelRegression().fit(X, y, groups=g)
    arrays, meta = plain.get_state()
    meta.pop("goal")  # a state written before goal-centred models
    assert TrendKernelRegression.from_state(arrays, meta).goal_ is None


def test_bad_goal_is_refused():
    X, y, g = _bowl_data(np.zeros(2))
    with pytest.raises(ValueError, match="goal"):
        TrendKernelRegression().fit(X, y, groups=g, goal=np.zeros(3))


def _bundle(seed=0):
    # Demonstrations bundled along one bent path into the goal (the origin), with values
    # that fall along it: the values alone leave the slope across the bundle free.
    rng = np.random.default_rng(seed)
    X, y, g, steps = [], [], [], []
    s = np.linspace(0.0, 1.0, 60)
    for k in range(6):
        offset = rng.normal(scale=0.02, size=2)
        path = np.stack([-1.0 + s, 0.8 * np.sin(np.pi * s)], axis=1) + offset * (1 - s)[:, None]
        X.append(path)
        y.append((1.0 - s) ** 2)
        g.append(np.full(len(s), k))
        steps.append(np.gradient(path, axis=0))
    return (np.concatenate(X), np.concatenate(y), np.concatenate(g),
            np.concatenate(steps))


def test_motion_makes_the_gradient_follow_bundled_demonstrations():
    X, y, g, steps = _bundle()
    goal = np.zeros(2)

    def alignment(model):
        # Cosine between the policy and the motion, over the first two thirds of the path.
        pi = -model.gradient(X)
        cos = np.sum(pi * steps, axis=1) / (np.linalg.norm(pi, axis=1)
                                           * np.linalg.norm(steps, axis=1))
        return float(np.median(cos[np.tile(np.arange(60) < 40, 6)]))

    # As many centres as samples allow: the fit without motion can then bend the field
    # across the bundle (with the 25 per demonstration of "auto" it happens not to here).
    free = TrendKernelRegression(n_centres=300).fit(X, y, groups=g, goal=goal)
    guided = TrendKernelRegression(n_centres=300).fit(X, y, groups=g, goal=goal,
                                                      motion=steps)
    assert alignment(guided) > 0.99 and alignment(free) < 0.9
    assert np.allclose(guided.gradient(goal[None]), 0.0, atol=1e-9)
    with pytest.raises(ValueError, match="direction_weight"):
        TrendKernelRegression(direction_weight=-1.0).fit(X, y, groups=g, goal=goal,
                                                         motion=steps)
    with pytest.raises(ValueError, match="direction_weight"):
        TrendKernelRegression(direction_weight="large").fit(X, y, groups=g, goal=goal,
                                                            motion=steps)


def test_auto_direction_weight_outside_policy_align_is_the_smallest():
    X, y, g, steps = _bundle()
    goal = np.zeros(2)
    auto = TrendKernelRegression().fit(X, y, groups=g, goal=goal, motion=steps)
    fixed = TrendKernelRegression(direction_weight=10.0).fit(X, y, groups=g, goal=goal,
                                                             motion=steps)
    strong = TrendKernelRegression(direction_weight=1000.0).fit(X, y, groups=g, goal=goal,
                                                                motion=steps)
    np.testing.assert_array_equal(auto.gradient(X), fixed.gradient(X))
    assert not np.allclose(strong.gradient(X), fixed.gradient(X))


@pytest.mark.parametrize("pinned", [False, True])
def test_kernel_direction_rows_project_the_kernel_gradients(pinned):
    # The direction rows come from two products per feature instead of its gradient; the
    # gradient itself matches finite differences of the features.
    rng = np.random.default_rng(5)
    Z, C = rng.normal(size=(30, 3)), rng.normal(size=(7, 3))
    J = _kernel_jacobian(Z, C, 0.8, pinned)
    h = 1e-6
    numeric = np.stack([(_kernel(Z + h * e, C, 0.8, pinned) - _kernel(Z - h * e, C, 0.8, pinned))
                        / (2 * h) for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(J, numeric, atol=1e-8)
    B = direction_bases(rng.normal(size=(30, 3)), 10.0)
    np.testing.assert_allclose(_kernel_directions(B, Z, C, 0.8, pinned),
                               direction_rows(B, J), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("pinned", [False, True])
def test_kernel_features_and_their_gradient_are_the_formulas(pinned):
    # The features are computed in place, in one buffer; they must still be the Gaussians
    # exp(-|z - c|^2 / (2 l^2)) (less the pinned term) and their weighted gradient J alpha.
    rng = np.random.default_rng(6)
    Z, C, alpha = rng.normal(size=(40, 3)), rng.normal(size=(9, 3)), rng.normal(size=9)
    direct = np.exp(-np.sum((Z[:, None, :] - C[None]) ** 2, axis=2) / (2 * 0.7**2))
    np.testing.assert_allclose(_gaussian(Z, C, 0.7), direct, rtol=1e-12, atol=1e-15)
    if not pinned:
        np.testing.assert_allclose(_kernel(Z, C, 0.7, pinned), direct, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(_kernel_gradient(Z, C, 0.7, alpha, pinned),
                               _kernel_jacobian(Z, C, 0.7, pinned) @ alpha, rtol=1e-10,
                               atol=1e-13)


@pytest.mark.parametrize("pinned", [False, True])
def test_value_and_gradient_from_one_kernel_block_equal_the_two_calls(pinned):
    # A descent takes both from one Gaussian block; they must equal the separate features'
    # value and gradient to the last bit, so that the descents' results do not move.
    rng = np.random.default_rng(7)
    Z, C, alpha = rng.normal(size=(25, 3)), rng.normal(size=(8, 3)), rng.normal(size=8)
    value, gradient = _kernel_value_gradient(Z, C, 0.9, alpha, pinned)
    assert np.array_equal(value, _kernel(Z, C, 0.9, pinned) @ alpha)
    assert np.array_equal(gradient, _kernel_gradient(Z, C, 0.9, alpha, pinned))
    X, y, groups = _bowl_data(np.array([0.3, -0.2]))
    for goal in (None, np.array([0.3, -0.2])):
        model = TrendKernelRegression(trend_form="quadratic", length_scale=0.8,
                                      kernel_ridge=1e-4, random_state=0)
        model.fit(X, y + 0.05 * np.sin(3 * X[:, 0]), groups=groups, goal=goal)
        assert len(model.alpha_)
        value, gradient = model.value_and_gradient(X[:7])
        assert np.array_equal(value, model.predict(X[:7]))
        assert np.array_equal(gradient, model.gradient(X[:7]))


@pytest.mark.parametrize("n", [1, 2, 3, 7])
def test_direction_bases_penalise_the_slope_across_the_motion_as_the_projector(n):
    # n - 1 rows per sample whose squares sum to weight |s|^2 (I - s s' / |s|^2); a step of
    # zero gives zero rows.
    rng = np.random.default_rng(n)
    steps = rng.normal(size=(20, n))
    steps[3] = 0.0
    steps[4] = -np.abs(steps[4])  # either sign of the first coordinate
    B = direction_bases(steps, 10.0)
    assert B.shape == (20, n - 1, n)
    norm2 = np.sum(steps**2, axis=1)
    unit = steps / np.sqrt(np.maximum(norm2, 1e-300))[:, None]
    expected = 10.0 * norm2[:, None, None] * (np.eye(n) - unit[:, :, None] * unit[:, None, :])
    expected[3] = 0.0
    np.testing.assert_allclose(np.einsum("mri,mrj->mij", B, B), expected, atol=1e-12)


def _lines(goal, n_demos=6, seed=3):
    # Straight demonstrations into the goal of the bowl |x - goal|^2, with its values, each
    # sample's central step and the values' change over it.
    rng = np.random.default_rng(seed)
    X, y, g, steps, drops = [], [], [], [], []
    for k in range(n_demos):
        angle = 2 * np.pi * k / n_demos + rng.uniform(-0.2, 0.2)
        start = goal + rng.uniform(1.5, 2.5) * np.array([np.cos(angle), np.sin(angle)])
        P = start + np.linspace(0.0, 1.0, 60)[:, None] ** 0.7 * (goal - start)
        values = np.sum((P - goal) ** 2, axis=1)
        X.append(P)
        y.append(values)
        g.append(np.full(len(P), k))
        steps.append(np.gradient(P, axis=0))
        drops.append(np.gradient(values))
    return (np.concatenate(X), np.concatenate(y), np.concatenate(g), np.concatenate(steps),
            np.concatenate(drops))


def test_along_motion_rows_observe_the_slope_along_and_zero_across():
    # For a linear potential g'z, each sample's rows minus their targets vanish when the
    # drops are g's, and a step too short to have a direction gets no row along.
    rng = np.random.default_rng(7)
    steps = rng.normal(size=(25, 3))
    steps[5] *= 1e-3
    grad = rng.normal(size=3)
    for k in range(25):  # every step along the gradient, to be downhill-consistent
        steps[k] = np.linalg.norm(steps[k]) * grad / np.linalg.norm(grad)
    across = direction_bases(steps, 10.0)
    bases, targets = along_motion(steps, steps @ grad, across, 30.0)
    assert bases.shape == (25, 3, 3) and targets.shape == (25, 3)
    np.testing.assert_allclose(bases @ grad, targets, atol=1e-9)
    assert np.all(bases[5, 0] == 0.0) and targets[5, 0] == 0.0
    np.testing.assert_array_equal(bases[:, 1:], across)
    # Every moving sample's row along weighs the same whatever its speed.
    moving = np.delete(np.arange(25), 5)
    np.testing.assert_allclose(np.linalg.norm(bases[moving, 0], axis=1),
                               np.sqrt(30.0) * np.median(np.linalg.norm(steps, axis=1)))


def test_drops_consistent_with_the_values_keep_the_bowl():
    goal = np.array([0.3, -0.2])
    X, y, g, steps, drops = _lines(goal)
    model = TrendKernelRegression().fit(X, y, groups=g, goal=goal, motion=steps, drops=drops)
    assert takes_drops(model)
    np.testing.assert_allclose(model.gradient(X), 2 * (X - goal), atol=1e-3)


def test_drops_set_the_slope_along_the_motion():
    # The values are the bowl's, but the drops say it falls twice as steeply: with a
    # strong weight, the fit with them is steeper along the motion than the fit on the
    # values alone, and still stationary at the goal.
    goal = np.array([0.3, -0.2])
    X, y, g, steps, drops = _lines(goal)
    strong = TrendKernelRegression(direction_weight=1000.0)
    steep = copy.deepcopy(strong).fit(X, y, groups=g, goal=goal, motion=steps, drops=2.0 * drops)
    without = copy.deepcopy(strong).fit(X, y, groups=g, goal=goal, motion=steps)

    def slope(model):
        return np.median(np.abs(np.sum(model.gradient(X) * steps, axis=1) / drops))

    assert slope(without) == pytest.approx(1.0, abs=0.01)
    assert slope(steep) > 1.2
    assert np.allclose(steep.gradient(goal[None]), 0.0, atol=1e-9)
    with pytest.raises(ValueError, match="drops"):
        TrendKernelRegression().fit(X, y, groups=g, goal=goal, drops=drops)
    with pytest.raises(ValueError, match="drops"):
        TrendKernelRegression().fit(X, y, groups=g, goal=goal, motion=steps, drops=drops[:-1])


def test_a_refit_on_other_targets_sharing_the_sums_equals_a_fresh_fit():
    # Within shared_sums a second fit on the same samples with other values and drops (each
    # demonstration on another clock) reuses the first fit's Grams, and its model is the
    # fresh fit's to the last bit; outside the context nothing is kept.
    goal = np.array([0.3, -0.2])
    X, y, g, steps, drops = _lines(goal)
    factor = np.linspace(0.7, 1.4, g.max() + 1)[g]
    template = TrendKernelRegression(direction_weight=100.0, random_state=0)
    fresh = copy.deepcopy(template).fit(X, factor * y, groups=g, goal=goal, motion=steps,
                                        drops=factor * drops)
    with shared_sums() as memo:
        copy.deepcopy(template).fit(X, y, groups=g, goal=goal, motion=steps, drops=drops)
        misses = memo.misses
        shared = copy.deepcopy(template).fit(X, factor * y, groups=g, goal=goal,
                                             motion=steps, drops=factor * drops)
    assert memo.hits > 0 and memo.misses == misses  # every sum of the refit was shared
    assert shared.cv_best_ == fresh.cv_best_
    np.testing.assert_array_equal(shared.trend_, fresh.trend_)
    np.testing.assert_array_equal(shared.alpha_, fresh.alpha_)
    assert _MEMO.get() is None


def test_the_memo_keeps_at_most_its_bytes():
    goal = np.array([0.3, -0.2])
    X, y, g, steps, drops = _lines(goal)
    with shared_sums(max_bytes=1) as memo:  # no design fits: every sum is built afresh
        TrendKernelRegression(direction_weight=100.0, random_state=0).fit(
            X, y, groups=g, goal=goal, motion=steps, drops=drops)
    assert memo.hits == 0 and memo.misses > 0 and not memo._entries


def _smallest_curvature(model, goal):
    return goal_curvature(model.gradient, goal, 1.0)


def test_min_curvature_bounds_the_bowl_at_the_goal_and_nothing_else():
    # The bundle's values leave the slope across it free: the trend is flat across.
    X, y, g, _ = _bundle()
    goal = np.zeros(2)
    trend = TrendKernelRegression(kernel_ridge=math.inf)
    flat = copy.deepcopy(trend).fit(X, y, groups=g, goal=goal)
    bound = 20.0 * _smallest_curvature(flat, goal)
    bowl = copy.deepcopy(trend).fit(X, y, groups=g, goal=goal, min_curvature=bound)
    assert _smallest_curvature(bowl, goal) == pytest.approx(bound, rel=1e-4)
    assert bowl.min_curvature_ == bound and flat.min_curvature_ is None
    assert np.allclose(bowl.gradient(goal[None]), 0.0, atol=1e-9)
    # Without a goal there is no bowl to bound.
    free = copy.deepcopy(trend).fit(X, y, groups=g, min_curvature=bound)
    plain = copy.deepcopy(trend).fit(X, y, groups=g)
    assert free.min_curvature_ is None
    np.testing.assert_array_equal(free.gradient(X), plain.gradient(X))
    with pytest.raises(ValueError, match="min_curvature"):
        copy.deepcopy(trend).fit(X, y, groups=g, goal=goal, min_curvature=-1.0)


def test_min_curvature_round_trips():
    X, y, g, _ = _bundle()
    model = TrendKernelRegression().fit(X, y, groups=g, goal=np.zeros(2), min_curvature=0.5)
    assert TrendKernelRegression.from_state(*model.get_state()).min_curvature_ == 0.5
