"""Tests of policy_align_ros.control.locked_projection (projection with limit locks)."""

import numpy as np
from control_rigs import DT, LOWER, UPPER, VMAX, N
from hypothesis import given, settings
from hypothesis import strategies as st

from policy_align_ros.control import constrained_command, limit_locks, project_with_locks


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(0, 3))
def test_command_satisfies_constraints_speed_and_limits(seed, k):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1.0, 1.0, N)
    q[rng.random(N) < 0.3] = 1.0  # some joints sit on a limit
    pi = rng.normal(scale=2.0, size=N)
    A = rng.normal(size=(k, N))
    qdot = constrained_command(q, pi, A, LOWER, UPPER, VMAX, DT)
    np.testing.assert_allclose(A @ qdot, 0.0, atol=1e-10)
    assert np.all(np.abs(qdot) <= VMAX + 1e-12)
    q_next = q + DT * qdot
    assert np.all(q_next <= UPPER + 1e-12) and np.all(q_next >= LOWER - 1e-12)


def test_joint_on_a_limit_is_locked_but_the_others_keep_moving():
    q = np.array([1.0, 0, 0, 0, 0, 0])
    pi = np.array([0.3, 0.2, -0.1, 0, 0, 0])
    assert limit_locks(q, pi, LOWER, UPPER).tolist() == [True] + [False] * 5
    qdot = constrained_command(q, pi, np.zeros((0, N)), LOWER, UPPER, VMAX, DT)
    np.testing.assert_allclose(qdot, [0.0, 0.2, -0.1, 0, 0, 0])


def test_locked_joint_under_a_coupling_constraint_keeps_a_qdot_zero():
    # A couples joints 0 and 1; joint 0 is on its limit, so joint 1 must stop as well.
    q = np.array([1.0, 0, 0, 0, 0, 0])
    A = np.array([[1.0, -1.0, 0, 0, 0, 0]])
    pi = np.array([1.0, 1.0, 0.3, 0, 0, 0])
    qdot = constrained_command(q, pi, A, LOWER, UPPER, VMAX, DT)
    np.testing.assert_allclose(qdot, [0, 0, 0.3, 0, 0, 0], atol=1e-12)


def test_uniform_scaling_keeps_the_direction():
    pi = np.array([4.0, 1.0, 0, 0, 0, 0])
    qdot = constrained_command(np.zeros(N), pi, np.zeros((0, N)), LOWER, UPPER, VMAX, DT)
    np.testing.assert_allclose(qdot, pi / 8.0)


def test_projection_with_locks_zeroes_locked_joints_and_returns_their_projector():
    # Joint 0 on its upper limit and pushed out; A couples joints 2 and 3.
    q = np.array([1.0, 0, 0, 0, 0, 0])
    A = np.array([[0, 0, 1.0, -1.0, 0, 0]])
    pi = np.array([0.5, -0.2, 0.4, 0.0, 0.1, 0])
    v, P = project_with_locks(q, pi, A, LOWER, UPPER)
    assert v[0] == 0.0  # exactly, not up to round-off
    np.testing.assert_allclose(v, [0, -0.2, 0.2, 0.2, 0.1, 0], atol=1e-12)
    np.testing.assert_allclose(P @ v, v, atol=1e-12)  # the command lies in N'
    np.testing.assert_allclose(P[:, 0], 0.0, atol=1e-12)  # the locked joint is out of N'
