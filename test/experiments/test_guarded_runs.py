"""Closed-loop runs under the executor's extrapolation guard: reached, held, flagged or
silent."""

import numpy as np
import pytest

from policy_align_ros.control.guard import ExtrapolationGuard
from policy_align_ros.control.guard_hold import HOLD_SCALE
from policy_align_ros.experiments.guarded_runs import (
    REACH_TOLERANCE,
    guarded_rollout,
    run_outcome,
)

SPACING = 0.1  # the data: one state at the origin, spacings of 0.1 rad


def _distance(q):
    r = float(np.linalg.norm(q))
    return r / SPACING, (None if r == 0.0 else q / (r * SPACING))


def _towards(c):
    c = np.asarray(c, dtype=float)
    return lambda X: -(X - c)


def _run(centre, x0, project=None, steps=3000):
    guard = ExtrapolationGuard(_distance)  # defaults: edge 0.5 rad from the data here
    return guarded_rollout(_towards(centre), guard, np.asarray(x0, float), 0.01, steps,
                           project)


def test_a_policy_whose_goal_lies_in_the_data_reaches_it_unscaled():
    end, scale = _run([0.05, 0.0], [0.3, 0.2])
    assert scale == 1.0
    assert run_outcome(end, scale, np.array([0.3, 0.2]), np.array([0.05, 0.0])) == "reached"


def test_a_policy_leading_far_out_is_held_at_the_data_edge():
    x0 = np.array([0.1, 0.0])
    end, scale = _run([3.0, 0.0], x0)
    assert scale <= HOLD_SCALE
    # It went as far as the guard lets it: max_extrapolation_rad, within a step.
    assert np.linalg.norm(end) == pytest.approx(0.5, abs=0.01)
    assert np.linalg.norm(end) <= 0.5 + 1e-9
    assert run_outcome(end, scale, x0, np.array([3.0, 0.0])) == "held"


def test_a_run_that_settles_off_the_goal_inside_the_data_is_a_silent_miss():
    x0, expert_end = np.array([0.3, 0.0]), np.array([-0.2, 0.0])
    end, scale = _run([0.0, 0.1], x0)  # the learnt minimum, 0.22 from the expert's end
    assert scale == 1.0
    assert run_outcome(end, scale, x0, expert_end) == "silent"


def test_the_constraint_projection_is_applied_to_every_command():
    hold_y = lambda x, i, v: np.array([v[0], 0.0])  # noqa: E731
    end, _ = _run([0.0, 0.3], [0.2, 0.1], project=hold_y)
    assert end[1] == pytest.approx(0.1)
    assert end[0] == pytest.approx(0.0, abs=1e-6)


def test_the_guard_sees_the_projected_command_not_the_policy():
    # The data: the segment from (0, 0) to (0, 1). The policy leads away from it along x;
    # the constraint lets the robot move along y only, parallel to the data. Guarded before
    # the projection it would be held at the start; after it, it moves on unscaled.
    def distance(q):
        support = np.array([[0.0, 0.0], [0.0, 1.0]])
        near = support[np.argmin(np.linalg.norm(support - q, axis=1))]
        gap = q - near if abs(q[1] - 0.5) > 0.5 else np.array([q[0], 0.0])
        r = float(np.linalg.norm(gap))
        return r / SPACING, (None if r == 0.0 else gap / (r * SPACING))

    only_y = lambda x, i, v: np.array([0.0, v[1]])  # noqa: E731
    policy = lambda X: np.array([[3.0, 1.0]])  # noqa: E731
    x0 = np.array([0.6, 0.0])  # beyond the edge (0.5 rad) already
    end, scale = guarded_rollout(policy, ExtrapolationGuard(distance), x0, 0.01, 50, only_y)
    assert scale == 1.0
    assert end == pytest.approx([0.6, 0.5])


def test_reached_is_judged_relative_to_the_start_distance():
    goal, x0 = np.zeros(2), np.array([1.0, 0.0])
    just_in = np.array([REACH_TOLERANCE * 0.99, 0.0])
    just_out = np.array([REACH_TOLERANCE * 1.01, 0.0])
    assert run_outcome(just_in, 0.0, x0, goal) == "reached"
    assert run_outcome(just_out, 0.5, x0, goal) == "silent"
    assert run_outcome(just_out, HOLD_SCALE, x0, goal) == "held"


def test_a_flag_names_a_miss_the_guard_does_not_hold_and_nothing_else():
    goal, x0 = np.zeros(2), np.array([1.0, 0.0])
    off, there = np.array([0.3, 0.0]), np.array([0.001, 0.0])
    assert run_outcome(off, 1.0, x0, goal, flagged=True) == "flagged"
    assert run_outcome(off, 1.0, x0, goal, flagged=False) == "silent"
    # A hold is reported by the guard already; a run that arrives is not a miss.
    assert run_outcome(off, HOLD_SCALE, x0, goal, flagged=True) == "held"
    assert run_outcome(there, 1.0, x0, goal, flagged=True) == "reached"
