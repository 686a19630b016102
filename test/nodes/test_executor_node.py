"""Integration tests of the ``executor`` node (own rclpy.Context, domain ids 112, 150-159,
200-211, 219).

Assertions count control ticks and messages, never wall-clock speed: waits are "until a
condition holds, or fail after a generous timeout". The ramp, arming and staleness logic
itself is tested without a graph in test/control/.
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
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.duration import Duration
from rclpy.exceptions import InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.time import Time
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool

from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.nodes import executor as executor_module
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
        overrides = {"robot": "talos", "joints": JOINTS, "rate_hz": 1.0 / PERIOD,
                     "state_timeout_s": 0.5, "max_acceleration": ACC, "constraints": PLANE,
                     "controller": "", **params}
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

    def close(self) -> None:
        self.executor.shutdown()
        self.probe.destroy_node()
        if self.node is not None:
            self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def rig(request):
    made = []

    def make(domain_id, **params):
        made.append(Rig(domain_id, **params))
        return made[-1]

    yield make
    for r in made:
        r.close()


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


def test_enable_is_refused_without_a_model_and_with_stale_joint_states(rig):
    r = rig(150)
    response = r.enable(True)
    assert not response.success and "no model loaded" in response.message
    r.spin(0.2)
    assert r.commands == []  # disarmed: the topic is left alone
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin(0.1, publish_states=False)
    r.stamp = r.node.get_clock().now().to_msg()
    r.publish_state()  # one state, then nothing: stale after state_timeout_s
    r.spin(0.7, publish_states=False)
    response = r.enable(True)
    assert not response.success and "stale" in response.message
    r.stamp = None
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    assert r.enable(True).success
    r.spin_until(lambda: len(r.commands) >= 5, what="commands")


def test_commands_ramp_follow_the_policy_and_satisfy_the_constraint(rig):
    r = rig(151)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    assert r.enable(True).success
    r.spin_until(lambda: len(r.commands) >= 30, what="30 commands")
    # Every step, starting from zero at enable: the first command too.
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))
    assert np.max(np.abs(r.commands[0])) == pytest.approx(ACC * PERIOD)
    A = r.node.controller.step.constraint_matrix(r.q)
    assert A.shape == (1, len(JOINTS))
    for c in r.commands:
        assert np.abs(A @ c).max() < 1e-9 * max(1.0, np.linalg.norm(c))
        assert np.abs(c).max() <= 0.5 + 1e-12
    # The policy pulls back towards the neutral posture: a descent direction of the potential.
    assert float(r.commands[-1] @ (r.q - r.node.robot.neutral())) < 0


def test_stale_joint_states_stop_at_once_and_disarm(rig):
    r = rig(152, state_timeout_s=0.3)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "")
    assert r.enable(True).success
    r.spin_until(lambda: len(r.commands) >= 20 and np.max(np.abs(r.commands[-1])) > 0.1,
                 what="motion")
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False, what="disarm")
    r.spin(0.1, publish_states=False)
    # Straight to zero (no ramp without a trusted state), then silence.
    assert not np.any(r.commands[-1]) and np.max(np.abs(r.commands[-2])) > 0.1
    assert "stale" in r.node.controller.zero_reason
    count = len(r.commands)
    r.spin(0.3)  # fresh states again: it stays disarmed
    assert len(r.commands) == count and not r.node.controller.armed


def test_disable_ramps_down_to_zero_then_stays_silent(rig):
    r = rig(153)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "")
    assert r.enable(True).success
    r.spin_until(lambda: len(r.commands) >= 20, what="motion")
    assert np.any(r.commands[-1])
    response = r.enable(False)
    assert response.success and response.message.startswith("disabled")
    r.spin_until(lambda: not r.node.controller.publishing, what="ramp down")
    r.spin(0.1)
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))
    assert not np.any(r.commands[-1])
    count = len(r.commands)
    r.spin(0.3)
    assert len(r.commands) == count


def test_shutdown_sends_a_zero_command(rig):
    r = rig(154)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "")
    r.enable(True)
    r.spin_until(lambda: len(r.commands) >= 5 and np.any(r.commands[-1]), what="motion")
    r.executor.remove_node(r.node)
    r.node.destroy_node()
    r.node = None
    r.spin(0.2, publish_states=False)
    assert not np.any(r.commands[-1])


def test_bad_parameters_are_refused_with_a_reason(rig):
    r = rig(155)
    node = r.node
    result = node.set_parameters([Parameter("constraints", value="[{type: plane}]")])[0]
    assert not result.successful and "frame" in result.reason
    result = node.set_parameters([Parameter("constraints",
                                            value="[{type: joints, joints: 3}]")])[0]
    assert not result.successful and "joints: must be a non-empty list" in result.reason
    result = node.set_parameters([Parameter("constraints", value="[]")])[0]
    assert result.successful and node.controller.step.constraints == []
    for name, bad in (("max_velocity", -1.0), ("max_acceleration", 0.0),
                      ("max_acceleration", 1000.0), ("max_acceleration", float("nan")),
                      ("state_timeout_s", 0.0), ("max_clock_skew_s", -0.1)):
        result = node.set_parameters([Parameter(name, value=bad)])[0]
        assert not result.successful and result.reason, (name, bad)
    assert node.set_parameters([Parameter("max_velocity", value=0.2)])[0].successful
    assert np.max(node.controller.step.max_velocity) == 0.2
    assert node.set_parameters([Parameter("max_acceleration", value=3.0)])[0].successful
    assert node.controller.max_acceleration == 3.0
    assert node.set_parameters([Parameter("max_clock_skew_s", value=0.2)])[0].successful
    assert node.controller.max_clock_skew_s == pytest.approx(0.2)
    assert not node.set_parameters([Parameter("rate_hz", value=50.0)])[0].successful
    # Every numeric parameter documents its range.
    for desc in node.describe_parameters(["max_velocity", "max_acceleration",
                                          "state_timeout_s", "max_clock_skew_s", "rate_hz"]):
        assert desc.description and len(desc.floating_point_range) == 1, desc.name


def test_model_announced_on_learner_topic_is_loaded_and_checked(rig, tmp_path):
    r = rig(156)
    center = np.zeros(len(JOINTS))
    # Fitted first: a fit blocks this thread, and the joint states with it.
    good = _fit_model(tmp_path / "good.npz", JOINTS, center)
    wrong = _fit_model(tmp_path / "wrong.npz", [j.replace("left", "right") for j in JOINTS],
                       center)
    r.models.publish(String(data=str(good)))
    r.spin_until(lambda: r.node.model_path == str(good), what="model loaded")
    assert r.node.controller.step.policy is not None
    assert r.node.get_parameter("model_path").value == str(good)
    assert r.enable(True).success
    r.spin_until(lambda: r.commands and np.linalg.norm(r.commands[-1]) > 1e-6,
                 what="motion")
    r.models.publish(String(data=str(wrong)))
    r.spin(0.3)
    assert r.node.model_path == str(good)  # refused: trained on other joints
    assert r.node.get_parameter("model_path").value == str(good)
    assert r.node.controller.armed  # a refused model changes nothing


def _start_executor_process(domain_id: int, model, log: Path, **params):
    """The executor as its console script runs it (``main()``), armed at the first state."""
    code = "import sys; from policy_align_ros.nodes.executor import main; sys.exit(main())"
    args = []
    values = {"robot": "talos", "joints": "[" + ",".join(JOINTS) + "]",
              "model_path": str(model), "start_enabled": "true", "state_timeout_s": "1.0",
              **params}
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
        assert "armed: following the policy" in log.read_text()
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


def test_model_path_set_at_run_time_loads_the_model_or_is_refused(rig, tmp_path):
    r = rig(158)
    center = np.zeros(len(JOINTS))
    # Fitted first: a fit blocks this thread, and the joint states with it.
    other = _fit_model(tmp_path / "other.npz", JOINTS, center)
    result = r.node.set_parameters([Parameter("model_path", value=str(tmp_path / "no.npz"))])
    assert not result[0].successful and "no.npz" in result[0].reason
    assert r.node.controller.step.policy is None and r.node.model_path == ""
    wrong = _fit_model(tmp_path / "wrong.npz", [j.replace("left", "right") for j in JOINTS],
                       center)
    result = r.node.set_parameters([Parameter("model_path", value=str(wrong))])[0]
    assert not result.successful and "joints" in result.reason
    good = _fit_model(tmp_path / "good.npz", JOINTS, center)
    assert r.node.set_parameters([Parameter("model_path", value=str(good))])[0].successful
    assert r.node.model_path == str(good) and r.node.controller.step.policy is not None
    result = r.node.set_parameters([Parameter("model_path", value="")])[0]
    assert not result.successful and r.node.model_path == str(good)
    # A swap while armed ramps down and leaves the executor disarmed.
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "")
    assert r.enable(True).success
    r.spin_until(lambda: len(r.commands) >= 15, what="motion")
    assert r.node.set_parameters([Parameter("model_path", value=str(other))])[0].successful
    assert not r.node.controller.armed and "model swap" in r.node.controller.zero_reason
    r.spin_until(lambda: not r.node.controller.publishing, what="ramp down")
    r.spin(0.2)
    assert not np.any(r.commands[-1]) and not r.node.controller.armed
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))


def test_broken_or_badly_stamped_joint_states_stop_at_once_and_are_counted(rig):
    r = rig(159)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))

    def moving():
        r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "")
        assert r.enable(True).success
        r.spin_until(lambda: len(r.commands) >= 15 and np.max(np.abs(r.commands[-1])) > 0.04,
                     what="motion")

    # The same joint twice, the second with another value.
    moving()
    msg = JointState(name=[*JOINTS, JOINTS[0]], position=[*r.q.tolist(), 1.0])
    msg.header.stamp = r.node.get_clock().now().to_msg()
    r.states.publish(msg)
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False, what="disarm")
    r.spin(0.1, publish_states=False)
    assert not np.any(r.commands[-1]) and "duplicate_joints" in r.node.controller.zero_reason
    assert r.node.rejected_states["duplicate_joints"] == 1
    # NaN, then a stamp 10 s old, then a zero stamp: each one stops it.
    for bad, key in ((dict(position=[np.nan] * len(JOINTS)), "non_finite"),
                     (dict(stamp_age_s=10.0), "stamp_too_old"),
                     (dict(stamp_age_s=None), "zero_stamp")):
        moving()
        msg = JointState(name=JOINTS, position=bad.get("position", r.q.tolist()))
        if "stamp_age_s" not in bad:
            msg.header.stamp = r.node.get_clock().now().to_msg()
        elif bad["stamp_age_s"] is not None:
            msg.header.stamp = (r.node.get_clock().now()
                                - Duration(seconds=bad["stamp_age_s"])).to_msg()
        r.states.publish(msg)
        r.spin_until(lambda: not r.node.controller.armed, publish_states=False,
                     what=f"disarm on {key}")
        r.spin(0.1, publish_states=False)
        assert not np.any(r.commands[-1]), key
        assert r.node.rejected_states[key] == 1, r.node.rejected_states


def test_sim_time_drives_the_ticks_and_a_backwards_clock_disarms(rig):
    r = rig(200, use_sim_time=True)
    clock_pub = r.probe.create_publisher(Clock, "/clock", 10)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    sim_ns = 1000 * 1_000_000_000

    def advance(periods: int) -> None:
        """Step /clock by whole periods, one joint state each (stamped with sim time).

        While the executor publishes, each step waits for that period's command, so a
        slow machine delays the test instead of merging ticks.
        """
        nonlocal sim_ns
        for _ in range(periods):
            sim_ns += int(PERIOD * 1e9)
            stamp = Time(nanoseconds=sim_ns).to_msg()
            clock_pub.publish(Clock(clock=stamp))
            r.stamp = stamp
            r.spin_until(lambda t=sim_ns: r.node._now_ns() == t, publish_states=False,
                         what="the node clock to follow /clock")
            r.publish_state()
            count = len(r.commands)
            if r.node.controller.publishing:
                r.spin_until(lambda c=count: len(r.commands) > c, publish_states=False,
                             what="this period's command")
            else:
                for _ in range(3):
                    r.executor.spin_once(timeout_sec=0.002)

    advance(5)
    assert r.node._now_ns() == sim_ns  # the node clock is the simulation's
    assert r.enable(True).success
    r.commands.clear()
    advance(40)
    r.spin(0.2, publish_states=False)  # wall time passes, sim time does not: no ticks
    # One command per simulated period, and none while only wall time passed.
    assert len(r.commands) == 40
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))
    count = len(r.commands)
    sim_ns -= 5_000_000_000  # the simulation restarts: /clock jumps back 5 s
    advance(3)
    r.spin(0.1, publish_states=False)
    assert not r.node.controller.armed and "clock jumped back" in r.node.controller.zero_reason
    assert not np.any(r.commands[-1]) and len(r.commands) > count
    count = len(r.commands)
    advance(10)
    assert len(r.commands) == count  # stays disarmed


def test_diagnostics_report_arming_model_zero_reason_and_ramp(rig, tmp_path):
    good = _fit_model(tmp_path / "good.npz", JOINTS, np.zeros(len(JOINTS)))
    r = rig(201, model_path=str(good))

    def latest():
        status = r.diagnostics[-1].status[0]
        return status, {kv.key: kv.value for kv in status.values}

    r.spin_until(lambda: r.diagnostics, what="diagnostics")
    status, values = latest()
    assert values["armed"] == "false" and values["model"] == str(good)
    assert values["zero_reason"] == "not enabled yet" and "ramp_scale" in values
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "")
    assert r.enable(True).success
    r.spin_until(lambda: latest()[1]["armed"] == "true", what="armed diagnostics")
    status, values = latest()
    assert status.level == status.OK and values["zero_reason"] == ""
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False, what="stale")
    r.diagnostics.clear()
    r.spin_until(lambda: r.diagnostics, publish_states=False, what="diagnostics")
    status, values = latest()
    assert status.level == status.WARN and values["armed"] == "false"
    assert "stale" in values["zero_reason"] and "stale" in values["joint_states"]
    assert float(values["ramp_scale"]) == 1.0


def test_every_arming_change_is_reported_at_once(rig, monkeypatch):
    # The periodic status out of reach: every status seen here is an arming change's.
    monkeypatch.setattr(executor_module, "DIAGNOSTICS_PERIOD_S", 1e6)
    r = rig(112, state_timeout_s=0.3)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))

    def armed_flags():
        return [{kv.key: kv.value for kv in a.status[0].values}["armed"]
                for a in r.diagnostics]

    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    assert r.diagnostics == []
    assert r.enable(True).success
    r.spin_until(lambda: armed_flags() == ["true"], what="the arming's status")
    # A disarm by stale states, which no service call announces.
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False,
                 what="the stale-state disarm")
    r.spin_until(lambda: len(r.diagnostics) == 2, publish_states=False,
                 what="the disarm's status")
    values = {kv.key: kv.value for kv in r.diagnostics[-1].status[0].values}
    assert values["armed"] == "false" and "stale" in values["zero_reason"]
    assert r.diagnostics[-1].status[0].level == r.diagnostics[-1].status[0].WARN
    # Armed again and disabled: one status per change, none while nothing changes.
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states again")
    assert r.enable(True).success
    assert r.enable(False).success
    r.enable(False)  # already disarmed: no change, so no status
    r.spin(0.2)
    assert armed_flags() == ["true", "false", "true", "false"]


def test_a_model_path_that_does_not_load_at_start_stops_the_node(tmp_path):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=202)
    try:
        with pytest.raises(InvalidParameterValueException, match="missing.npz"):
            Executor(context=context, parameter_overrides=[
                Parameter("joints", value=JOINTS),
                Parameter("model_path", value=str(tmp_path / "missing.npz"))])
    finally:
        rclpy.try_shutdown(context=context)


def test_enable_checks_the_controllers_joint_order(rig):
    """~/enable reads the controller's ``joints`` (same single-threaded executor: no deadlock)."""
    r = rig(204, controller="/velocity_controller")
    controller = Node("velocity_controller", context=r.context)
    try:
        controller.declare_parameter("joints", JOINTS[::-1])
        r.executor.add_node(controller)
        r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
        r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                     what="fresh joint states")
        response = r.enable(True)
        assert not response.success and not r.node.controller.armed
        assert ("controller /velocity_controller orders the joints differently: command "
                "slot 0 is 'arm_left_7_joint' there and 'arm_left_1_joint' here"
                ) in response.message
        controller.set_parameters([Parameter("joints", value=[*JOINTS[:-1], "head_1_joint"])])
        response = r.enable(True)
        assert not response.success
        assert ("has other joints than the executor: not in the controller "
                "['arm_left_7_joint'], only in the controller ['head_1_joint']"
                ) in response.message
        r.spin(0.1)
        assert r.commands == []  # refused: nothing was ever published
        controller.set_parameters([Parameter("joints", value=JOINTS)])
        response = r.enable(True)
        assert response.success and "not checked" not in response.message, response.message
        r.spin_until(lambda: len(r.commands) >= 3, what="commands")
    finally:
        r.executor.remove_node(controller)
        controller.destroy_node()


