"""Tests of policy_align_ros.control.turns (continuous joints on the model's turn)."""

import numpy as np
import pytest

from policy_align_ros.control import (
    TURN,
    ControlStep,
    nearest_turn,
    turn_centres,
    wrap_continuous,
)


def test_centres_are_the_middle_of_the_support_along_continuous_joints_in_command_order():
    # Model order (b, a); the command order (a, b): permutation [1, 0]. Only a is continuous.
    support = np.array([[0.0, 2.8], [0.5, 3.6], [0.2, 3.0]])
    centres = turn_centres(support, np.array([True, False]), permutation=np.array([1, 0]))
    np.testing.assert_allclose(centres[0], 3.2)
    assert np.isnan(centres[1])
    assert turn_centres(support, np.array([False, False])) is None
    # A three-cycle (its own inverse no longer): q[permutation] is q in model order.
    model = np.array([[1.0, 10.0, 100.0], [3.0, 30.0, 300.0]])  # middles 2, 20, 200
    permutation = np.array([2, 0, 1])
    centres = turn_centres(model, np.ones(3, dtype=bool), permutation)
    np.testing.assert_allclose(centres[permutation], [2.0, 20.0, 200.0])
    np.testing.assert_allclose(centres, [20.0, 200.0, 2.0])
    with pytest.raises(ValueError, match="support"):
        turn_centres(support[:, :1], np.array([True, False]))


def test_a_measured_angle_moves_by_whole_turns_to_within_half_a_turn_of_its_centre():
    centres = np.array([3.2, np.nan])
    for q0 in (-3.1, 3.183, 3.183 + 2 * TURN, -3.1 - 5 * TURN):
        q = nearest_turn(np.array([q0, 7.0]), centres)
        assert abs(q[0] - 3.2) <= np.pi and q[1] == 7.0  # not continuous: untouched
        assert abs(np.remainder(q[0] - q0 + np.pi, TURN) - np.pi) < 1e-12  # whole turns
    q = np.array([1.0, 2.0])
    assert nearest_turn(q, None) is q


def test_the_step_commands_the_same_on_either_side_of_the_wrap():
    # A policy learnt near pi on a continuous joint 0: xdot = -(x - goal).
    goal = np.array([3.0, 0.2])
    step = ControlStep(np.array([-np.inf, -1.0]), np.array([np.inf, 1.0]), np.full(2, 2.0),
                       0.01, policy=lambda X: -(X - goal))
    step.turn_centres = np.array([3.0, np.nan])
    unwrapped = np.array([TURN - 3.1, 0.5])  # 3.183 rad: just past pi
    wrapped = np.array([-3.1, 0.5])  # the same posture as a driver reports it
    v_wrapped, _, cause = step(wrapped)
    assert cause is None
    np.testing.assert_allclose(v_wrapped, step(unwrapped)[0], atol=1e-12)
    np.testing.assert_allclose(v_wrapped, -(unwrapped - goal), atol=1e-12)
    # Without the centres the wrapped angle lies 6 rad from the data: the joint would turn
    # the long way round.
    step.turn_centres = None
    assert step(wrapped)[0][0] > 0.0 > step(unwrapped)[0][0]


def test_wrap_continuous_puts_continuous_angles_on_one_turn_and_leaves_the_rest():
    continuous = np.array([True, True, True, True, False])
    q = np.array([7.0, -4.0, np.pi, -np.pi, 7.0])
    out = wrap_continuous(q, continuous)
    np.testing.assert_allclose(out, [7.0 - 2 * np.pi, -4.0 + 2 * np.pi, -np.pi, -np.pi, 7.0])
    np.testing.assert_array_equal(q, [7.0, -4.0, np.pi, -np.pi, 7.0])  # input untouched


def test_wrap_continuous_stays_in_half_open_turn_for_random_and_rows():
    rng = np.random.default_rng(3)
    Q = rng.uniform(-50.0, 50.0, size=(200, 2))
    Q[0, 0] = -1e-17 - np.pi  # rounds onto a whole turn inside the mod
    out = wrap_continuous(Q, [True, False])
    assert np.all(out[:, 0] >= -np.pi) and np.all(out[:, 0] < np.pi)
    # Same angle: differs by whole turns.
    turns = (Q[:, 0] - out[:, 0]) / (2 * np.pi)
    np.testing.assert_allclose(turns, np.round(turns), atol=1e-9)
    np.testing.assert_array_equal(out[:, 1], Q[:, 1])
