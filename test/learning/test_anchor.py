"""Tests of the goal anchor's decision (policy_align_ros.learning.anchor)."""

import warnings

import numpy as np
import pytest

from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.anchor import (
    CONSISTENT_SCORE,
    REFERENCE_SAMPLES,
    anchor_decision,
    bowl_curvature,
    choose_direction_weight,
    direction_candidates,
    goal_curvature,
    motion_drops,
    motion_steps,
    step_scale,
)
from policy_align_ros.learning.goal import (
    data_extent,
    demonstrated_goal,
    starts_elsewhere,
    typical_speed,
)
from policy_align_ros.learning.regressors import TrendKernelRegression
from policy_align_ros.learning.regressors.trend_kernel.model import DIRECTION_WEIGHTS
from policy_align_ros.learning.trajectory import Trajectory
from policy_align_ros.sim.recording import retime_path


class _Bowl:
    """The potential |x - c|^2 with its gradient (a fitted regressor's interface)."""

    def __init__(self, centre):
        self.centre = np.asarray(centre, dtype=float)

    def predict(self, X):
        return np.sum((X - self.centre) ** 2, axis=1)

    def gradient(self, X):
        return 2.0 * (X - self.centre)


def _demos_resting_at(goal, seed=0, k=5):
    """Demonstrations converging to ``goal`` and resting there (2-D, 50 Hz)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 6.0, 0.02)
    out = []
    for _ in range(k):
        start = goal + rng.uniform(-1.0, 1.0, 2)
        X = goal + (start - goal) * np.exp(-1.5 * t)[:, None]
        out.append(Trajectory(positions=X, times=t))
    return out


def test_a_potential_whose_minimum_is_where_the_demonstrations_end_is_kept():
    goal = np.array([0.2, -0.1])
    decision = anchor_decision(_Bowl(goal), _demos_resting_at(goal), cv_score=1e-3)
    assert decision["goal"] is not None and not decision["anchored"]
    assert decision["unanchored_error_fraction"] < 1e-3


def test_a_minimum_away_from_the_demonstrated_goal_is_anchored():
    goal = np.array([0.2, -0.1])
    decision = anchor_decision(_Bowl(goal + [0.3, 0.0]), _demos_resting_at(goal),
                               cv_score=1e-3)
    assert decision["anchored"] and np.allclose(decision["goal"], goal, atol=1e-3)


def test_a_minimum_within_the_spread_of_where_the_teacher_stopped_is_kept():
    # Ends scattered 2.5 % of the extent around the goal: a minimum 1.5 % from their mean
    # (beyond ANCHOR_TOL) is one the demonstrations cannot tell from theirs, one 15 %
    # away is not.
    goal = np.array([0.2, -0.1])
    demos = _demos_resting_at(goal)
    extent = data_extent(demos)
    offsets = 0.025 * extent * np.array([[1, 0], [0, 1], [-1, 0], [0, -1], [0.6, 0.6]])
    u = demos[0].times / demos[0].times[-1]
    blend = (u * u * (3 - 2 * u))[:, None]  # at rest at both ends
    scattered = [Trajectory(positions=d.positions + blend * o, times=d.times)
                 for d, o in zip(demos, offsets, strict=True)]
    mean = goal + offsets.mean(axis=0)
    inside = anchor_decision(_Bowl(mean + [0.015 * extent, 0.0]), scattered, cv_score=1e-3)
    assert inside["goal_spread_fraction"] > 0.015 and not inside["anchored"]
    outside = anchor_decision(_Bowl(mean + [0.15 * extent, 0.0]), scattered, cv_score=1e-3)
    assert outside["anchored"] and np.allclose(outside["goal"], mean, atol=1e-3 * extent)


def test_a_fit_exact_to_round_off_keeps_the_papers_potential():
    # Exact flows of the fitted potential that rest elsewhere rest under a constraint.
    goal = np.array([0.2, -0.1])
    decision = anchor_decision(_Bowl(goal + [0.3, 0.0]), _demos_resting_at(goal),
                               cv_score=0.1 * CONSISTENT_SCORE)
    assert decision["consistent"] and not decision["anchored"]


def test_no_anchor_for_a_regressor_that_cannot_take_a_goal():
    goal = np.array([0.2, -0.1])
    decision = anchor_decision(_Bowl(goal + [0.3, 0.0]), _demos_resting_at(goal),
                               can_anchor=False)
    assert not decision["anchored"]


def test_motion_steps_are_central_differences():
    X = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 1.0]])
    np.testing.assert_allclose(motion_steps(X), [[1.0, 0.0], [1.5, 0.5], [2.0, 1.0]])
    assert motion_steps(X[:1]).shape == (1, 2)


def test_motion_drops_are_the_potential_over_the_same_steps():
    # The change of a potential over each sample's step: for values linear in the
    # positions, the slope times the step.
    X = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 1.0], [5.0, 2.0]])
    values = X @ np.array([-2.0, 0.5])
    np.testing.assert_allclose(motion_drops(values), motion_steps(X) @ np.array([-2.0, 0.5]))
    np.testing.assert_array_equal(motion_drops(values[:1]), [0.0])


class _Tilted(_Bowl):
    """A bowl at the goal plus a steep downhill slope along +x: every descent leaves."""

    def predict(self, X):
        return super().predict(X) - 50.0 * X[:, 0]

    def gradient(self, X):
        return super().gradient(X) - [50.0, 0.0]


class _Saddle(_Bowl):
    """Stationary at the centre, a saddle there (curvature -2 along y), with minima at
    ``y = +-0.05`` beside it: descents from the demonstrations' starts stop within a few
    percent of the extent of the centre, and count as at the goal."""

    def predict(self, X):
        d = X - self.centre
        return d[:, 0] ** 2 - d[:, 1] ** 2 + 200.0 * d[:, 1] ** 4

    def gradient(self, X):
        d = X - self.centre
        return np.stack([2.0 * d[:, 0], -2.0 * d[:, 1] + 800.0 * d[:, 1] ** 3], axis=1)


def test_bowl_curvature_takes_an_offset_to_the_goal_tolerance_in_the_reach_time():
    t = np.linspace(0.0, 1.0, 11)
    trajs = [Trajectory(np.zeros((11, 2)), times=d * t) for d in (2.0, 3.0, 4.0)]
    bound = bowl_curvature(trajs)
    # The flow xdot = -bound x over 3 times the median duration leaves 5 % of an offset.
    assert np.exp(-bound * 3.0 * 3.0) == pytest.approx(0.05)
    # Untimed demonstrations count one step per sample.
    assert bowl_curvature([Trajectory(np.zeros((11, 2)))] * 2) == pytest.approx(
        np.log(20.0) / 30.0)


def test_step_scale_measures_steps_as_at_the_reference_sample_count():
    def demos(n):
        return [Trajectory(np.zeros((n, 2)), times=np.linspace(0.0, d, n)) for d in (2.0, 5.0)]

    assert step_scale(demos(REFERENCE_SAMPLES)) == 1.0  # the weights' own rate, exactly
    # Five times the rate: steps five times shorter, so five times the factor.
    assert step_scale(demos(5 * (REFERENCE_SAMPLES - 1) + 1)) == pytest.approx(5.0)
    # The median over demonstrations: two at the reference count outvote one at 3 times it.
    mixed = demos(REFERENCE_SAMPLES) + demos(3 * (REFERENCE_SAMPLES - 1) + 1)[:1]
    assert step_scale(mixed) == 1.0


def _human_paths(hz: float, seed: int = 0, k: int = 6) -> list[Trajectory]:
    """Flows of ``x' diag(1, 4) x / 2`` to the origin on a teacher's minimum-jerk timing
    (1.5-3 s, at rest before and after), recorded at ``hz``: the same paths whatever the
    rate."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 4.0, 0.002)
    out = []
    for _ in range(k):
        x0 = rng.uniform(-1.0, 1.0, 2)
        path = np.exp(-np.outer(t, [1.0, 4.0])) * (x0 / np.linalg.norm(x0))
        X, _, times, _ = retime_path(path, rng.uniform(1.5, 3.0), 1.0 / hz,
                                     rest_before=0.2, rest_after=0.3)
        out.append(Trajectory(X, times))
    return out


