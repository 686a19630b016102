"""Integration tests of the ``demonstrator`` node (own rclpy.Context, domain ids 180-189).

The robot is the real ``sim_robot`` node (left arm of Talos); the recorder is faked by
Trigger services on a probe node, which also records the joint states in between.
"""


import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from policy_align_ros.nodes.demonstrator import Demonstrator, random_plane_specs
from policy_align_ros.nodes.sim_robot import SimRobot

JOINTS = [f"arm_left_{i}_joint" for i in range(1, 8)]
HAND = "arm_left_7_link"


def _run(domain_id, refuse_start=False, num_demos=2, plane_switches=0, duration=0.6):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    nodes = []
    try:
        common = [Parameter("robot", value="talos"), Parameter("joints", value=JOINTS),
                  Parameter("rate_hz", value=100.0)]
        sim = SimRobot(context=context, parameter_overrides=common)
        demo = Demonstrator(context=context, parameter_overrides=common + [
            Parameter("num_demos", value=num_demos),
            Parameter("demo_duration_s", value=duration),
            Parameter("plane_switches", value=plane_switches),
            Parameter("constraint_frames", value=[HAND]), Parameter("seed", value=3),
            Parameter("service_timeout_s", value=5.0)])
        probe = Node("recorder", context=context)
        nodes += [sim, demo, probe]
        events, segments = [], []

        def start(request, response):
            events.append("start")
            segments.append([])
            response.success = not refuse_start
            response.message = "refused" if refuse_start else "recording"
            return response

        def stop(request, response):
            events.append("stop")
            response.success = True
            return response

        def state(msg):
            if events and events[-1] == "start":
                segments[-1].append(np.array(msg.position))

        probe.create_service(Trigger, "~/start_demo", start)
        probe.create_service(Trigger, "~/stop_demo", stop)
        probe.create_subscription(JointState, "/joint_states", state, 100)
        executor = SingleThreadedExecutor(context=context)
        for node in nodes:
            executor.add_node(node)
        executor.spin_until_future_complete(demo.done, timeout_sec=30.0)
        return demo, sim, events, segments
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_demonstrations_are_bracketed_and_keep_the_hand_on_a_plane():
    demo, sim, events, segments = _run(180)
    assert demo.done.done() and demo.done.result() == 0
    assert events == ["start", "stop", "start", "stop"]
    assert demo.demos_done == 2
    for seg in segments:
        assert len(seg) >= 30
        hand = np.array([sim.robot.frame_position(q, HAND) for q in seg])
        moved = np.linalg.norm(hand[-1] - hand[0])
        assert moved > 0.01  # the expert really moves the hand ...
        s = np.linalg.svd(hand - hand.mean(axis=0), compute_uv=False)
        assert s[2] < 1e-2 * s[0]  # ... within a plane
        dist = np.linalg.norm(np.array(seg) - demo.attractor, axis=1)
        assert dist[-1] < dist[0]  # towards the attractor


def _planarity(hand):
    s = np.linalg.svd(hand - hand.mean(axis=0), compute_uv=False)
    return s[2] / s[0]


def test_planes_are_redrawn_within_a_demonstration():
    demo, sim, events, segments = _run(182, num_demos=1, plane_switches=2, duration=1.5)
    assert demo.done.result() == 0 and events == ["start", "stop"]
    hand = np.array([sim.robot.frame_position(q, HAND) for q in segments[0]])
    thirds = np.array_split(hand, 3)
    # Each third (trimmed at the switches) lies on its own plane; the whole does not.
    assert all(_planarity(part[5:-5]) < 1e-2 for part in thirds)
    assert _planarity(hand) > 3e-2


def test_refused_start_ends_with_status_1():
    demo, _, events, _ = _run(181, refuse_start=True)
    assert demo.done.result() == 1 and events == ["start"]


def test_random_plane_specs_are_unit_normals_per_frame():
    specs = random_plane_specs(["a", "b"], np.random.default_rng(0))
    assert [s["frame"] for s in specs] == ["a", "b"]
    for s in specs:
        assert s["type"] == "plane"
        assert np.linalg.norm(s["normal"]) == pytest.approx(1.0)
    assert specs[0]["normal"] != specs[1]["normal"]
