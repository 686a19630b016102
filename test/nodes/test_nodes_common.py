"""Tests of policy_align_ros.nodes._common (the shared main() of the node executables;
domain ids 192 and 104)."""

import os
import subprocess
import sys

import pytest

ENV = dict(os.environ, ROS_DOMAIN_ID="192")

# A node whose constructor is hit by SIGTERM (a graph stopped while the machine is busy):
# it must not spin on (its timer would keep it alive until the test's timeout).
_SIGNALLED_WHILE_STARTING = """
import os, signal, sys, time
from rclpy.node import Node
from policy_align_ros.nodes._common import run_node

class Slow(Node):
    def __init__(self):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.2)
        super().__init__("slow_start")
        self.create_timer(0.01, lambda: None)

sys.exit(run_node(Slow, ["--ros-args"]))
"""


def test_sigterm_while_the_node_is_built_stops_it():
    done = subprocess.run([sys.executable, "-c", _SIGNALLED_WHILE_STARTING],
                          env=ENV, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_bad_parameter_file_exits_one(tmp_path):
    code = ("import sys; from rclpy.node import Node; "
            "from policy_align_ros.nodes._common import run_node; "
            f"sys.exit(run_node(lambda: Node('n'), ['--ros-args', '--params-file', "
            f"'{tmp_path / 'missing.yaml'}']))")
    done = subprocess.run([sys.executable, "-c", code], env=ENV,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1, done.stderr
    assert done.stderr and "Traceback" not in done.stderr


# A node whose destruction never returns (as Fast DDS can deadlock destroying a
# participant): after SIGTERM the process must still end, with the loop's exit code.
_STUCK_IN_TEARDOWN = """
import os, signal, sys, threading
from rclpy.node import Node
from policy_align_ros.nodes._common import run_node

class Stuck(Node):
    def __init__(self):
        super().__init__("stuck_teardown")
        self.create_timer(0.05, lambda: os.kill(os.getpid(), signal.SIGTERM))

    def destroy_node(self):
        threading.Event().wait()

sys.exit(run_node(Stuck, ["--ros-args"]))
"""


def test_a_teardown_that_never_returns_still_ends_the_process():
    done = subprocess.run([sys.executable, "-c", _STUCK_IN_TEARDOWN], env=ENV,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr  # ended by the watchdog, with the loop's code


# The same in C++ that holds the GIL (Fast DDS spinning in DomainParticipant::set_listener
# while it destroys a participant), so no Python thread runs: here a regular expression
# that backtracks forever. The C watchdog ends the process (status 1, tracebacks on stderr).
_STUCK_HOLDING_THE_GIL = _STUCK_IN_TEARDOWN.replace(
    "threading.Event().wait()", "__import__('re').match(r'(a+)+$', 'a' * 64 + 'b')")


def test_a_teardown_stuck_holding_the_gil_still_ends_the_process():
    done = subprocess.run([sys.executable, "-c", _STUCK_HOLDING_THE_GIL], env=ENV,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr


# A node that stops itself: run_node's normal way out. Then the garbage collector's worst
# order is forced: it may finalise an executor's signal guard condition before the executor
# itself (both unreachable together), and an executor that still holds it then prints
# "Exception ignored in ... Executor.__del__ ... InvalidHandle".
_STOPS_ITSELF = """
import gc, os, signal, sys
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerGuardCondition
from policy_align_ros.nodes._common import run_node

class Short(Node):
    def __init__(self):
        super().__init__("short_lived")
        self.create_timer(0.05, lambda: os.kill(os.getpid(), signal.SIGTERM))

code = run_node(Short, ["--ros-args"], executor_factory={factory})
for obj in gc.get_objects():
    if isinstance(obj, SignalHandlerGuardCondition):
        obj.__del__()
gc.collect()
sys.exit(code)
"""


@pytest.mark.parametrize("factory", ["SingleThreadedExecutor",
                                     "lambda: MultiThreadedExecutor(2)"])
def test_a_node_main_ends_without_ignored_exceptions(factory):
    done = subprocess.run([sys.executable, "-c", _STOPS_ITSELF.format(factory=factory)],
                          env=ENV, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "Exception ignored" not in done.stderr, done.stderr
    assert "Traceback" not in done.stderr, done.stderr


def test_a_parameter_given_at_start_that_the_node_does_not_declare_is_named(ros_context):
    # rclpy ignores it: a misspelt limit would leave the default in force, unsaid.
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from policy_align_ros.nodes._common import undeclared_overrides

    node = Node("typo", context=ros_context(104), parameter_overrides=[
        Parameter("max_velocty", value=0.1), Parameter("max_velocity", value=0.1),
        Parameter("qos_overrides./x.subscription.depth", value=5)])
    try:
        node.declare_parameter("max_velocity", 0.5)
        found = undeclared_overrides(node)
        assert len(found) == 1 and "'max_velocty'" in found[0] and "max_velocity" in found[0]
    finally:
        node.destroy_node()
