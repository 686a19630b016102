"""Tests of policy_align_ros.sim.demonstrations (ROS-free expert rollouts)."""

import numpy as np
import pytest

from policy_align_ros.kinematics import Robot, constraint_from_spec
from policy_align_ros.sim.demonstrations import (
    demo_step,
    from_constraint,
    generate_demonstrations,
    held_out_masks,
    no_constraint,
    rollout,
    sample_start_states,
    stack_ground_truth,
)
from policy_align_ros.sim.experts import QuadraticPotential, TaskSpacePotential


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
    with pytest.raises(ValueError, match=r"^center\b.*\(6,\)"):
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


def test_task_space_expert_hand_trajectories_follow_projected_policy(hands) -> None:
    from policy_align_ros.sim.demonstrations import task_space_rollout
    from policy_align_ros.sim.experts import TaskSpaceExpert

    robot, smap = hands
    q0 = robot.neutral()
    x0 = smap.states(q0)
    target = x0 + np.array([0.1, 0.05, 0.1, 0.1, -0.05, 0.05])
    expert = TaskSpaceExpert(smap, target, weight=0.5)
    normal = np.array([0.0, 0.6, 0.8])

    def plane_on_left_hand_after_1s(x, t, pi):
        return np.r_[normal, np.zeros(3)][None] if t >= 1.0 else np.zeros((0, 6))

    errors = []
    for dt in (0.02, 0.01):
        demo = task_space_rollout(q0, expert, plane_on_left_hand_after_1s, int(3.0 / dt), dt,
                                  name="a")
        X, V = demo.trajectory.positions, demo.trajectory.velocities
        # The recorded hand states are the forward kinematics of the joint states.
        np.testing.assert_allclose(X, smap.states(demo.joints.positions), atol=1e-12)
        # Ground truth: pi_x = -grad phi_x = -2 W (x - c), velocity N_x pi_x.
        np.testing.assert_allclose(demo.policy, -(X - target), atol=1e-12)
        np.testing.assert_allclose(V, np.einsum("mij,mj->mi", demo.projectors, demo.policy),
                                   atol=1e-12)
        assert np.all(demo.n_active[: int(1.0 / dt)] == 0)
        assert np.all(demo.n_active[int(1.0 / dt):] == 1)
        # The hands really move along N_x pi_x: finite differences of the hand states
        # match the expert's velocity to first order in dt.
        fd = np.diff(X, axis=0) / dt
        errors.append(np.abs(fd - V[:-1]).max())
        assert errors[-1] < 0.02 * np.abs(V).max()
        # The constrained hand does not leave its plane (A_x xdot = 0 to O(dt^2) a step).
        height = X[int(1.0 / dt):, :3] @ normal
        assert np.ptp(height) < dt**2 * np.abs(V).max()
        assert np.all(np.diff(demo.potential) <= 1e-12)
    assert 1.6 < errors[0] / errors[1] < 2.4  # first-order (Euler) discretisation


def test_task_space_expert_reaches_the_targets_and_refuses_bad_shapes(hands) -> None:
    from policy_align_ros.sim.demonstrations import task_space_rollout
    from policy_align_ros.sim.experts import TaskSpaceExpert

    robot, smap = hands
    q0 = robot.neutral()
    target = smap.states(q0) + np.array([0.05, 0.05, 0.05, 0.05, -0.05, 0.05])
    demo = task_space_rollout(q0, TaskSpaceExpert(smap, target, 1.0), None, 400, 0.01)
    final = demo.trajectory.positions[-1].reshape(2, 3) - target.reshape(2, 3)
    assert np.linalg.norm(final, axis=1).max() < 1e-3
    with pytest.raises(ValueError, match=r"^center\b.*\(6,\).*\(3,\)"):
        TaskSpaceExpert(smap, np.zeros(3))
    with pytest.raises(ValueError, match=r"^rest\b.*\(16,\).*\(3,\)"):
        TaskSpaceExpert(smap, target, rest=np.zeros(3))
    with pytest.raises(ValueError, match=r"^n_samples\b.*\b1$"):
        task_space_rollout(q0, TaskSpaceExpert(smap, target), None, 1, 0.01)


def test_task_space_expert_keeps_the_hand_motion_at_joint_speed_limits(hands) -> None:
    """Saturating joints are held at their limit; the hands still move with N_x pi_x.

    Scaling the whole command instead would record ``s N_x pi_x`` with ``s < 1``, which
    is no projection of ``pi_x`` and biases the potential estimated from the recording.
    """
    from policy_align_ros.sim.experts import TaskSpaceExpert

    robot, smap = hands
    q0 = robot.neutral()
    x0, J = smap.kinematics(q0)
    # Exact inverse: the damping near singularities is tested on its own.
    expert = TaskSpaceExpert(smap, x0 + np.array([0.3, 0.2, 0.3, 0.3, -0.2, 0.3]), 1.0,
                             threshold=0.0, damping=0.0)
    free, step = expert.command(q0)
    vmax = 0.95 * np.abs(free).max()  # feasible: a linear program finds such a qdot
    qdot, _ = expert.command(q0, max_velocity=vmax, dt=0.01)
    assert np.abs(qdot).max() <= vmax + 1e-9
    np.testing.assert_allclose(J @ qdot, step.velocity, atol=1e-9)
    assert np.abs(qdot - free).max() > 0.1  # not the free command: joints were held


