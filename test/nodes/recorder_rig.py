"""The ``recorder`` node's test rig: joint-state messages, a harness that publishes them and
calls the node's services, and a private ``rclpy.Context`` per test.
"""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from policy_align_ros.nodes.recorder import RecorderNode
from policy_align_ros.polling import wait_for

T0 = 1_700_000_000 * 10**9
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10000,
                 reliability=ReliabilityPolicy.RELIABLE)


def _msg(stamp_ns: int, names, positions, velocities=()) -> JointState:
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg.name = list(names)
    msg.position = [float(x) for x in positions]
    msg.velocity = [float(x) for x in velocities]
    return msg


def _wait(predicate, timeout: float, what: str) -> None:
    if not wait_for(predicate, timeout):
        raise AssertionError(f"timed out after {timeout} s waiting for {what}")


class _Harness:
    """A test node (publisher, service clients) and optionally a recorder, spun in a thread."""

    def __init__(self, ctx: rclpy.Context, recorder: RecorderNode | None,
                 recorder_name: str = "/recorder") -> None:
        self.node = Node("recorder_test_client", context=ctx)
        self.pub = self.node.create_publisher(JointState, "/joint_states", QOS)
        self.start = self.node.create_client(Trigger, f"{recorder_name}/start_demo")
        self.stop = self.node.create_client(Trigger, f"{recorder_name}/stop_demo")
        self.recorder = recorder
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.node)
        if recorder is not None:
            self.executor.add_node(recorder)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def ready(self, timeout: float = 20.0) -> None:
        assert self.start.wait_for_service(timeout_sec=timeout), "no ~/start_demo"
        assert self.stop.wait_for_service(timeout_sec=timeout), "no ~/stop_demo"
        _wait(lambda: self.pub.get_subscription_count() >= 1, timeout, "the subscription")
        if self.recorder is not None:
            sub = self.recorder.subscription
            _wait(lambda: sub.get_publisher_count() >= 1, timeout, "the publisher")
        time.sleep(0.3)  # let both ends of the reliable match settle

    def call(self, client, timeout: float = 20.0) -> Trigger.Response:
        future = client.call_async(Trigger.Request())
        _wait(future.done, timeout, "a service response")
        return future.result()

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        self.thread.join(timeout=5.0)
        self.node.destroy_node()
        if self.recorder is not None:
            self.recorder.destroy_node()


@contextmanager
def _ros(domain_id: int):
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


@contextmanager
def _ab_recorder(domain_id: int, dataset_dir):
    """A recorder of joints ``a`` and ``b`` into ``dataset_dir`` on its own domain, and a
    ready harness for it: ``(harness, DemoRecorder)``."""
    with _ros(domain_id) as ctx:
        recorder = RecorderNode(context=ctx, parameter_overrides=[
            Parameter("dataset_dir", value=str(dataset_dir)),
            Parameter("joints", value=["a", "b"])])
        harness = _Harness(ctx, recorder)
        try:
            harness.ready()
            yield harness, recorder.recorder
        finally:
            harness.close()