def test_enable_without_an_answering_controller_arms_and_says_so(rig):
    r = rig(205)
    assert r.node.set_parameters([Parameter("controller", value="/velocity_controller")]
                                 )[0].successful
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    ticks = []
    r.node.create_timer(PERIOD, lambda: ticks.append(1))
    response = r.enable(True)
    assert response.success and r.node.controller.armed
    assert ("joint order of the command array not checked: /velocity_controller did not "
            "answer within 1 s") in response.message
    assert ticks  # the node kept running while it waited for the controller
    for bad in ("has space", "/trailing/", "1starts_with_digit"):
        result = r.node.set_parameters([Parameter("controller", value=bad)])[0]
        assert not result.successful and "controller: not a valid node name" in result.reason
    assert r.node.set_parameters([Parameter("controller", value="")])[0].successful
    response = r.enable(False)
    assert response.success
    response = r.enable(True)
    assert response.success and "not checked" not in response.message
    desc = r.node.describe_parameters(["controller"])[0]
    assert "joints parameter" in desc.description


HAND = "gripper_left_base_link"
_FRAMES: dict[str, object] = {}


def _frames_model():
    """A PolicyAlign model learnt on left-hand positions of task-space expert demos.

    Six demonstrations of a hand-space expert (``xdot = pi_x = -grad phi_x``, driven through
    the arm), mapped to hand states as ``policy-align learn --state frames:...`` does.
    Returns (model, state definition dict, target (3,), robot, state map).
    """
    from policy_align_ros.kinematics import LearningStateMap, Robot, TaskSpaceMap
    from policy_align_ros.sim.demonstrations import sample_start_states, task_space_rollout
    from policy_align_ros.sim.experts import TaskSpaceExpert

    if not _FRAMES:
        robot = Robot.load("talos", joints=JOINTS)
        smap = TaskSpaceMap(robot, [HAND])
        q0 = robot.neutral()
        target = smap.states(q0) + np.array([0.1, 0.05, 0.08])
        expert = TaskSpaceExpert(smap, target, 1.0)
        starts = sample_start_states(np.random.default_rng(0), q0, 6, 0.05, robot.lower,
                                     robot.upper)
        demos = [task_space_rollout(q, expert, None, 60, 0.05, name=f"demo_{k}")
                 for k, q in enumerate(starts)]
        learn_map = LearningStateMap(robot, [HAND])
        model = PolicyAlign().fit([learn_map(d.joints) for d in demos])
        _FRAMES.update(model=model, state=learn_map.definition(), target=target,
                       robot=robot, smap=smap)
    return (_FRAMES["model"], _FRAMES["state"], _FRAMES["target"], _FRAMES["robot"],
            _FRAMES["smap"])


