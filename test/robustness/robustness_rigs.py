"""ROS rigs of the robustness cases: a node under test with a probe node, and the checks of
a parameter set, a service call and a node start-up that every node's cases share."""

from __future__ import annotations

import contextlib
import threading
import traceback
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from robustness_harness import BIN, Lab, Result, Run, run_process, short

from policy_align_ros.polling import wait_for


class NodeRig:
    """A node under test and a probe node, spun in the background on their own domain.

    Callback exceptions are caught per spin, recorded in ``errors`` (they count as crashes)
    and spinning goes on, so one case's crash does not hide the next case's behaviour.
    """

    def __init__(self, lab: Lab, make: Callable[..., Any], params: dict[str, Any] | None = None,
                 threads: int = 3) -> None:
        import rclpy
        from rclpy.executors import MultiThreadedExecutor
        from rclpy.node import Node
        from rclpy.parameter import Parameter

        self.domain = lab.domain()
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=self.domain)
        self.errors: list[str] = []
        try:
            self.node = make(context=self.context, parameter_overrides=[
                Parameter(k, value=v) for k, v in (params or {}).items()])
        except BaseException:
            rclpy.try_shutdown(context=self.context)
            raise
        self.name = self.node.get_fully_qualified_name()
        self.probe = Node("robustness_probe", context=self.context)
        self.executor = MultiThreadedExecutor(num_threads=threads, context=self.context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()
        self._clients: dict[tuple[Any, str], Any] = {}
        self._publishers: dict[tuple[Any, str], Any] = {}

    def _spin(self) -> None:
        # spin(), not a loop of spin_once(): MultiThreadedExecutor.spin_once can leave a
        # reentrant service unanswered after concurrent calls.
        while not self._stop.is_set() and self.context.ok():
            try:
                self.executor.spin()
            except Exception:  # noqa: BLE001 - recorded as a crash of the node under test
                self.errors.append(traceback.format_exc())

    def call(self, srv_type: Any, service: str, request: Any = None,
             timeout: float = 30.0) -> Any:
        """Call a service from the probe; the response, or None if none came in time."""
        client = self.client(srv_type, service)
        if not client.wait_for_service(timeout_sec=timeout):
            return None
        future = client.call_async(request if request is not None else srv_type.Request())
        wait_for(future.done, timeout)
        return future.result() if future.done() else None

    def client(self, srv_type: Any, service: str) -> Any:
        """The probe's one client of ``service`` (one per service: a second client of the
        same service in the same node can miss its responses)."""
        key = (srv_type, service)
        client = self._clients.get(key)
        if client is None:
            client = self._clients[key] = self.probe.create_client(srv_type, service)
        return client

    def set_param(self, name: str, value: Any) -> tuple[bool, str]:
        """Set a parameter through the node's ``set_parameters`` service (as a user does)."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        request = SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()])
        response = self.call(SetParameters, f"{self.name}/set_parameters", request)
        if response is None:
            return False, "NO ANSWER"
        result = response.results[0]
        return bool(result.successful), result.reason

    def publish(self, msg_type: Any, topic: str, msg: Any) -> None:
        key = (msg_type, topic)
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._publishers[key] = self.probe.create_publisher(msg_type, topic, 100)
        pub.publish(msg)

    def alive(self) -> bool:
        """The node still answers a parameter request."""
        from rcl_interfaces.srv import ListParameters

        return self.call(ListParameters, f"{self.name}/list_parameters",
                         timeout=10.0) is not None

    def close(self) -> None:
        import rclpy

        self._stop.set()
        self.executor.shutdown()
        self._thread.join(timeout=5.0)
        self.probe.destroy_node()
        shutdown = getattr(self.node, "shutdown", None)
        if callable(shutdown):
            shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@contextlib.contextmanager
def rig_case(r: Result, rig: NodeRig) -> Iterator[None]:
    """Count callback exceptions raised during the block, and a node that stops answering."""
    before = len(rig.errors)
    yield
    new = rig.errors[before:]
    if new:
        r.crash = r.traceback = True
        r.data["errors"] = new
    elif not rig.alive():
        r.crash = True
        r.problems.append("the node stopped answering")


def node_start(lab: Lab, executable: str, *ros_args: str, timeout: float = 60.0) -> Run:
    """Start a node executable with ``--ros-args ROS_ARGS``; it should exit by itself."""
    return run_process([str(BIN / executable), "--ros-args", *ros_args],
                       lab.env(lab.domain()), timeout)


def start_refused(r: Result, run: Run, *needles: str) -> None:
    r.crash, r.traceback = run.crashed, run.traceback
    r.data.update(code=run.code, err=run.err)
    if run.code is None:
        r.behaviour = "started and kept running with the bad value"
        r.problems.append("a bad start-up parameter was accepted")
        return
    r.behaviour = f"exit {run.code}: {run.line()}"
    r.expect(run.code != 0, "exit status 0")
    text = run.err + run.out
    for needle in needles:
        r.expect(needle in text, f"the reason does not mention {needle!r}")



def param_case(rig: NodeRig, case: str, tried: str, name: str, value: Any,
                *needles: str) -> Result:
    """Set a bad value at run time: it must be refused with a reason, the node unharmed."""
    r = Result(case, "parameters", tried)
    with rig_case(r, rig):
        before = _get_param(rig, name)
        ok, reason = rig.set_param(name, value)
        after = _get_param(rig, name)
    r.data.update(successful=ok, reason=reason)
    r.behaviour = "accepted" if ok else f"refused: {short(reason, 150)}"
    r.expect(not ok, "the bad value was accepted")
    r.expect(bool(reason.strip()) or ok, "refused without a reason")
    for needle in needles:
        r.expect(needle in reason, f"the reason does not mention {needle!r}")
    r.expect(ok or _same(before, after), "the value changed although refused")
    return r


def _get_param(rig: NodeRig, name: str) -> Any:
    try:
        return rig.node.get_parameter(name).value
    except Exception:  # noqa: BLE001 - an unset parameter
        return None


def _same(a: Any, b: Any) -> bool:
    try:
        return bool(np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True))
    except TypeError:
        return a == b


def trigger(rig: NodeRig, service: str) -> Any:
    from std_srvs.srv import Trigger

    return rig.call(Trigger, service, Trigger.Request())


def service_case(rig: NodeRig, case: str, tried: str, call: Callable[[], Any],
                  success: bool, *needles: str) -> Result:
    r = Result(case, "services", tried)
    with rig_case(r, rig):
        response = call()
    if response is None:
        # An answer that never comes is what a service callback that raised looks like.
        r.behaviour = "no answer within 30 s"
        r.crash = True
        r.problems.append("the service did not answer")
        return r
    r.data.update(success=response.success, message=response.message)
    r.behaviour = f"success={str(response.success).lower()}: {short(response.message, 150)}"
    r.expect(response.success == success, f"success={response.success}, expected {success}")
    for needle in needles:
        r.expect(needle in response.message, f"the message does not mention {needle!r}")
    return r



def duration(seconds: float):
    from rclpy.duration import Duration

    return Duration(nanoseconds=int(seconds * 1e9))

