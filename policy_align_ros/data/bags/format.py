"""What writer and reader of JointState bags share: message type, topic, type store."""

from __future__ import annotations

from pathlib import Path

from rosbags.typesys import Stores, get_typestore

__all__ = ["DEFAULT_TOPIC", "JOINT_STATE", "TYPESTORE", "is_temporary"]

JOINT_STATE = "sensor_msgs/msg/JointState"
DEFAULT_TOPIC = "/joint_states"
# JointState is identical in every ROS 2 distribution's store; Jazzy is the target.
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def is_temporary(path: Path) -> bool:
    """True for hidden entries (such as unfinished bags), which readers ignore."""
    return path.name.startswith(".")
