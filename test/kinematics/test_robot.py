"""Tests of policy_align_ros.kinematics.robot (Pinocchio loading, subsets, Jacobians)."""

import numpy as np
import pinocchio as pin
import pytest

from policy_align_ros.kinematics import ROBOTS, Robot
from policy_align_ros.kinematics.robot import robots_dir

TALOS_ARM = [f"arm_left_{i}_joint" for i in range(1, 8)] + ["torso_1_joint", "torso_2_joint"]


@pytest.fixture(scope="module")
def talos_arm() -> Robot:
    return Robot.load("talos", joints=TALOS_ARM)


@pytest.mark.parametrize(
    ("name", "nq"), [("talos", 32), ("panda", 9), ("ur5", 6), ("human", 36)]
)
def test_load_by_name(name: str, nq: int) -> None:
    robot = Robot.load(name)
    assert robot.nq == nq == len(robot.joint_names)
    assert robot.lower.shape == robot.upper.shape == robot.velocity_limit.shape == (nq,)
    q0 = robot.neutral()
    assert np.all(q0 >= robot.lower - 1e-12) and np.all(q0 <= robot.upper + 1e-12)


def test_load_by_urdf_path() -> None:
    path = robots_dir() / "ur_description" / "urdf" / "ur5_robot.urdf"
    robot = Robot.load(str(path), joints=["elbow_joint", "shoulder_pan_joint"])
    assert robot.joint_names == ["elbow_joint", "shoulder_pan_joint"]
    assert robot.nq == 2


def test_subset_keeps_requested_order_and_reference(talos_arm: Robot) -> None:
    full = Robot.load("talos")
    assert talos_arm.joint_names == TALOS_ARM
    # Locked joints sit at half_sitting, so the subset's FK equals the full robot's FK.
    q_full = full.neutral()
    q_sub = np.array([q_full[full.joint_names.index(j)] for j in TALOS_ARM])
    np.testing.assert_allclose(talos_arm.neutral(), q_sub)
    rng = np.random.default_rng(0)
    q_sub = q_sub + 0.2 * rng.standard_normal(len(TALOS_ARM))
    for j, v in zip(TALOS_ARM, q_sub, strict=True):
        q_full[full.joint_names.index(j)] = v
    for frame in ("gripper_left_base_link", "arm_left_4_link"):
        np.testing.assert_allclose(
            talos_arm.frame_position(q_sub, frame), full.frame_position(q_full, frame),
            atol=1e-12,
        )
    # Half-sitting (SRDF) is not the zero posture: the knee is bent.
    knee = full.joint_names.index("leg_left_4_joint")
    assert q_full[knee] > 0.5


def _fd_jacobian(robot: Robot, q: np.ndarray, frame: str, eps: float = 1e-6) -> np.ndarray:
    jac = np.empty((3, robot.nq))
    for i in range(robot.nq):
        dq = np.zeros(robot.nq)
        dq[i] = eps
        # pin.integrate works on the reduced model's (tree-ordered) configuration.
        qp = robot._pin_q(q)
        plus = pin.integrate(robot.model, qp, robot._pin_q(dq))
        minus = pin.integrate(robot.model, qp, -robot._pin_q(dq))
        p_plus = _pos_tree(robot, plus, frame)
        p_minus = _pos_tree(robot, minus, frame)
        jac[:, i] = (p_plus - p_minus) / (2 * eps)
    return jac


def _pos_tree(robot: Robot, q_tree: np.ndarray, frame: str) -> np.ndarray:
    pin.forwardKinematics(robot.model, robot.data, q_tree)
    return pin.updateFramePlacement(robot.model, robot.data, robot.frame_id(frame)).translation


@pytest.mark.parametrize(
    ("name", "joints", "frame"),
    [
        ("talos", TALOS_ARM, "gripper_left_base_link"),
        ("panda", None, "panda_hand"),
        ("ur5", None, "tool0"),
        ("human", None, "right_hand"),
    ],
)
def test_jacobian_matches_finite_differences(name, joints, frame) -> None:
    robot = Robot.load(name, joints=joints)
    rng = np.random.default_rng(1)
    for _ in range(3):
        q = robot.random_configuration(rng, std=0.3)
        jac = robot.frame_jacobian(q, frame)
        assert jac.shape == (3, robot.nq)
        np.testing.assert_allclose(jac, _fd_jacobian(robot, q, frame), atol=1e-6)
        pos, jacs = robot.frames_kinematics(q, [frame, frame])
        np.testing.assert_allclose(pos[1], robot.frame_position(q, frame), atol=1e-12)
        np.testing.assert_allclose(jacs[0], jac, atol=1e-12)


