"""Tests of policy_align_ros.kinematics.control (the executor's ROS-free control law)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from policy_align_ros.kinematics import Robot, constraint_from_spec
from policy_align_ros.kinematics.control import (
    ControlStep,
    constrained_command,
    limit_locks,
    model_permutation,
    velocity_scale,
)

#: Talos arms and torso (ROS-free test: the nodes' default list is not imported).
TALOS_JOINTS = (
    ["torso_1_joint", "torso_2_joint"]
    + [f"arm_left_{i}_joint" for i in range(1, 8)]
    + [f"arm_right_{i}_joint" for i in range(1, 8)]
)
N = 6
LOWER = -np.ones(N)
UPPER = np.ones(N)
VMAX = np.full(N, 0.5)
DT = 0.01


def test_velocity_scale_respects_speed_and_position_limits():
    q = np.zeros(N)
    v = np.array([2.0, 0.1, 0, 0, 0, 0])
    assert velocity_scale(q, v, DT, LOWER, UPPER, VMAX) == pytest.approx(0.25)
    q_near = np.array([0.999, 0, 0, 0, 0, 0])
    s = velocity_scale(q_near, np.array([0.2, 0, 0, 0, 0, 0]), DT, LOWER, UPPER, VMAX)
    assert s == pytest.approx(0.5)  # 0.001 of room, 0.002 of travel in one period
    assert velocity_scale(q, np.zeros(N), DT, LOWER, UPPER, VMAX) == 1.0


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


def test_model_permutation_maps_controller_order_to_model_order():
    perm = model_permutation(["b", "c", "a"], ["a", "b", "c"])
    q = np.array([1.0, 2.0, 3.0])  # a, b, c
    np.testing.assert_array_equal(q[perm], [2.0, 3.0, 1.0])
    np.testing.assert_array_equal(model_permutation(None, ["a", "b"]), [0, 1])
    with pytest.raises(ValueError, match=r"model needs \['d'\].*not in the model \['c'\]"):
        model_permutation(["a", "b", "d"], ["a", "b", "c"])


class _Linear:
    """pi(x) = -(x - c) in model order."""

    def __init__(self, center):
        self.center = np.asarray(center, dtype=float)

    def __call__(self, X):
        return -(X - self.center)


def test_control_step_zero_commands_and_reasons():
    step = ControlStep(LOWER, UPPER, VMAX, DT)
    qdot, reason = step(np.zeros(N))
    assert reason == "no model loaded" and not np.any(qdot)
    step.policy = _Linear(np.full(N, 0.1))
    qdot, reason = step(np.full(N, np.nan))
    assert "not finite" in reason and not np.any(qdot)
    step.policy = lambda X: np.full_like(X, np.inf)
    qdot, reason = step(np.zeros(N))
    assert reason == "policy output not finite" and not np.any(qdot)


def test_control_step_applies_the_permutation():
    center_model = np.arange(N) * 0.1  # model joint k has attractor 0.1 k
    perm = np.array([5, 4, 3, 2, 1, 0])  # model joint k is controller joint perm[k]
    step = ControlStep(LOWER, UPPER, np.full(N, 10.0), DT, policy=_Linear(center_model),
                       permutation=perm)
    qdot, reason = step(np.zeros(N))
    assert reason == ""
    expected = np.empty(N)
    expected[perm] = center_model
    np.testing.assert_allclose(qdot, expected)


def test_talos_hands_on_planes_give_a_qdot_zero():
    robot = Robot.load("talos", TALOS_JOINTS)
    rng = np.random.default_rng(3)
    specs = [{"type": "plane", "frame": f, "normal": rng.normal(size=3).tolist()}
             for f in ("arm_left_7_link", "arm_right_7_link")]
    constraints = [constraint_from_spec(s, robot) for s in specs]
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 1.0), DT,
                       constraints=constraints, policy=_Linear(robot.neutral()))
    for _ in range(5):
        q = robot.random_configuration(rng, std=0.3)
        qdot, reason = step(q)
        assert reason == "" and np.linalg.norm(qdot) > 1e-3
        A = step.constraint_matrix(q)
        assert A.shape == (2, robot.nq)
        np.testing.assert_allclose(A @ qdot, 0.0, atol=1e-9)


def test_bad_control_step_arguments():
    with pytest.raises(ValueError, match="max_velocity"):
        ControlStep(LOWER, UPPER, 0.0, DT)
    with pytest.raises(ValueError, match="dt"):
        ControlStep(LOWER, UPPER, VMAX, 0.0)
