"""Tests of policy_align_ros.kinematics.task_space (frame states and their Jacobian)."""

import numpy as np
import pinocchio as pin
import pytest
from task_space_rigs import ARM, ELBOW, HAND, _joint_trajectory

from policy_align_ros.kinematics import Robot, TaskSpaceMap, parse_state_spec


def test_states_of_recorded_joint_trajectories_match_forward_kinematics(robot: Robot
                                                                        ) -> None:
    smap = TaskSpaceMap(robot, [HAND, ELBOW])
    Q = _joint_trajectory(robot, 40, seed=1)
    X = smap.states(Q)
    assert X.shape == (40, 6)
    expect = np.array([np.r_[robot.frame_position(q, HAND), robot.frame_position(q, ELBOW)]
                       for q in Q])
    np.testing.assert_allclose(X, expect, atol=1e-12)
    np.testing.assert_allclose(smap(Q[3]), expect[3], atol=1e-12)
    # The positions really change along the trajectory (the check is not vacuous).
    assert np.ptp(X, axis=0).max() > 0.05


def test_states_refuse_bad_joint_rows(hand_map: TaskSpaceMap) -> None:
    Q = np.tile(hand_map.robot.neutral(), (3, 1))
    Q[2, 4] = np.nan
    with pytest.raises(ValueError, match=r"^Q\b.*\b2\b.*NaN"):
        hand_map.states(Q)
    with pytest.raises(ValueError, match=r"^Q\b.*\(m, 9\)"):
        hand_map.states(np.zeros((3, 8)))
    with pytest.raises(ValueError, match=r"^q\b.*\(9,\)"):
        hand_map.kinematics(np.zeros(4))


def test_jacobian_matches_finite_differences_with_pin_integrate(robot: Robot) -> None:
    smap = TaskSpaceMap(robot, [HAND, ELBOW])
    model, data = robot.model, robot.model.createData()
    fids = [robot.frame_id(HAND), robot.frame_id(ELBOW)]
    iq = [model.joints[model.getJointId(j)].idx_q for j in robot.joint_names]
    iv = [model.joints[model.getJointId(j)].idx_v for j in robot.joint_names]

    def positions(q_pin: np.ndarray) -> np.ndarray:
        pin.forwardKinematics(model, data, q_pin)
        pin.updateFramePlacements(model, data)
        return np.concatenate([data.oMf[f].translation for f in fids])

    h = 1e-6
    for q in _joint_trajectory(robot, 3, seed=2):
        x, J = smap.kinematics(q)
        q_pin = pin.neutral(model)
        q_pin[iq] = q
        np.testing.assert_allclose(x, positions(q_pin), atol=1e-12)
        fd = np.empty_like(J)
        for col, v in enumerate(iv):
            dv = np.zeros(model.nv)
            dv[v] = h
            plus = positions(pin.integrate(model, q_pin, dv))
            minus = positions(pin.integrate(model, q_pin, -dv))
            fd[:, col] = (plus - minus) / (2 * h)
        np.testing.assert_allclose(J, fd, atol=1e-7)
        assert np.abs(J).max() > 0.1


def test_root_frame_must_be_fixed_to_the_world(robot: Robot) -> None:
    base = TaskSpaceMap(robot, [HAND], root_frame="base_link")
    q = robot.neutral()
    np.testing.assert_allclose(base.states(q), robot.frame_position(q, HAND), atol=1e-12)
    with pytest.raises(ValueError, match=r"^root_frame\b.*'arm_left_2_link'"):
        TaskSpaceMap(robot, [HAND], root_frame="arm_left_2_link")
    with pytest.raises(ValueError, match=r"^root_frame\b.*'nowhere'"):
        TaskSpaceMap(robot, [HAND], root_frame="nowhere")
    with pytest.raises(ValueError, match=r"\bframe\b.*'hand'"):
        TaskSpaceMap(robot, ["hand"])
    with pytest.raises(ValueError, match=repr(HAND)):
        TaskSpaceMap(robot, [HAND, HAND])


def test_parse_state_spec() -> None:
    assert parse_state_spec("joints") is None
    assert parse_state_spec("frames:a,b") == ["a", "b"]
    for bad in ("hands", "frames:", "frames:a,,b", "frames:a,a"):
        with pytest.raises(ValueError, match="state:"):
            parse_state_spec(bad)


def test_learning_state_map_maps_positions_and_velocities(robot: Robot) -> None:
    from policy_align_ros.kinematics import LearningStateMap
    from policy_align_ros.learning import Trajectory

    lmap = LearningStateMap(robot, [HAND])
    assert lmap.definition().get("rest") is None
    Q = _joint_trajectory(robot, 30, seed=7)
    times = 0.01 * np.arange(30)
    V = np.gradient(Q, times, axis=0)
    out = lmap(Trajectory(Q, times, V, name="d0"))
    assert out.name == "d0"
    np.testing.assert_array_equal(out.times, times)
    np.testing.assert_allclose(out.positions, lmap.map.states(Q), atol=1e-12)
    np.testing.assert_allclose(out.velocities[5], lmap.map.jacobian(Q[5]) @ V[5])
    np.testing.assert_allclose(lmap(Q[:10]), out.positions[:10])
    rest = lmap.definition()["rest"]
    np.testing.assert_allclose([rest[j] for j in ARM], (Q[-1] + Q[9]) / 2)
    with pytest.raises(ValueError, match=r"\bd1\b.*\b3\b.*\b9\b"):
        lmap(Trajectory(np.zeros((4, 3)), name="d1"))
