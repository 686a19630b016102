"""Tests of policy_align_ros.experiments.demonstrators (ROS-free expert rollouts)."""

import numpy as np
import pytest

from policy_align_ros.experiments.demonstrators import (
    QuadraticPotential,
    TaskSpacePotential,
    demo_step,
    from_constraint,
    generate_demonstrations,
    held_out_masks,
    no_constraint,
    rollout,
    sample_start_states,
    stack_ground_truth,
)
from policy_align_ros.kinematics import Robot, constraint_from_spec


def test_quadratic_potential_gradient_matches_finite_differences() -> None:
    rng = np.random.default_rng(0)
    W = np.diag([0.1, 0.2, 0.3])
    pot = QuadraticPotential([1.0, -1.0, 0.5], W)
    x = rng.standard_normal(3)
    eps = 1e-6
    fd = [(pot.value(x + eps * e) - pot.value(x - eps * e))[0] / (2 * eps) for e in np.eye(3)]
    np.testing.assert_allclose(pot.gradient(x)[0], fd, atol=1e-8)
    np.testing.assert_allclose(pot.policy(pot.center[None]), 0.0)
    with pytest.raises(ValueError, match="weight: must be positive definite"):
        QuadraticPotential([0.0, 0.0], -1.0)
    with pytest.raises(ValueError, match=r"X: must have shape \(m, 3\)"):
        pot.value(np.zeros((2, 2)))


def test_unconstrained_rollout_is_euler_of_the_policy() -> None:
    pot = QuadraticPotential([0.0, 0.0], 0.05)
    demo = rollout(np.array([1.0, 2.0]), pot, no_constraint(2), 30, dt=1.0, name="a")
    X = demo.trajectory.positions
    # x_{i+1} = x_i - 0.1 x_i  (paper's toy dynamics with dt = 1)
    np.testing.assert_allclose(X[1:], 0.9 * X[:-1])
    np.testing.assert_allclose(demo.trajectory.velocities, -0.1 * X)
    np.testing.assert_allclose(demo.trajectory.times, np.arange(30.0))
    np.testing.assert_allclose(demo.potential, 0.05 * np.sum(X**2, axis=1))
    assert np.all(demo.n_active == 0)


def test_constrained_step_moves_in_nullspace_only() -> None:
    pot = QuadraticPotential([0.0, 0.0, 0.0], 0.5)
    A = np.array([[0.0, 0.0, 1.0]])
    step = demo_step(np.array([1.0, 1.0, 1.0]), 0.0, pot, lambda x, t, pi: A, dt=0.1)
    np.testing.assert_allclose(step.velocity, [-1.0, -1.0, 0.0])
    np.testing.assert_allclose(step.x_next, [0.9, 0.9, 1.0])
    np.testing.assert_allclose(step.policy, [-1.0, -1.0, -1.0])


def test_joint_space_demo_keeps_hand_on_plane() -> None:
    robot = Robot.load("ur5")
    c = constraint_from_spec({"type": "plane", "frame": "tool0", "normal": [0, 0, 1]}, robot)
    pot = QuadraticPotential(robot.neutral(), 0.5)
    x0 = robot.neutral() + 0.2
    demo = rollout(x0, pot, from_constraint(c), 40, dt=0.02)
    z = [robot.frame_position(q, "tool0")[2] for q in demo.trajectory.positions]
    moved = np.linalg.norm(demo.trajectory.positions[-1] - x0)
    assert moved > 0.05
    assert np.ptp(z) < 1e-3 * moved  # first-order constraint: drift is second order
    for N, v in zip(demo.projectors, demo.trajectory.velocities, strict=True):
        np.testing.assert_allclose(N @ v, v, atol=1e-12)


def test_task_space_potential_reaches_target() -> None:
    robot = Robot.load("ur5")
    target = robot.frame_position(robot.neutral() + 0.3, "tool0")
    pot = TaskSpacePotential(robot, ["tool0"], target, 1.0)
    demo = rollout(robot.neutral(), pot, no_constraint(robot.nq), 200, dt=0.05)
    final = robot.frame_position(demo.trajectory.positions[-1], "tool0")
    assert np.linalg.norm(final - target) < 0.1 * np.linalg.norm(
        robot.frame_position(robot.neutral(), "tool0") - target)
    assert np.all(np.diff(demo.potential) <= 1e-12)
    with pytest.raises(ValueError, match=r"center: must have shape \(6,\)"):
        TaskSpacePotential(robot, ["tool0", "wrist_1_link"], target)


def test_start_states_and_masks_are_seeded() -> None:
    lo, hi = -np.ones(4), np.ones(4)
    a = sample_start_states(np.random.default_rng(7), np.zeros(4), 500, 0.1, lo, hi)
    b = sample_start_states(np.random.default_rng(7), np.zeros(4), 500, 0.1, lo, hi)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (500, 4)
    assert abs(np.var(a) - 0.1) < 0.02
    wide = sample_start_states(np.random.default_rng(7), np.zeros(4), 100, 9.0, lo, hi)
    assert np.all(np.abs(wide) <= 1.0) and np.any(np.abs(wide) == 1.0)

    pot = QuadraticPotential(np.zeros(2))
    rng = np.random.default_rng(8)
    demos = generate_demonstrations(
        pot, rng.standard_normal((5, 2)), lambda k, r: no_constraint(2), 20, 1.0, rng)
    train, test = held_out_masks(demos, 0.2, rng)
    assert all(t.sum() == 4 and not np.any(t & tr) for t, tr in zip(test, train, strict=True))
    gt = stack_ground_truth(demos, test, keep=[0, 2])
    assert gt["X"].shape == (8, 2) and gt["N"].shape == (8, 2, 2)
    np.testing.assert_allclose(gt["pi"], pot.policy(gt["X"]))
    np.testing.assert_array_equal(gt["demo"], [0] * 4 + [2] * 4)
