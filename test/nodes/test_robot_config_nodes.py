"""sim_robot, demonstrator and recorder on a robot config (own rclpy.Context, domain id
118): robot, joints, home posture and frames come from the config unless set."""

import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter

from policy_align_ros.kinematics.robot_config import load_robot_config
from policy_align_ros.nodes._common import DEFAULT_JOINTS
from policy_align_ros.nodes.demonstrator import Demonstrator
from policy_align_ros.nodes.recorder import RecorderNode
from policy_align_ros.nodes.sim_robot import SimRobot

UR5 = load_robot_config("ur5")
PANDA = load_robot_config("panda")


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=118)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def _node(cls, context, **params):
    return cls(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()])


def test_sim_robot_takes_robot_joints_and_home_from_the_config(context):
    node = _node(SimRobot, context, robot_config="ur5")
    try:
        assert node.robot.name == "ur5" and node.robot.joint_names == UR5.joints
        np.testing.assert_allclose(node.sim.q, UR5.home)
        assert list(node.get_parameter("joints").value) == UR5.joints
    finally:
        node.destroy_node()
    # An explicit joint subset wins (and the home posture, one per config joint, is not
    # used for it).
    node = _node(SimRobot, context, robot_config="ur5", joints=UR5.joints[:2])
    try:
        assert node.robot.joint_names == UR5.joints[:2]
        np.testing.assert_allclose(node.sim.q, node.robot.neutral())
    finally:
        node.destroy_node()


def test_demonstrator_constrains_the_configs_frames_around_its_home(context, tmp_path):
    node = _node(Demonstrator, context, robot_config="ur5")
    try:
        assert node.robot.joint_names == UR5.joints
        assert node.script.frames == UR5.constraint_frames
        np.testing.assert_allclose(node.attractor, UR5.home)
    finally:
        node.destroy_node()


def test_recorder_records_the_configs_joints_unless_told(context, tmp_path):
    node = _node(RecorderNode, context, robot_config="panda", dataset_dir=str(tmp_path / "a"))
    try:
        assert node._recorder.joints == PANDA.joints
    finally:
        node.destroy_node()
    node = _node(RecorderNode, context, robot_config="panda", joints=["panda_joint3"],
                 dataset_dir=str(tmp_path / "b"))
    try:
        assert node._recorder.joints == ["panda_joint3"]
    finally:
        node.destroy_node()


def test_the_default_joints_are_the_talos_configs():
    assert DEFAULT_JOINTS == load_robot_config("talos").joints
