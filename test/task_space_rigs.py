"""Shared rigs of the task-space tests: the Talos left arm and torso, a random joint trajectory."""

import numpy as np

from policy_align_ros.kinematics import Robot

ARM = [f"arm_left_{i}_joint" for i in range(1, 8)] + ["torso_1_joint", "torso_2_joint"]
HAND = "gripper_left_base_link"
ELBOW = "arm_left_4_link"


def _joint_trajectory(robot: Robot, m: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = 0.05 * rng.standard_normal((m, robot.nq))
    return robot.clip(robot.neutral() + np.cumsum(steps, axis=0))
