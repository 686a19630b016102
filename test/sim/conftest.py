"""Shared rig of the sim tests: Talos's arms and torso with both hands as task space."""

import pytest

from policy_align_ros.kinematics import Robot, TaskSpaceMap

HANDS = ["gripper_left_base_link", "gripper_right_base_link"]
ARMS = ([f"arm_left_{i}_joint" for i in range(1, 8)]
        + [f"arm_right_{i}_joint" for i in range(1, 8)] + ["torso_1_joint", "torso_2_joint"])


@pytest.fixture(scope="module")
def hands():
    robot = Robot.load("talos", joints=ARMS)
    smap = TaskSpaceMap(robot, HANDS)
    return robot, smap
