"""Tests of policy_align_ros.control.limits (speed and position limits, the ramp)."""

import numpy as np
import pytest
from control_rigs import DT, LOWER, STEP_TOL, UPPER, VMAX, N
from hypothesis import given, settings
from hypothesis import strategies as st

from policy_align_ros.control import (
    goal_in_margin,
    joint_velocity_bounds,
    position_outside_limits,
    ramp_toward,
    velocity_scale,
)


def constrained_projector(A):
    from policy_align_ros.kinematics import nullspace_projector

    return nullspace_projector(A, N)


def test_velocity_scale_respects_speed_and_position_limits():
    q = np.zeros(N)
    v = np.array([2.0, 0.1, 0, 0, 0, 0])
    assert velocity_scale(q, v, DT, LOWER, UPPER, VMAX) == pytest.approx(0.25)
    q_near = np.array([0.999, 0, 0, 0, 0, 0])
    s = velocity_scale(q_near, np.array([0.2, 0, 0, 0, 0, 0]), DT, LOWER, UPPER, VMAX)
    assert s == pytest.approx(0.5)  # 0.001 of room, 0.002 of travel in one period
    assert velocity_scale(q, np.zeros(N), DT, LOWER, UPPER, VMAX) == 1.0


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(0, 3),
       max_delta=st.floats(1e-4, 1.0))
def test_ramp_toward_bounds_every_joint_and_keeps_the_constraints(seed, k, max_delta):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(k, N))
    P = constrained_projector(A)
    previous = P @ rng.normal(size=N)
    target = P @ rng.normal(scale=3.0, size=N)
    command, alpha, forced = ramp_toward(previous, target, P, max_delta)
    assert 0.0 <= alpha <= 1.0
    assert np.max(np.abs(command - previous)) <= max_delta + STEP_TOL
    np.testing.assert_allclose(A @ command, 0.0, atol=1e-10)
    np.testing.assert_allclose(forced, 0.0, atol=1e-12)
    if alpha == 1.0:
        np.testing.assert_array_equal(command, target)
    else:  # as far as allowed: some joint uses its whole budget
        assert np.max(np.abs(command - previous)) == pytest.approx(max_delta)


def test_ramp_toward_blends_a_new_constraint_in_within_the_acceleration_limit():
    previous = np.array([0.4, 0.4, 0.0, 0.1, 0.0, 0.0])
    A = np.array([[1.0, 0, 0, 0, 0, 0]])  # joint 0 newly locked
    P = constrained_projector(A)
    target = np.array([0.0, 0.5, 0.3, 0.1, 0.0, 0.0])
    command, alpha, forced = ramp_toward(previous, target, P, 0.02)
    np.testing.assert_allclose(forced, [-0.4, 0, 0, 0, 0, 0], atol=1e-15)
    # The acceleration limit wins: joint 0 slows by 0.02, nothing else moves yet.
    np.testing.assert_allclose(command, [0.38, 0.4, 0.0, 0.1, 0.0, 0.0], atol=1e-15)
    assert alpha == 0.0
    commands = [previous, command]
    for _ in range(60):
        commands.append(ramp_toward(commands[-1], target, P, 0.02)[0])
    steps = np.abs(np.diff(commands, axis=0))
    assert steps.max() <= 0.02 + STEP_TOL
    assert commands[20][0] == pytest.approx(0.0, abs=1e-12)  # blended in after 0.4 / 0.02
    np.testing.assert_allclose(commands[-1], target, atol=1e-12)


def test_velocity_scale_brakes_for_limits_when_given_an_acceleration():
    q = np.array([0.9, 0, 0, 0, 0, 0])  # 0.1 rad from the upper limit
    v = np.array([0.5, 0, 0, 0, 0, 0])
    assert velocity_scale(q, v, DT, LOWER, UPPER, VMAX) == 1.0
    s = velocity_scale(q, v, DT, LOWER, UPPER, VMAX, max_acceleration=2.0)
    assert s * 0.5 == pytest.approx(np.sqrt(2.0 * 0.1))


