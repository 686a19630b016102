"""The ROS environment checked before rclpy.init (policy_align_ros.ros_env), and the
node and client entry points that refuse a domain id Fast DDS cannot use."""

from __future__ import annotations

import os
import subprocess
import sys

from policy_align_ros.ros_env import DOMAIN_RANGE, FASTDDS_PROFILES, domain_id_problem


def test_a_domain_id_beyond_fast_dds_ports_is_named_with_the_fix():
    high = DOMAIN_RANGE[1]
    problem = domain_id_problem({"ROS_DOMAIN_ID": str(high + 9)})
    assert str(high + 9) in problem and "ROS_DOMAIN_ID" in problem
    assert FASTDDS_PROFILES[0] in problem  # the other way out
    for fine in ({}, {"ROS_DOMAIN_ID": ""}, {"ROS_DOMAIN_ID": str(high)},
                 {"ROS_DOMAIN_ID": "0"},
                 {"ROS_DOMAIN_ID": "241", FASTDDS_PROFILES[1]: "/tmp/dds.xml"},
                 {"ROS_DOMAIN_ID": "seven"}):  # rcl names a value that is no integer
        assert domain_id_problem(fine) == "", fine


def test_nodes_and_clients_refuse_it_before_starting_ros():
    env = {k: v for k, v in os.environ.items() if k not in FASTDDS_PROFILES}
    env["ROS_DOMAIN_ID"] = "241"
    node = ("import sys; from rclpy.node import Node; "
            "from policy_align_ros.nodes._common import run_node; "
            "sys.exit(run_node(lambda: Node('never_built')))")
    client = ("import sys; from policy_align_ros.client.oneshot import open_context; "
              "sys.exit(0 if open_context('call', 1.0) is None else 3)")
    for code, expected in ((node, 1), (client, 0)):  # the node exits 1, the client gets None
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                              text=True, timeout=60)
        assert done.returncode == expected and "241" in done.stderr, done.stderr
        assert "Traceback" not in done.stderr
