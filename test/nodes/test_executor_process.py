"""The ``executor`` node as its console script runs it: signals, a bad start-up (domain ids
127, 157, 171, 202, 203).

Assertions count control ticks and messages, never wall-clock speed: waits are "until a
condition holds, or fail after a generous timeout".
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from executor_rig import JOINTS, _fit_model
from rclpy.exceptions import InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from policy_align_ros.nodes.executor import Executor


def _start_executor_process(domain_id: int, model, log: Path, **params):
    """The executor as its console script runs it (``main()``), armed at the first state.

    No controller node runs here: the joint order check is opted out of on the command
    line (``controller:=none``), as a user without one would.
    """
    code = "import sys; from policy_align_ros.nodes.executor import main; sys.exit(main())"
    args = []
    values = {"robot": "talos", "joints": "[" + ",".join(JOINTS) + "]",
              "model_path": str(model), "start_enabled": "true", "state_timeout_s": "1.0",
              "controller": "none", **params}
    for k, v in values.items():
        args += ["-p", f"{k}:={v}"]
    with open(log, "wb") as out:
        return subprocess.Popen([sys.executable, "-c", code, "--ros-args", *args],
                                env=dict(os.environ, ROS_DOMAIN_ID=str(domain_id)),
                                stdout=out, stderr=subprocess.STDOUT)


def test_sigint_to_the_executor_process_leaves_a_zero_command(tmp_path):
    """The installed-style process (``main()``) stops the robot when interrupted."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=157)
    probe = Node("probe", context=context)
    proc = None
    try:
        model = _fit_model(tmp_path / "model.npz", JOINTS, np.zeros(len(JOINTS)))
        commands = []
        probe.create_subscription(Float64MultiArray, "/velocity_controller/commands",
                                  lambda m: commands.append(np.array(m.data)), 100)
        states = probe.create_publisher(JointState, "/joint_states", 10)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(probe)
        log = tmp_path / "executor.log"
        proc = _start_executor_process(157, model, log)
        q = np.full(len(JOINTS), 0.3)
        q[JOINTS.index("arm_left_4_joint")] = -0.3  # inside its limits [-2.36, 0]
        end = time.monotonic() + 30.0
        while not (commands and np.any(commands[-1])) and time.monotonic() < end:
            msg = JointState(name=JOINTS, position=q.tolist())
            msg.header.stamp = probe.get_clock().now().to_msg()
            states.publish(msg)
            executor.spin_once(timeout_sec=0.01)
        assert commands and np.any(commands[-1]), log.read_text()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10.0) == 0, log.read_text()
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.01)
        assert not np.any(commands[-1]), log.read_text()
        # A clean exit: no finaliser failing while the interpreter shuts down.
        assert "Exception ignored" not in log.read_text(), log.read_text()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        probe.destroy_node()
        rclpy.try_shutdown(context=context)


def test_sigkill_mid_motion_sim_robot_stops_within_its_command_timeout(tmp_path):
    """Killed executor: no final zero; only the command timeout stops the robot.

    A ros2_control velocity controller holds the last command forever; ``sim_robot``
    drops it after ``command_timeout_s``. This is the hazard the README describes: a
    real robot needs that timeout on the controller side.
    """
    from policy_align_ros.nodes.sim_robot import SimRobot

    timeout_s, period_ns = 0.2, 10_000_000
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=203)
    nodes, proc = [], None
    try:
        model = _fit_model(tmp_path / "model.npz", JOINTS, np.zeros(len(JOINTS)))
        sim = SimRobot(context=context, parameter_overrides=[
            Parameter("joints", value=JOINTS), Parameter("rate_hz", value=100.0),
            Parameter("command_timeout_s", value=timeout_s),
            Parameter("initial_positions", value=[0.5, 0.4, 0.5, -0.8, 0.4, 0.4, 0.4])])
        probe = Node("probe", context=context)
        nodes += [sim, probe]
        states: list[tuple[int, np.ndarray, np.ndarray]] = []
        probe.create_subscription(JointState, "/joint_states", lambda m: states.append(
            (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, np.array(m.position),
             np.array(m.velocity))), 1000)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(sim)
        executor.add_node(probe)
        log = tmp_path / "executor.log"
        proc = _start_executor_process(203, model, log, state_timeout_s="0.5")
        # Moving under the executor's commands (a bound on a failure, not on speed).
        end = time.monotonic() + 60.0
        while not (states and np.abs(states[-1][2]).max() > 0.05):
            assert time.monotonic() < end and proc.poll() is None, log.read_text()
            executor.spin_once(timeout_sec=0.01)
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=10.0) == -signal.SIGKILL
        killed = len(states)
        # Spin until the sim has published 30 states after the timeout expired.
        end = time.monotonic() + 30.0
        while True:
            last_ns = round(sim.sim._command_time * 1e9)
            after = [s for s in states if s[0] > last_ns + round(timeout_s * 1e9) + period_ns]
            if len(after) >= 30:
                break
            assert time.monotonic() < end, "no 30 states after the command timeout"
            executor.spin_once(timeout_sec=0.01)
        # No zero command came: the last one received still moves the robot...
        assert np.abs(sim.sim._command).max() > 0.05
        assert np.abs(states[killed - 1][2]).max() > 0.05
        # ...until command_timeout_s after it (plus one period for the tick): then still.
        for stamp, q, qdot in after:
            assert not np.any(qdot), (stamp - last_ns) / 1e9
            np.testing.assert_array_equal(q, after[0][1])
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_a_model_path_that_does_not_load_at_start_stops_the_node(tmp_path):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=202)
    try:
        # A ValueError of the executor's own (run_node prints it as one line), naming the
        # parameter and the file, not rclpy's parameter-set failure.
        with pytest.raises(ValueError, match="missing.npz") as err:
            Executor(context=context, parameter_overrides=[
                Parameter("joints", value=JOINTS),
                Parameter("model_path", value=str(tmp_path / "missing.npz"))])
        assert not isinstance(err.value, InvalidParameterValueException)
        assert str(err.value).startswith("model_path")
    finally:
        rclpy.try_shutdown(context=context)


def test_process_with_a_missing_model_file_exits_with_one_line_naming_it(node_process):
    done = node_process("executor", 127, "model_path:=nosuch.npz")
    assert done.returncode == 1 and "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, done.stderr
    # The parameter and the file, once; where a relative path was looked for; the other
    # way out (no model_path: wait for the learner's).
    assert "model_path" in errors[0] and errors[0].count("nosuch.npz") == 1
    assert os.getcwd() in errors[0] and "/learner/model" in errors[0]


def test_process_with_an_empty_joint_list_exits_with_status_1_and_a_reason(node_process):
    # rcl gives ``joints:=[]`` to rclpy as an unset parameter (None), not as an empty list.
    done = node_process("executor", 171, "joints:=[]")
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    assert "joints" in done.stderr  # names the parameter


def test_an_empty_constraint_list_at_start_is_no_constraint():
    # rcl gives ``constraints:=[]`` to rclpy as no value: the parameter stays unset.
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=222)
    try:
        node = Executor(context=context, parameter_overrides=[
            Parameter("joints", value=JOINTS), Parameter("constraints", value=None)])
        try:
            assert node.controller.step.constraints == []
            node.publish_diagnostics()  # reads the parameter too
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