def _save_frames_model(path: Path, state: dict) -> Path:
    model = _frames_model()[0]
    model.state_definition_ = state
    try:
        model.save(path)
    finally:
        model.state_definition_ = _FRAMES["state"]
    return path


def test_frames_model_moves_the_hand_along_the_projected_policy(rig, tmp_path):
    """A model learnt on hand positions drives the arm through J under A(q)."""
    from policy_align_ros.control import policy_for_state
    from policy_align_ros.kinematics import constraint_from_spec

    model, state, target, robot, smap = _frames_model()
    path = _save_frames_model(tmp_path / "hand.npz", state)
    plane = f"[{{type: plane, frame: {HAND}, normal: [0, 0, 1]}}]"
    r = rig(206, model_path=str(path), constraints=plane)
    assert r.node.model_state == f"frames {HAND}"
    # Phase 1, the robot held still: after the ramp the command is the task-space map
    # of the learnt pi_x under the hand plane, scaled by the speed limit only.
    r.q = robot.clip(robot.neutral() + np.array([0.1, 0.15, -0.1, 0.2, 0.0, 0.1, 0.0]))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "")
    assert r.enable(True).success
    r.spin_until(lambda: len(r.commands) >= 3 and np.array_equal(r.commands[-1],
                                                                 r.commands[-2]),
                 what="a steady command")
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))
    c = r.commands[-1]
    A = constraint_from_spec({"type": "plane", "frame": HAND, "normal": [0, 0, 1]},
                             robot).matrix(r.q)
    assert np.abs(A @ c).max() < 1e-9  # A(q) qdot = 0
    x, J = smap.kinematics(r.q)
    pi_x = model.policy(x[None])[0]
    N_x = np.diag([1.0, 1.0, 0.0])
    xdot = J @ c  # the hand's velocity to first order
    s = float(xdot @ (N_x @ pi_x)) / float(np.linalg.norm(N_x @ pi_x)) ** 2
    assert 0.05 < s <= 1.0 + 1e-9
    np.testing.assert_allclose(xdot, s * N_x @ pi_x, atol=1e-9)
    expect = policy_for_state(model, state, robot, r.node._constraint_matrix).command(r.q)
    np.testing.assert_allclose(c, s * expect, atol=1e-9)
    # Phase 2, closed loop: the arm integrates each command; the hand slides in its
    # plane towards the target's projection.
    start = x.copy()
    count = len(r.commands)
    for _ in range(300):
        r.spin_until(lambda n=count: len(r.commands) > n, what="the next command")
        count = len(r.commands)
        r.q = robot.clip(r.q + PERIOD * r.commands[-1])
    end = smap.states(r.q)
    # Held in its plane: exact to first order per step; 300 Euler steps of the arm
    # drift at second order.
    assert abs(end[2] - start[2]) < 2e-3
    before = np.linalg.norm((start - target)[:2])
    assert np.linalg.norm((end - target)[:2]) < 0.3 * before, (before, end - target)


