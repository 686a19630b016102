"""Tests of policy_align_ros.sim.experts (known potentials and the hand-space expert)."""

import numpy as np
import pytest

from policy_align_ros.sim.experts import QuadraticPotential, TaskSpacePotential


def test_quadratic_potential_gradient_matches_finite_differences() -> None:
    rng = np.random.default_rng(0)
    W = np.diag([0.1, 0.2, 0.3])
    pot = QuadraticPotential([1.0, -1.0, 0.5], W)
    x = rng.standard_normal(3)
    eps = 1e-6
    fd = [(pot.value(x + eps * e) - pot.value(x - eps * e))[0] / (2 * eps) for e in np.eye(3)]
    np.testing.assert_allclose(pot.gradient(x)[0], fd, atol=1e-8)
    np.testing.assert_allclose(pot.policy(pot.center[None]), 0.0)
    with pytest.raises(ValueError, match=r"^weight\b"):
        QuadraticPotential([0.0, 0.0], -1.0)
    with pytest.raises(ValueError, match=r"^X\b.*\(m, 3\).*\(2, 2\)"):
        pot.value(np.zeros((2, 2)))


def test_joint_space_expert_seen_in_hand_space_is_not_the_hand_gradient(hands) -> None:
    # Why the task-space expert exists: a joint-space expert on the same hand potential
    # moves the hands with -J J^T grad phi_x, which is not -grad phi_x (nor parallel).
    robot, smap = hands
    q = robot.neutral()
    x, J = smap.kinematics(q)
    target = x + np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.1])
    joint_expert = TaskSpacePotential(robot, smap.frames, target, weight=0.5)
    seen = J @ joint_expert.policy(q[None])[0]
    wanted = -(x - target)
    cos = seen @ wanted / (np.linalg.norm(seen) * np.linalg.norm(wanted))
    assert cos < 0.99


def test_the_task_space_expert_turns_a_continuous_joint_to_its_rest_the_short_way(
        jaco_wrist) -> None:
    # The expert the demonstrator records must turn the wrist 0.45 rad across the wrap to
    # its rest, not 5.83 rad back the other way.
    from policy_align_ros.sim.experts import TaskSpaceExpert

    smap, six, rest, q = jaco_wrist
    expert = TaskSpaceExpert(smap, smap.states(q[None])[0], rest=rest)  # hand held: rest alone
    assert expert.command(q)[0][six] > 0.0  # the short way round, up to rest + a turn
    q[six] = -3.0 - 0.45  # on the rest's own turn: the same pull, toward the rest
    assert expert.command(q)[0][six] > 0.0