def test_wrong_names_list_closest() -> None:
    with pytest.raises(ValueError, match="talos"):
        Robot.load("tallos")
    with pytest.raises(ValueError, match="arm_left_7_joint"):
        Robot.load("talos", joints=["arm_left_77_joint"])
    robot = Robot.load("ur5")
    with pytest.raises(ValueError, match="tool0"):
        robot.frame_position(robot.neutral(), "tool")
    with pytest.raises(ValueError, match="'elbow_joint'"):
        Robot.load("ur5", joints=["elbow_joint", "elbow_joint"])
    with pytest.raises(ValueError, match="/nonexistent/robot.urdf"):
        Robot.load("/nonexistent/robot.urdf")
    with pytest.raises(ValueError, match=r"^q\b.*\(6,\).*\(5,\)"):
        robot.frame_position(np.zeros(5), "tool0")


def test_reference_dict_sets_locked_posture() -> None:
    robot = Robot.load("ur5", joints=["shoulder_pan_joint"], reference={"elbow_joint": 1.0})
    moved = robot.frame_position(np.zeros(1), "tool0")
    straight = Robot.load("ur5", joints=["shoulder_pan_joint"]).frame_position(
        np.zeros(1), "tool0")
    assert np.linalg.norm(moved - straight) > 0.1
    with pytest.raises(ValueError, match=r"^reference\b.*'elbow'"):
        Robot.load("ur5", reference={"elbow": 1.0})


def test_random_configuration_within_limits(talos_arm: Robot) -> None:
    rng = np.random.default_rng(2)
    qs = np.array([talos_arm.random_configuration(rng, std=2.0) for _ in range(50)])
    assert np.all(qs >= talos_arm.lower) and np.all(qs <= talos_arm.upper)
    assert np.any(qs == talos_arm.lower) or np.any(qs == talos_arm.upper)


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_every_known_name_resolves(name: str) -> None:
    robot = Robot.load(name)
    assert robot.urdf.is_file()
    assert robot.nq == len(robot.joint_names) == robot.neutral().shape[0] > 0


def test_locked_posture_and_urdf_hash(talos_arm: Robot) -> None:
    import hashlib

    full = Robot.load("talos")
    assert full.locked_posture == {}
    assert set(talos_arm.locked_posture) == set(full.joint_names) - set(TALOS_ARM)
    q_ref = dict(zip(full.joint_names, full.neutral(), strict=True))
    for joint, values in talos_arm.locked_posture.items():
        assert values == [pytest.approx(q_ref[joint])]
    moved = Robot.load("talos", joints=TALOS_ARM, reference={"arm_right_4_joint": -1.0})
    assert moved.locked_posture["arm_right_4_joint"] == [-1.0]
    expect = hashlib.sha256(talos_arm.urdf.read_bytes()).hexdigest()
    assert talos_arm.urdf_sha256() == expect != Robot.load("panda").urdf_sha256()


def test_a_continuous_joint_is_one_angle_with_no_limits() -> None:
    # Kinova's Jaco: joints 1, 4 and 6 are URDF "continuous", which Pinocchio configures
    # by (cos, sin) of the angle; /joint_states and this class give the angle.
    path = robots_dir() / "kinova_description" / "robots" / "kinova.urdf"
    joints = ["j2s6s200_joint_4", "j2s6s200_joint_1", "j2s6s200_joint_3"]
    robot = Robot.load(str(path), joints=joints)
    assert robot.nq == 3
    assert np.all(np.isinf(robot.lower[:2])) and np.all(np.isinf(robot.upper[:2]))
    assert np.isfinite(robot.lower[2]) and np.isfinite(robot.upper[2])
    frame = "j2s6s200_end_effector"
    q = np.array([0.4, -2.0, 1.5])
    # Pinocchio's own configuration, written out: the locked joints at their posture.
    full = pin.buildModelFromUrdf(str(path))
    q_pin = np.concatenate([
        [np.cos(q[joints.index(name)]), np.sin(q[joints.index(name)])]
        if name in joints[:2] else [q[2]] if name == joints[2]
        else robot.locked_posture[name] for name in full.names[1:]])
    data = full.createData()
    pin.forwardKinematics(full, data, q_pin)
    expected = pin.updateFramePlacement(full, data, full.getFrameId(frame)).translation
    np.testing.assert_allclose(robot.frame_position(q, frame), expected, atol=1e-12)
    turned = q + np.array([2 * np.pi, -2 * np.pi, 0.0])
    np.testing.assert_allclose(robot.frame_position(turned, frame), expected, atol=1e-12)
    eps = 1e-6
    fd = np.stack([(robot.frame_position(q + eps * e, frame)
                    - robot.frame_position(q - eps * e, frame)) / (2 * eps)
                   for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(robot.frame_jacobian(q, frame), fd, atol=1e-6)
    np.testing.assert_allclose(robot.frames_kinematics(q, [frame])[1][0], fd, atol=1e-6)
