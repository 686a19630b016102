"""Runs of the learnt policy from the demonstrated starts, in time
(policy_align_ros.learning.reach)."""

import math
import warnings

import numpy as np

from policy_align_ros.learning import Trajectory
from policy_align_ros.learning.reach import REACH_TIME, reach_times, starts_reach

DT = 0.01


def _line(start, duration):
    """A demonstration from ``start`` straight to the origin, at rest at its end."""
    t = np.arange(0.0, duration + DT / 2, DT)
    s = np.minimum(t / (0.8 * duration), 1.0)[:, None]
    return Trajectory((1.0 - s) * np.asarray(start, float), times=t)


def test_runs_of_a_linear_flow_arrive_when_its_exponential_says():
    starts = np.array([[1.0, 0.0], [0.0, -2.0]])
    arrival = reach_times(lambda X: X, starts, np.zeros(2), np.array([10.0, 10.0]), DT, 0.1)
    # |x(t)| = |x0| exp(-t); Euler at DT arrives within a step or two of it.
    np.testing.assert_allclose(arrival, np.log([10.0, 20.0]), atol=2 * DT)
    late = reach_times(lambda X: X, starts, np.zeros(2), np.array([1.0, 10.0]), DT, 0.1)
    assert math.isinf(late[0]) and np.isfinite(late[1])


def test_a_start_on_a_plateau_is_late_and_the_others_are_not():
    demos = [_line([1.0, 0.0], 4.0), _line([0.0, 1.0], 4.0), _line([-1.0, 0.2], 4.0)]

    def gradient(X):
        # The bowl |x|^2 / 2, but a hundred times flatter within 0.3 of the first start.
        flat = np.linalg.norm(X - [1.0, 0.0], axis=1) < 0.3
        return X * np.where(flat, 0.01, 1.0)[:, None]

    out = starts_reach(demos, gradient, np.zeros(2), extent=2.0)
    assert out["n_starts_late"] == 1 and out["start_reach_ratios"][0] is None
    # The others arrive within 5 % of the extent (0.1) after ln(|x0| / 0.1) seconds.
    np.testing.assert_allclose(out["start_reach_ratios"][1:],
                               np.log([10.0, np.hypot(1.0, 0.2) / 0.1]) / 4.0, atol=0.01)
    assert max(out["start_reach_ratios"][1:]) < REACH_TIME


def test_no_common_goal_runs_nothing_and_untimed_data_count_steps():
    demos = [_line([1.0, 0.0], 4.0), _line([0.0, 1.0], 4.0)]
    assert starts_reach(demos, lambda X: X, None, 2.0) == {"start_reach_ratios": None,
                                                           "n_starts_late": 0}
    untimed = [Trajectory(d.positions) for d in demos]  # 401 samples: 400 steps each
    out = starts_reach(untimed, lambda X: 0.01 * X, np.zeros(2), 2.0)
    # Per step the flow is 100 times slower: ln(10) * 100 steps, over 400 steps.
    np.testing.assert_allclose(out["start_reach_ratios"], math.log(10.0) * 100 / 400,
                               atol=0.01)


def test_a_run_thrown_off_to_infinity_is_late_without_a_warning():
    demos = [_line([1.0, 0.0], 4.0), _line([0.0, 1.0], 4.0)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warning escapes
        out = starts_reach(demos, lambda X: -np.exp(np.abs(X)) * X, np.zeros(2), 2.0)
    assert out["n_starts_late"] == 2 and out["start_reach_ratios"] == [None, None]
