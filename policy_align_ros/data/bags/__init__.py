"""rosbag2 demonstrations of ``sensor_msgs/msg/JointState`` (ROS-free, ``rosbags``).

Units and conventions: stamps are integer nanoseconds since the epoch (header stamps,
falling back to the bag's receive time when a header stamp is zero); trajectory times
are seconds relative to the first sample of the demonstration; positions and
velocities are in the joints' units (rad, rad/s for revolute joints).

Modules:

* :mod:`~policy_align_ros.data.bags.format`: the message type, default topic and type
  store shared by writer and reader;
* :mod:`~policy_align_ros.data.bags.write`: one demonstration -> one bag, atomically;
* :mod:`~policy_align_ros.data.bags.read`: finding bags and decoding their JointState
  messages, also of bags a killed recorder left unfinished;
* :mod:`~policy_align_ros.data.bags.dataset`: bags -> demonstrations (joints matched by
  name, split at time gaps, malformed messages counted) with a report of what was used.
"""
