"""The executor's robot and joints: an explicit parameter, then the model file, then the
robot config, else an error naming the fix; a model file contradicting the robot config
given is not loaded; the model file is read once (own rclpy.Context, domain ids 196-198,
228 and 122)."""

import numpy as np
import pytest
import rclpy
from executor_rig import _fit_model
from rclpy.parameter import Parameter

from policy_align_ros.kinematics.robot import ROBOTS, robots_dir
from policy_align_ros.kinematics.robot_config import load_robot_config
from policy_align_ros.learning import PolicyAlign, model_io
from policy_align_ros.nodes.executor import Executor

PANDA = load_robot_config("panda").joints
UR5 = load_robot_config("ur5")


@pytest.fixture
def executor():
    """``executor(domain_id, **params)``: an Executor node (or its exception), closed after
    the test."""
    contexts = []

    def make(domain_id, **params):
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain_id)
        contexts.append(context)
        node = Executor(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        contexts.append(node)
        return node

    yield make
    for item in reversed(contexts):
        if isinstance(item, Executor):
            item.destroy_node()
        else:
            rclpy.try_shutdown(context=item)


def _model(path, joints, center, robot):
    """A model file learnt on ``joints`` naming ``robot`` (None: an old-format file)."""
    _fit_model(path, joints, np.asarray(center, dtype=float))
    model = PolicyAlign.load(path)
    model.robot_ = robot
    model.save(path)
    return str(path)


def test_robot_without_joints_takes_the_joints_of_its_config(executor):
    node = executor(196, robot="panda")
    assert node.robot.joint_names == PANDA
    assert list(node.get_parameter("joints").value) == PANDA
    assert node.get_parameter("controller").value == "/velocity_controller"
    # Explicit joints come first.
    other = executor(197, robot_config="panda", joints=PANDA[:3])
    assert other.robot.joint_names == PANDA[:3] and other.robot.name == "panda"


def test_the_model_file_gives_robot_and_joints_before_the_config(executor, tmp_path):
    # Learnt on the UR5's joints in another order: the config's (controller) order wins.
    path = _model(tmp_path / "ur5.npz", UR5.joints[::-1], UR5.home[::-1], "ur5")
    node = executor(196, model_path=path)
    assert node.robot.name == "ur5" and node.robot.joint_names == UR5.joints
    assert node.get_parameter("robot").value == "ur5" and node.model_path == path
    # An old file without the robot field: its joints, the robot named explicitly.
    old = _model(tmp_path / "old.npz", PANDA[:4], np.zeros(4), None)
    legacy = executor(197, robot="panda", model_path=old)
    assert legacy.robot.joint_names == PANDA[:4] and legacy.model_path == old


def test_a_model_file_contradicting_robot_config_is_not_loaded_at_start(executor, tmp_path,
                                                                         capfd):
    path = _model(tmp_path / "ur5.npz", UR5.joints, UR5.home, "ur5")
    node = executor(122, robot_config="panda", model_path=path)
    # The config's robot and joints, no model, and model_path saying so.
    assert node.robot.name == "panda" and node.robot.joint_names == PANDA
    assert node.controller.step.policy is None and node.model_path == ""
    assert node.get_parameter("model_path").value == ""
    # The error names the file, both robots, a joint of each and the fixes.
    err = capfd.readouterr().err
    line = next(text for text in err.splitlines() if path in text)
    for item in ("'ur5'", UR5.joints[0], "'panda'", PANDA[-1], "robot_config",
                 "-p robot:=", "-p joints:="):
        assert item in line, item
    # Set at run time, the same file is refused as before.
    result = node.set_parameters([Parameter("model_path", value=path)])[0]
    assert not result.successful and node.controller.step.policy is None
    # The same robot with other joints (a panda model of three joints) is refused too.
    few = _model(tmp_path / "few.npz", PANDA[:3], np.zeros(3), "panda")
    node = executor(122, robot_config="panda", model_path=few)
    assert node.robot.joint_names == PANDA and node.controller.step.policy is None
    # Explicit robot and joints win over the config: the model loads.
    node = executor(122, robot_config="panda", robot="ur5", joints=UR5.joints,
                    model_path=path)
    assert node.robot.name == "ur5" and node.model_path == path
    assert node.controller.step.policy is not None


def test_the_robot_parameter_names_the_robots_it_knows(executor):
    desc = executor(122, robot="panda").describe_parameters(["robot"])[0]
    assert all(name in desc.description for name in ROBOTS) and "URDF" in desc.description


def test_the_model_file_given_at_start_is_read_once(executor, tmp_path, monkeypatch):
    path = _model(tmp_path / "ur5.npz", UR5.joints, UR5.home, "ur5")
    reads = []
    load_npz = model_io.load_npz
    monkeypatch.setattr(model_io, "load_npz", lambda *a, **k: reads.append(a[0])
                        or load_npz(*a, **k))
    node = executor(198, model_path=path)
    # Robot, joints and the policy from one read of the file.
    assert node.robot.name == "ur5" and node.controller.step.policy is not None
    assert reads == [path]
    # Setting model_path later reads the file again: it may have been replaced.
    assert node.set_parameters([Parameter("model_path", value=path)])[0].successful
    assert reads == [path, path]


def test_unknown_joints_stop_the_node_with_the_fix(executor):
    urdf = str(robots_dir() / "ur_description" / "urdf" / "ur5_robot.urdf")
    with pytest.raises(ValueError, match="robot_config") as err:
        executor(198, robot=urdf)
    assert "joints" in str(err.value)
    # Joints of another robot name where they came from and the fix.
    with pytest.raises(ValueError, match="robot_config") as err:
        executor(198, robot="panda", joints=["torso_1_joint"])
    assert "torso_1_joint" in str(err.value)


def test_a_joint_state_model_brings_continuous_joints_to_its_turn(executor, tmp_path):
    # Kinova's joints 1 and 4 are continuous, joint 2 is not; learnt near pi on joint 1.
    urdf = str(robots_dir() / "kinova_description" / "robots" / "kinova.urdf")
    joints = ["j2s6s200_joint_1", "j2s6s200_joint_2", "j2s6s200_joint_4"]
    path = _model(tmp_path / "kinova.npz", joints, [3.1, 2.5, 0.5], urdf)
    node = executor(228, model_path=path)
    centres = node.controller.step.turn_centres
    support = PolicyAlign.load(path).support_states_
    middle = 0.5 * (support.min(axis=0) + support.max(axis=0))
    np.testing.assert_allclose(centres[[0, 2]], middle[[0, 2]])
    assert np.isnan(centres[1])
    # A wrapped measurement gets the command of the same posture on the model's turn.
    q = np.array([3.3, 2.5, 0.5])
    wrapped = q - np.array([2 * np.pi, 0.0, 0.0])
    np.testing.assert_allclose(node.controller.step(wrapped)[0], node.controller.step(q)[0])