def test_frames_model_of_another_robot_or_frame_set_is_refused(rig, tmp_path):
    from policy_align_ros.kinematics import FrameStateDefinition, Robot

    _, state, _, _, _ = _frames_model()
    good = _save_frames_model(tmp_path / "hand.npz", state)
    panda = FrameStateDefinition.from_robot(Robot.load("panda"), ["panda_hand"]).to_dict()
    other_robot = _save_frames_model(tmp_path / "panda.npz", panda)
    two = _save_frames_model(tmp_path / "two.npz",
                             {**state, "frames": [HAND, "arm_left_4_link"]})
    unknown = _save_frames_model(tmp_path / "kind.npz", {**state, "type": "poses"})
    r = rig(207, model_path=str(good))
    result = r.node.set_parameters([Parameter("model_path", value=str(other_robot))])[0]
    assert not result.successful
    assert "panda.npz: state definition does not match the robot: URDF differs" in result.reason
    result = r.node.set_parameters([Parameter("model_path", value=str(two))])[0]
    assert not result.successful
    assert ("policy: learnt on 3-D states, the state map gives 6-D states (2 frames)"
            in result.reason)
    result = r.node.set_parameters([Parameter("model_path", value=str(unknown))])[0]
    assert not result.successful and "state definition of type 'poses'" in result.reason
    # Announced by the learner: refused with the reason, the loaded model stays.
    r.models.publish(String(data=str(other_robot)))
    r.spin(0.3)
    assert r.node.model_path == str(good) and r.node.model_state == f"frames {HAND}"


