"""Demonstrations on disk: rosbag2 bags of ``sensor_msgs/msg/JointState`` (ROS-free).

Imports numpy, rosbags and :mod:`policy_align_ros.learning` only (the learning
pipeline's ``frames:`` state imports :mod:`policy_align_ros.kinematics` when used). Stamps
are integer nanoseconds, trajectory times seconds, positions and velocities in the joints'
units.
"""

from policy_align_ros.data.bags.dataset import DatasetReport, DemoInfo, load_dataset
from policy_align_ros.data.bags.read import find_bags, read_joint_states
from policy_align_ros.data.bags.write import write_joint_state_bag
from policy_align_ros.data.messages import SKIP_REASONS
from policy_align_ros.data.pipeline import PipelineResult, learn_pipeline
from policy_align_ros.data.quality import Gates
from policy_align_ros.data.recording import DemoRecorder

__all__ = [
    "SKIP_REASONS",
    "DatasetReport",
    "DemoInfo",
    "DemoRecorder",
    "Gates",
    "PipelineResult",
    "find_bags",
    "learn_pipeline",
    "load_dataset",
    "read_joint_states",
    "write_joint_state_bag",
]
