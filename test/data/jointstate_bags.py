"""JointState bags for the tests of policy_align_ros.data.bags: random demonstrations and
bags written as another tool would write them. Stamps in ns, positions in rad."""

from __future__ import annotations

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from policy_align_ros.data.bags.write import write_joint_state_bag

TS = get_typestore(Stores.ROS2_HUMBLE)
JS = TS.types["sensor_msgs/msg/JointState"]
HEADER = TS.types["std_msgs/msg/Header"]
TIME = TS.types["builtin_interfaces/msg/Time"]
T0 = 1_700_000_000 * 10**9
MS = 10**6


def _demo(rng: np.random.Generator, n_samples: int = 50, n: int = 3):
    stamps = T0 + np.cumsum(rng.integers(5, 15, n_samples)) * MS
    q = rng.normal(size=(n_samples, n))
    v = rng.normal(size=(n_samples, n))
    return stamps, q, v


def _foreign_bag(path, messages, *, storage=StoragePlugin.SQLITE3, topic="/robot/joints"):
    """Write arbitrary JointState messages (and one unrelated topic), as another tool would.

    ``messages`` are (stamp_ns, names, positions, velocities[, bag_time_ns]).
    """
    with Writer(path, version=8, storage_plugin=storage) as writer:
        conn = writer.add_connection(topic, JS.__msgtype__, typestore=TS)
        other = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=TS)
        string = TS.types["std_msgs/msg/String"]
        for item in messages:
            stamp, names, pos, vel = item[:4]
            bag_time = item[4] if len(item) > 4 else stamp
            msg = JS(
                header=HEADER(stamp=TIME(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=""),
                name=list(names),
                position=np.asarray(pos, dtype=float),
                velocity=np.asarray(vel, dtype=float),
                effort=np.empty(0),
            )
            writer.write(conn, bag_time, TS.serialize_cdr(msg, JS.__msgtype__))
            writer.write(other, bag_time, TS.serialize_cdr(string(data="x"), string.__msgtype__))


def _good_dataset(tmp_path, n_bags=8, joints=("j1", "j2"), seed=20):
    rng = np.random.default_rng(seed)
    for k in range(n_bags):
        stamps, q, _ = _demo(rng, 20, n=len(joints))
        write_joint_state_bag(tmp_path / f"demo_{k:04d}", list(joints), stamps, q)