def test_start_enabled_goes_through_the_controller_check(rig, tmp_path):
    good = _fit_model(tmp_path / "good.npz", JOINTS, np.zeros(len(JOINTS)))
    r = rig(208, model_path=str(good), start_enabled=True, controller="/velocity_controller")
    controller = Node("velocity_controller", context=r.context)
    try:
        controller.declare_parameter("joints", JOINTS[::-1])
        r.executor.add_node(controller)
        calls = []
        check = r.node._check_controller

        async def counted(client):
            calls.append(await check(client))
            return calls[-1]

        r.node._check_controller = counted
        r.spin_until(lambda: calls, what="the controller check at start")
        r.spin(0.3)
        assert "orders the joints differently" in calls[0][0]
        assert not r.node.controller.armed and r.commands == []
    finally:
        r.executor.remove_node(controller)
        controller.destroy_node()


def test_frame_support_distance_measures_the_hand_state_and_its_gradient():
    """The guard's distance for a frames model: in hand space, gradient through J."""
    from policy_align_ros.control import FrameSupportDistance

    model, _, _, robot, smap = _frames_model()
    distance = FrameSupportDistance(model, smap)
    q = robot.clip(robot.neutral() + np.array([0.4, 0.3, -0.3, 0.5, 0.2, 0.3, 0.1]))
    d, grad = distance(q)
    x = smap.states(q)
    expect, nearest = model.support_query(x[None])
    assert d == pytest.approx(expect[0]) and d > 2.0  # the hand is off the data
    assert d == pytest.approx(np.linalg.norm(x - nearest[0]) / model.support_spacing_)
    h = 1e-6
    fd = [(distance(q + h * e)[0] - distance(q - h * e)[0]) / (2 * h) for e in np.eye(q.size)]
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-6 * np.abs(grad).max())