def test_an_anchored_fit_learns_the_same_policy_at_any_recording_rate():
    grid = np.stack(np.meshgrid(np.linspace(-0.8, 0.8, 8), np.linspace(-0.8, 0.8, 8)),
                    axis=-1).reshape(-1, 2)
    policies = []
    for hz in (40.0, 200.0):
        demos = _human_paths(hz)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = PolicyAlign(random_state=0).fit(demos)
        assert model.fit_summary_["anchor"]["anchored"]  # the direction rows are in play
        assert model.fit_summary_["anchor"]["step_scale"] == step_scale(demos)
        policies.append(model.policy(grid))
    # Steps five times shorter at 200 Hz: without step_scale the policies differ by 0.36.
    diff = np.linalg.norm(policies[1] - policies[0]) / np.linalg.norm(policies[0])
    assert diff < 0.1


def test_goal_curvature_is_the_smallest_eigenvalue_of_the_hessian():
    A = np.array([[3.0, 1.0], [1.0, 2.0]])  # potential x' A x / 2 about c

    def gradient(X):
        return (X - [0.5, 0.2]) @ A

    curvature = goal_curvature(gradient, np.array([0.5, 0.2]), extent=2.0)
    assert abs(curvature - np.linalg.eigvalsh(A)[0]) < 1e-8
    assert abs(goal_curvature(_Saddle([0.0, 0.0]).gradient, np.zeros(2), 2.0) + 2.0) < 1e-4


