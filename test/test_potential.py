"""Potential estimates along single trajectories (policy_align_ros.learning.potential)."""

import numpy as np
import pytest

from policy_align_ros.learning import Trajectory
from policy_align_ros.learning.potential import (
    estimate_potential,
    euler_potential,
    trapezoid_potential,
)


def _quadratic_flow(dt: float, steps: int, x0=(1.5, -1.0), w=0.05):
    """Exact solution of xdot = -grad(w x^T x) = -2 w x, sampled every dt seconds."""
    t = dt * np.arange(steps)
    X = np.asarray(x0)[None, :] * np.exp(-2 * w * t)[:, None]
    return t, X, -2 * w * X, w * np.sum(X**2, axis=1)


def test_euler_rule_is_paper_eq7_in_step_units():
    X = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0]])
    np.testing.assert_allclose(euler_potential(X), [0.0, -1.0, -5.0])


def test_euler_with_times_is_in_per_second_units():
    # The same path sampled twice as fast must give the same potential drop.
    for dt in (0.1, 0.05):
        t, X, _, phi = _quadratic_flow(dt, int(round(10 / dt)) + 1)
        est = estimate_potential(Trajectory(X, times=t))
        drop_true = phi[-1] - phi[0]
        assert est[-1] == pytest.approx(drop_true, rel=0.05)


def test_trapezoid_is_more_accurate_than_euler_with_velocities():
    t, X, V, phi = _quadratic_flow(0.5, 30)
    traj = Trajectory(X, times=t, velocities=V)
    err_euler = np.abs(estimate_potential(traj, "euler") - (phi - phi[0])).max()
    err_trap = np.abs(estimate_potential(traj, "trapezoid") - (phi - phi[0])).max()
    assert err_trap < 0.1 * err_euler
    np.testing.assert_allclose(trapezoid_potential(X, V), phi - phi[0], atol=2e-3)


def test_trapezoid_without_velocities_and_unknown_rule_fail_clearly():
    traj = Trajectory(np.zeros((3, 2)), name="7")
    with pytest.raises(ValueError, match="trajectory 7: the trapezoid estimate needs"):
        estimate_potential(traj, "trapezoid")
    with pytest.raises(ValueError, match="unknown potential estimate"):
        estimate_potential(traj, "simpson")