def test_extrapolation_guard_of_a_frames_model_measures_in_hand_space(rig, tmp_path):
    """The guard scales hand motion leading away from the demonstrated hand states."""
    from policy_align_ros.control import FrameSupportDistance

    model, state, _, robot, smap = _frames_model()
    path = _save_frames_model(tmp_path / "hand.npz", state)
    q = robot.clip(robot.neutral() + np.array([0.4, 0.3, -0.3, 0.5, 0.2, 0.3, 0.1]))
    x = smap.states(q)
    d, nearest = model.support_query(x[None])
    u = (x - nearest[0]) / np.linalg.norm(x - nearest[0])  # outwards, in hand space
    p = model.policy(x[None])[0]
    a = float(p @ u)
    assert a < 0.0  # the learnt policy leads back to the data...
    w = (p - a * u) / np.linalg.norm(p - a * u)
    b = float(p @ w)
    # ...so hold the hand on a plane that turns it outwards: with n = cos(t) u + sin(t) w
    # and t = pi - delta, N_x p . u = sin(delta) (a sin(delta) + b cos(delta)) > 0.
    delta = 0.5 * np.arctan2(b, -a)
    n = -np.cos(delta) * u + np.sin(delta) * w
    plane = f"[{{type: plane, frame: {HAND}, normal: {n.tolist()}}}]"
    r = rig(209, model_path=str(path), constraints=plane, max_extrapolation=1000.0)
    r.q = q
    guard = r.node.controller.step.guard
    assert isinstance(guard.distance, FrameSupportDistance)
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "")
    assert r.enable(True).success

    def steady():
        r.spin_until(lambda: len(r.commands) >= 3 and np.array_equal(r.commands[-1],
                                                                     r.commands[-2]),
                     what="a steady command")
        return r.commands[-1]

    free = steady()
    d_q, grad = FrameSupportDistance(model, smap)(q)
    assert d_q == pytest.approx(d[0]) and float(grad @ free) > 0.0  # leads further out
    assert r.node.controller.extrapolation_scale == 1.0
    assert r.node.controller.step.extrapolation_distance == pytest.approx(d[0])
    # One spacing beyond max_extrapolation: scaled by 1 - 1 / band < 1, same direction.
    assert r.node.set_parameters([Parameter("max_extrapolation", value=d[0] - 1.0)]
                                 )[0].successful
    count = len(r.commands)
    r.spin_until(lambda: len(r.commands) > count + 2, what="commands after the change")
    scaled = steady()
    g = r.node.controller.extrapolation_scale
    assert 0.0 < g < 1.0
    np.testing.assert_allclose(scaled, g * free, atol=1e-9)
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))


