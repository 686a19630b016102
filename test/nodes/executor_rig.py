"""The ``executor`` node's test rig: an executor plus a probe node that fakes the robot, and
the model files the tests load.
"""

import time
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool

from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.nodes._common import LATCHED_QOS
from policy_align_ros.nodes.executor import Executor

JOINTS = [f"arm_left_{i}_joint" for i in range(1, 8)]
PLANE = "[{type: plane, frame: arm_left_7_link, normal: [0.3, -0.2, 1.0]}]"
ACC = 5.0  # rad/s^2 in the rig: full speed (0.5 rad/s) after 10 periods of 10 ms
PERIOD = 0.01
STEP_TOL = 1e-12


class Rig:
    """An executor plus a probe node that fakes the robot and listens to the commands."""

    def __init__(self, domain_id: int, **params):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        # A generous state timeout: a loaded machine must not turn into stale states. No
        # controller check unless a test asks for one (it would wait for an absent node).
        # No stall detection unless a test asks for it: the faked robot never moves.
        overrides = {"robot": "talos", "joints": JOINTS, "rate_hz": 1.0 / PERIOD,
                     "state_timeout_s": 0.5, "max_acceleration": ACC, "constraints": PLANE,
                     "controller": "", "stall_time_s": 0.0, **params}
        self.node = Executor(context=self.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in overrides.items()])
        self.probe = Node("probe", context=self.context)
        self.commands: list[np.ndarray] = []
        self.diagnostics: list[DiagnosticArray] = []
        self.probe.create_subscription(
            Float64MultiArray, "/velocity_controller/commands",
            lambda m: self.commands.append(np.array(m.data)), 1000)
        self.probe.create_subscription(DiagnosticArray, "/diagnostics",
                                       self.diagnostics.append, 100)
        self.states = self.probe.create_publisher(JointState, "/joint_states", 10)
        self.models = self.probe.create_publisher(String, "/learner/model", LATCHED_QOS)
        self.enable_client = self.probe.create_client(SetBool, "/executor/enable")
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self.q = self.node.robot.neutral() + 0.2
        self.stamp = None  # None: stamp with the node clock

    def publish_state(self, **fields) -> None:
        msg = JointState(name=JOINTS, position=self.q.tolist(), **fields)
        msg.header.stamp = (self.node.get_clock().now().to_msg() if self.stamp is None
                            else self.stamp)
        self.states.publish(msg)

    def spin(self, seconds: float, publish_states: bool = True) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if publish_states:
                self.publish_state()
            self.executor.spin_once(timeout_sec=0.005)

    def spin_until(self, condition, timeout: float = 10.0, publish_states: bool = True,
                   what: str = "condition") -> None:
        end = time.monotonic() + timeout
        while not condition():
            assert time.monotonic() < end, f"timed out waiting for {what}"
            if publish_states:
                self.publish_state()
            self.executor.spin_once(timeout_sec=0.005)

    def enable(self, on: bool) -> SetBool.Response:
        assert self.enable_client.wait_for_service(timeout_sec=5.0)
        future = self.enable_client.call_async(SetBool.Request(data=on))
        # Joint states keep coming while ~/enable waits (for the controller's answer).
        self.spin_until(future.done, timeout=10.0, what="the ~/enable answer")
        return future.result()

    def enable_when_fresh(self) -> None:
        """Wait until the executor holds a usable joint state, then arm; the enable must
        succeed."""
        self.spin_until(lambda: self.node.controller.state_problem(self.node._now_ns()) == "",
                        what="fresh joint states")
        response = self.enable(True)
        assert response.success, response.message

    def close(self) -> None:
        self.executor.shutdown()
        self.probe.destroy_node()
        if self.node is not None:
            self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _attractor_policy(center):
    return lambda X: -(X - center)


def _assert_ramped(commands, start=None):
    """Each joint's command changes by at most max_acceleration x period per message."""
    seq = np.array(([start] if start is not None else []) + list(commands))
    assert np.abs(np.diff(seq, axis=0)).max() <= ACC * PERIOD + STEP_TOL


_FITTED: dict[tuple, bytes] = {}


def _fit_model(path, joints, center):
    """A model file at ``path`` trained on ``joints`` around ``center``.

    Fitted once per (joints, center) and copied: a fit takes seconds on a loaded machine.
    """
    key = (tuple(joints), np.asarray(center, dtype=float).tobytes())
    if key not in _FITTED:
        rng = np.random.default_rng(0)
        trajs = []
        for _ in range(8):
            q = center + rng.normal(scale=0.3, size=len(joints))
            t = np.arange(40) * 0.05
            trajs.append(center + (q - center) * np.exp(-t)[:, None])
        model = PolicyAlign(sigma="medium").fit(
            [Trajectory(x, t) for x in trajs], joint_names=joints)
        model.save(path)
        _FITTED[key] = Path(path).read_bytes()
    else:
        Path(path).write_bytes(_FITTED[key])
    return path