def test_ramp_toward_applies_a_correction_outside_the_null_space_at_once():
    rng = np.random.default_rng(11)
    A = rng.normal(size=(2, N))
    P = constrained_projector(A)
    correction = A.T @ rng.normal(size=2)  # in the row space of A
    correction *= 0.005 / np.abs(correction).max()  # within one step's change
    target = P @ rng.normal(size=N) + correction
    previous = P @ rng.normal(size=N)
    command, alpha, _ = ramp_toward(previous, target, P, 0.01)
    assert alpha < 1.0
    np.testing.assert_allclose(A @ command, A @ target, atol=1e-12)
    # A correction larger than one step's change is blended in, like a new constraint.
    command, alpha, forced = ramp_toward(previous, target + 100 * correction, P, 0.01)
    assert alpha == 0.0 and np.abs(command - previous).max() == pytest.approx(0.01)
    np.testing.assert_allclose(command - previous, forced * 0.01 / np.abs(forced).max())


def test_joint_velocity_bounds_from_position_and_speed_limits() -> None:
    lower, upper = np.array([-1.0, -1.0, -np.inf]), np.array([1.0, 1.0, np.inf])
    q = np.array([1.0, 0.99, 5.0])
    lo, hi = joint_velocity_bounds(q, lower, upper)
    np.testing.assert_array_equal(hi, [0.0, np.inf, np.inf])
    np.testing.assert_array_equal(lo, [-np.inf] * 3)
    lo, hi = joint_velocity_bounds(q, lower, upper, max_velocity=2.0, dt=0.01)
    np.testing.assert_allclose(hi, [0.0, 1.0, 2.0])  # 0.01 rad of room over 10 ms
    np.testing.assert_allclose(lo, [-2.0, -2.0, -2.0])


def test_positions_outside_the_limits_beyond_the_margin_are_named_with_their_value():
    names = [f"j{i}" for i in range(N)]
    lower, upper = np.full(N, -1.57), np.full(N, 1.57)
    q = np.zeros(N)
    assert position_outside_limits(q, lower, upper, 0.1, names) == ""
    q[2] = 1.65  # 0.08 beyond the limit: within the margin
    q[4] = -1.6
    assert position_outside_limits(q, lower, upper, 0.1, names) == ""
    q[1] = 3.0
    text = position_outside_limits(q, lower, upper, 0.1, names)
    assert "j1" in text and f"{q[1]:g}" in text and "1.57" in text and "j2" not in text
    q[3] = -1e6  # the furthest out is named first, every joint outside is listed
    text = position_outside_limits(q, lower, upper, 0.1, names)
    assert f"{q[3]:g}" in text and "j1" in text and text.index("j3") < text.index("j1")
    assert not any(f"j{i}" in text for i in (0, 2, 4, 5))
    # A continuous joint (infinite limits) is never implausible.
    q = np.full(N, 1e6)
    assert position_outside_limits(q, np.full(N, -np.inf), np.full(N, np.inf), 0.1,
                                   names) == ""


def test_a_goal_within_the_braking_margin_of_a_limit_names_those_joints():
    # The control law brakes joints to rest joint_limit_margin inside their limits: a goal
    # there (an arm folded against its stop) is one no run reaches.
    names = [f"j{i}" for i in range(N)]
    lower, upper = np.full(N, -1.57), np.full(N, 1.57)
    lower[1] = 0.0
    goal = np.zeros(N)
    text = goal_in_margin(goal, lower, upper, 0.05, names)
    assert "j1" in text and not any(f"j{i}" in text for i in range(N) if i != 1)
    goal[1] = 0.06
    assert goal_in_margin(goal, lower, upper, 0.05, names) == ""
    goal[3] = 2.0  # beyond a limit: flagged too
    assert "j3" in goal_in_margin(goal, lower, upper, 0.05, names)
    # A continuous joint (infinite limits) never is.
    assert goal_in_margin(np.full(N, 1e6), np.full(N, -np.inf), np.full(N, np.inf), 0.05,
                          names) == ""