def _enable_waiting_for_an_absent_controller(r: Rig):
    """An ~/enable request that is waiting (up to 1 s) for /absent_controller's answer."""
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    assert r.enable_client.wait_for_service(timeout_sec=5.0)
    enable = r.enable_client.call_async(SetBool.Request(data=True))
    r.spin(0.2)
    assert not enable.done()
    return enable


def test_a_disable_while_enable_waits_for_the_controller_wins(rig):
    r = rig(210, controller="/absent_controller")
    enable = _enable_waiting_for_an_absent_controller(r)
    disable = r.enable_client.call_async(SetBool.Request(data=False))
    r.spin_until(lambda: enable.done() and disable.done(), what="both answers")
    assert disable.result().success
    assert not enable.result().success
    assert "superseded by a later ~/enable request" in enable.result().message
    r.spin(0.2)
    assert not r.node.controller.armed and r.commands == []


def test_a_controller_changed_while_enable_waits_for_it_refuses_the_enable(rig):
    # Setting ``controller`` must not destroy the client that the pending enable polls:
    # the old client lives until the check ends, and the enable is refused (the new
    # controller's joint order was never compared).
    r = rig(219, controller="/absent_controller")
    enable = _enable_waiting_for_an_absent_controller(r)
    assert r.node.set_parameters([Parameter("controller", value="/other_controller")]
                                 )[0].successful
    r.spin_until(enable.done, what="the ~/enable answer")
    assert not enable.result().success
    assert "the controller changed while it was checked" in enable.result().message
    r.spin(0.2)
    assert not r.node.controller.armed and r.commands == []
    assert r.node._retired_clients == []  # the old client is gone once the check ended


def test_lockstep_steps_once_per_joint_state_and_still_stops_on_stale_states(rig):
    r = rig(211, step_on_joint_state=True)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    assert r.enable(True).success
    r.spin(0.05, publish_states=False)
    r.commands.clear()
    for i in range(20):
        r.publish_state()
        r.spin_until(lambda i=i: len(r.commands) >= i + 1, publish_states=False,
                     what=f"command {i + 1}")
    # While the states are fresh the timer adds no step of its own: one command per state.
    r.spin(0.2, publish_states=False)
    assert len(r.commands) == 20
    _assert_ramped(r.commands)
    assert np.max(np.abs(r.commands[-1])) > 0.0
    # States that stop coming still stop the robot at once (the timer's job in lockstep).
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False,
                 what="the stale-state disarm")
    r.spin(0.05, publish_states=False)
    assert np.all(r.commands[-1] == 0.0)


def test_process_with_an_empty_joint_list_exits_with_status_1_and_a_reason(node_process):
    # rcl gives ``joints:=[]`` to rclpy as an unset parameter (None), not as an empty list.
    done = node_process("executor", 171, "joints:=[]")
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    assert "joints: must be a non-empty list" in done.stderr
