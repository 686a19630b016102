"""Tests of policy_align_ros.control.turns (continuous joints on the model's turn)."""

import numpy as np
import pytest

from policy_align_ros.control import TURN, ControlStep, nearest_turn, turn_centres


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
