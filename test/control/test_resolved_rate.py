"""Tests of policy_align_ros.control.resolved_rate (damped task-space inverse)."""

import numpy as np
import pytest

from policy_align_ros.control import damped_pinv, secondary_velocity, task_to_joint_velocity


def test_damping_bounds_qdot_at_a_constraint_induced_singularity() -> None:
    # J and A are each well conditioned (singular values 1), but J N_A loses rank as
    # eps -> 0: the constraint row nearly kills the task's second direction.
    J = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    xdot = np.array([0.1, 0.1])
    norms, undamped = [], []
    for eps in np.logspace(-1, -8, 8):
        A = np.array([[0.0, 1.0, eps]])
        assert np.linalg.svd(A, compute_uv=False).min() > 0.99
        qdot = task_to_joint_velocity(J, xdot, A, threshold=0.05, damping=0.05)
        assert abs((A @ qdot).item()) < 1e-12
        norms.append(np.linalg.norm(qdot))
        raw = task_to_joint_velocity(J, xdot, A, threshold=0.0, damping=0.0)
        undamped.append(np.linalg.norm(raw))
    # Bounded by |xdot| / damping; the undamped inverse grows like 1 / eps.
    assert max(norms) <= np.linalg.norm(xdot) / 0.05 + 1e-9
    assert undamped[-2] > 1e4
    # Far from the singularity (eps = 0.1 gives s_min ~ 0.1 > threshold) it is exact.
    np.testing.assert_allclose(norms[0], undamped[0])


def test_damped_pinv_is_exact_above_threshold_and_continuous() -> None:
    rng = np.random.default_rng(5)
    B = rng.standard_normal((3, 5))
    pinv, basis = damped_pinv(B, threshold=1e-3, damping=1e-3)
    np.testing.assert_allclose(pinv, np.linalg.pinv(B), atol=1e-12)
    np.testing.assert_allclose(basis @ basis.T, np.linalg.pinv(B) @ B, atol=1e-12)
    gains = [damped_pinv(np.array([[s]]), 0.05, 0.05)[0][0, 0]
             for s in (0.05 - 1e-9, 0.05 + 1e-9)]
    assert abs(gains[0] - gains[1]) < 1e-5
    assert damped_pinv(np.zeros((0, 4)))[0].shape == (4, 0)


def test_secondary_velocity_pulls_to_rest_away_from_limits_and_is_clamped() -> None:
    lower, upper = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    z = secondary_velocity(np.array([0.1, 0.0]), np.zeros(2), lower, upper, rest_gain=1.0)
    np.testing.assert_allclose(z, [-0.1, 0.0])
    near = secondary_velocity(np.array([0.95, -0.99]), np.array([0.95, -0.99]), lower,
                              upper, limit_gain=1.0, limit_margin=0.1, max_speed=10.0)
    np.testing.assert_allclose(near, [-0.75, 0.95])  # margins 0.2 rad wide
    big = secondary_velocity(np.array([0.0, 0.0]), np.array([5.0, 5.0]), lower, upper,
                             rest_gain=1.0, max_speed=0.5)
    assert np.linalg.norm(big) == pytest.approx(0.5)
