"""The conductor: a node in the demo's own process that watches the graph on simulated
time and calls its services."""

from __future__ import annotations

import time

import numpy as np
import rclpy
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from policy_align_ros.client.demo.graph import Graph
from policy_align_ros.client.demo.periods import repeated_steps
from policy_align_ros.client.demo.settings import StageError
from policy_align_ros.data.messages import JointSelector
from policy_align_ros.nodes._common import LATCHED_QOS

__all__ = ["Conductor"]


class Conductor:
    """A node in this process that watches the graph on sim time and calls its services.

    While ``trace`` is a list, every joint state is appended as ``(stamp_s, q)``, and the
    control periods of the run are counted: ``ticks`` joint states, of which ``missed``
    moved by the same non-zero step as the one before, i.e. the simulator integrated a
    command it had already used (no new command came within the period; see
    :func:`repeated_steps`).
    """

    def __init__(self, context: rclpy.Context, joints: list[str], graph: Graph) -> None:
        self.selector = JointSelector(joints)
        self.node = Node("policy_align_demo", context=context, parameter_overrides=[
            Parameter("use_sim_time", value=True)])
        self.graph = graph
        # Made last of what can fail: close() shuts it down before the context goes.
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.q: np.ndarray | None = None
        self.trace: list[tuple[float, np.ndarray]] | None = None
        self.progress = ""
        self.ticks = self.missed = 0
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self._states = None
        self.listen(True)
        self.node.create_subscription(String, "/demonstrator/progress", self._on_progress,
                                      LATCHED_QOS)

    def close(self) -> None:
        """Stop the executor and destroy the node (before the context shuts down)."""
        self.executor.shutdown()
        self.node.destroy_node()

    def listen(self, on: bool) -> None:
        """Subscribe to ``/joint_states`` or not (each message costs this process time)."""
        if on and self._states is None:
            self._last = None
            self._states = self.node.create_subscription(JointState, "/joint_states",
                                                         self._on_state, 1000)
        elif not on and self._states is not None:
            self.node.destroy_subscription(self._states)
            self._states = None

    def _on_state(self, msg: JointState) -> None:
        q = self.selector.vector(msg.name, msg.position, msg.velocity, msg.effort)
        if isinstance(q, str):  # rejected, for the reason q names
            return
        self.q = q
        if self.trace is not None:
            self.trace.append((msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, q))
            self.ticks += 1
            if self._last is not None and repeated_steps(
                    np.array([self._last[1], self._last[0], q]))[0]:
                self.missed += 1
        # (latest, the one before): two states before this one are needed for two steps.
        self._last = (q, self._last[0]) if self._last is not None else (q, q)

    def _on_progress(self, msg: String) -> None:
        self.progress = msg.data

    def now(self) -> float:
        """Simulated seconds (0 until the first /clock message)."""
        return self.node.get_clock().now().nanoseconds * 1e-9

    def spin(self, seconds: float) -> None:
        """Spin for ``seconds`` of wall time."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.05, max(end - time.monotonic(), 0)))

    def spin_sim(self, seconds: float, wall_timeout: float,
                 allow_exit: tuple[str, ...] = ("demonstrator",)) -> None:
        """Spin until ``seconds`` of simulated time passed; StageError if it stalls."""
        end = self.now() + seconds
        deadline = time.monotonic() + wall_timeout
        while self.now() < end:
            if time.monotonic() > deadline:
                raise StageError(f"simulated time stalled: {end - self.now():.2f} s of "
                                 f"{seconds:g} s left after {wall_timeout:g} s wall time")
            self.executor.spin_once(timeout_sec=0.01)
            self.graph.check(allow_exit=allow_exit)

    def call(self, srv_type, name: str, request, timeout: float):
        """Call service ``name``; its response, or StageError after ``timeout`` s."""
        client = self.node.create_client(srv_type, name)
        try:
            end = time.monotonic() + timeout
            while not client.service_is_ready():
                if time.monotonic() > end:
                    raise StageError(f"service {name} not available after {timeout:g} s")
                self.spin(0.05)
            future = client.call_async(request)
            self.executor.spin_until_future_complete(
                future, timeout_sec=max(end - time.monotonic(), 0.1))
            if not future.done() or future.result() is None:
                raise StageError(f"service {name} did not answer within {timeout:g} s")
            return future.result()
        finally:
            self.node.destroy_client(client)

    def trigger(self, name: str, timeout: float = 10.0) -> str:
        """Call Trigger service ``name``; its message, or StageError if it failed."""
        response = self.call(Trigger, name, Trigger.Request(), timeout)
        if not response.success:
            raise StageError(f"{name} failed: {response.message}")
        return response.message

    def set_parameter(self, node: str, name: str, value) -> None:
        """Set ``node``'s parameter ``name``; StageError if refused."""
        request = SetParameters.Request(parameters=[Parameter(name, value=value)
                                                    .to_parameter_msg()])
        result = self.call(SetParameters, f"{node}/set_parameters", request, 10.0).results[0]
        if not result.successful:
            raise StageError(f"{node}: parameter {name} refused: {result.reason}")

    def get_parameter(self, node: str, name: str):
        """``node``'s parameter ``name`` (None when it has none)."""
        response = self.call(GetParameters, f"{node}/get_parameters",
                             GetParameters.Request(names=[name]), 10.0)
        return Parameter.from_parameter_msg(
            _named(name, response.values[0])).value if response.values else None

    def enable(self, on: bool) -> SetBool.Response:
        """Call ``/executor/enable`` with ``on``."""
        return self.call(SetBool, "/executor/enable", SetBool.Request(data=on), 10.0)


def _named(name: str, value):
    from rcl_interfaces.msg import Parameter as ParameterMsg

    return ParameterMsg(name=name, value=value)