def test_a_weight_whose_goal_is_a_saddle_is_passed_over():
    goal = np.array([0.2, -0.1])
    demos = _demos_resting_at(goal)
    saddle = _Saddle(goal)
    # The saddle's starts count as reaching the goal: only the curvature rejects it.
    assert starts_elsewhere(demos, saddle.predict, saddle.gradient, data_extent(demos),
                            typical_speed(demos))["n_starts_elsewhere"] == 0
    largest, second = sorted(DIRECTION_WEIGHTS, reverse=True)[:2]
    models = {w: saddle if w == largest else _Bowl(goal) for w in DIRECTION_WEIGHTS}

    def fit(candidate):
        return models[candidate.direction_weight]

    out = choose_direction_weight(fit, direction_candidates(TrendKernelRegression()), demos,
                                  demonstrated_goal(demos))
    assert out["direction_weight"] == second and out["goal_is_minimum"]
    first, kept = out["direction_weights_tried"]
    assert first["goal_curvature"] < 0.0 < kept["goal_curvature"]


def test_a_kept_fit_whose_goal_is_not_a_minimum_is_flagged():
    goal = np.array([0.2, -0.1])
    with pytest.warns(UserWarning):
        demos = _demos_resting_at(goal)
        out = choose_direction_weight(lambda candidate: _Saddle(goal),
                                      direction_candidates(TrendKernelRegression()),
                                      demos, demonstrated_goal(demos))
    assert out["direction_weight"] == min(DIRECTION_WEIGHTS) and not out["goal_is_minimum"]


def test_auto_direction_weight_tries_every_weight_largest_first():
    weights = [c.direction_weight for c in direction_candidates(TrendKernelRegression())]
    assert weights == sorted(DIRECTION_WEIGHTS, reverse=True)
    fixed = TrendKernelRegression(direction_weight=3.0)
    assert direction_candidates(fixed) == [fixed]


def test_the_largest_weight_whose_starts_all_reach_the_goal_is_kept():
    goal = np.array([0.2, -0.1])
    demos = _demos_resting_at(goal)
    largest, second = sorted(DIRECTION_WEIGHTS, reverse=True)[:2]
    models = {w: _Tilted(goal) if w == largest else _Bowl(goal) for w in DIRECTION_WEIGHTS}
    fitted = []

    def fit(candidate):
        fitted.append(candidate.direction_weight)
        return models[candidate.direction_weight]

    out = choose_direction_weight(fit, direction_candidates(TrendKernelRegression()), demos,
                                  demonstrated_goal(demos))
    assert fitted == [largest, second] and out["direction_weight"] == second
    first, kept = out["direction_weights_tried"]
    assert first["n_starts_elsewhere"] == len(demos) and kept["n_starts_elsewhere"] == 0
    # The kept fit's check, handed to the goal report instead of being run again.
    assert out["starts"] == starts_elsewhere(demos, models[second].predict,
                                             models[second].gradient, data_extent(demos),
                                             typical_speed(demos))


def test_when_no_weight_takes_the_starts_to_the_goal_the_last_is_fitted_last():
    goal = np.array([0.2, -0.1])
    fitted = []

    def fit(candidate):
        fitted.append(candidate.direction_weight)
        return _Tilted(goal)

    demos = _demos_resting_at(goal)
    out = choose_direction_weight(fit, direction_candidates(TrendKernelRegression()), demos,
                                  demonstrated_goal(demos))
    assert fitted == sorted(DIRECTION_WEIGHTS, reverse=True)
    assert out["direction_weight"] == min(DIRECTION_WEIGHTS)
    assert out["starts"] is None  # the last fit is kept unchecked
