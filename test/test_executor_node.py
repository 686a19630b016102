"""Integration tests of the ``executor`` node (own rclpy.Context, domain ids 150-159)."""

import time

import numpy as np
import pytest
import rclpy
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


class Rig:
    """An executor plus a probe node that fakes the robot and listens to the commands."""

    def __init__(self, domain_id: int, **params):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        overrides = {"robot": "talos", "joints": JOINTS, "rate_hz": 100.0,
                     "state_timeout_s": 0.1, "constraints": PLANE, **params}
        self.node = Executor(context=self.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in overrides.items()])
        self.probe = Node("probe", context=self.context)
        self.commands: list[np.ndarray] = []
        self.probe.create_subscription(
            Float64MultiArray, "/velocity_controller/commands",
            lambda m: self.commands.append(np.array(m.data)), 100)
        self.states = self.probe.create_publisher(JointState, "/joint_states", 10)
        self.models = self.probe.create_publisher(String, "/learner/model", LATCHED_QOS)
        self.enable_client = self.probe.create_client(SetBool, "/executor/enable")
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self.q = self.node.robot.neutral() + 0.2

    def spin(self, seconds: float, publish_states: bool = True) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if publish_states:
                msg = JointState(name=JOINTS, position=self.q.tolist())
                self.states.publish(msg)
            self.executor.spin_once(timeout_sec=0.005)

    def enable(self, on: bool) -> SetBool.Response:
        assert self.enable_client.wait_for_service(timeout_sec=5.0)
        future = self.enable_client.call_async(SetBool.Request(data=on))
        self.executor.spin_until_future_complete(future, timeout_sec=5.0)
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


def test_no_model_gives_zero_commands(rig):
    r = rig(150)
    assert "no model" in r.enable(True).message
    r.spin(0.3)
    assert len(r.commands) >= 10
    assert all(not np.any(c) for c in r.commands)


def test_commands_follow_the_policy_and_satisfy_the_constraint(rig):
    r = rig(151)
    r.node.control.policy = _attractor_policy(r.node.robot.neutral())
    r.enable(True)
    r.spin(0.3)
    moving = [c for c in r.commands if np.linalg.norm(c) > 1e-6]
    assert len(moving) >= 10
    A = r.node.control.constraint_matrix(r.q)
    assert A.shape == (1, len(JOINTS))
    for c in moving:
        assert np.abs(A @ c).max() < 1e-9 * max(1.0, np.linalg.norm(c))
        assert np.abs(c).max() <= 0.5 + 1e-12
    # The policy pulls back towards the neutral posture: a descent direction of the potential.
    assert float(moving[-1] @ (r.q - r.node.robot.neutral())) < 0


def test_stale_joint_states_give_zero_commands(rig):
    r = rig(152)
    r.node.control.policy = _attractor_policy(r.node.robot.neutral())
    r.enable(True)
    r.spin(0.2)
    assert np.any(r.commands[-1])
    r.commands.clear()
    r.spin(0.4, publish_states=False)  # nothing new for 0.4 s > state_timeout_s
    assert len(r.commands) >= 10 and not np.any(r.commands[-1])


def test_disable_sends_one_zero_command_then_stays_silent(rig):
    r = rig(153)
    r.node.control.policy = _attractor_policy(r.node.robot.neutral())
    r.enable(True)
    r.spin(0.2)
    assert np.any(r.commands[-1])
    assert r.enable(False).success
    r.spin(0.1)
    assert not np.any(r.commands[-1])
    r.commands.clear()
    r.spin(0.3)
    assert r.commands == []


def test_shutdown_sends_a_zero_command(rig):
    r = rig(154)
    r.node.control.policy = _attractor_policy(r.node.robot.neutral())
    r.enable(True)
    r.spin(0.2)
    assert np.any(r.commands[-1])
    r.executor.remove_node(r.node)
    r.node.destroy_node()
    r.node = None
    r.spin(0.2, publish_states=False)
    assert not np.any(r.commands[-1])


def test_bad_constraints_parameter_is_refused_with_a_reason(rig):
    r = rig(155)
    result = r.node.set_parameters([Parameter("constraints", value="[{type: plane}]")])[0]
    assert not result.successful and "frame" in result.reason
    result = r.node.set_parameters([Parameter("constraints", value="[]")])[0]
    assert result.successful and r.node.control.constraints == []
    result = r.node.set_parameters([Parameter("max_velocity", value=-1.0)])[0]
    assert not result.successful
    assert r.node.set_parameters([Parameter("max_velocity", value=0.2)])[0].successful
    assert np.max(r.node.control.max_velocity) == 0.2


def _fit_model(path, joints, center):
    rng = np.random.default_rng(0)
    trajs = []
    for _ in range(8):
        q = center + rng.normal(scale=0.3, size=len(joints))
        t = np.arange(40) * 0.05
        trajs.append(center + (q - center) * np.exp(-t)[:, None])
    model = PolicyAlign(sigma="medium").fit(
        [Trajectory(x, t) for x in trajs], joint_names=joints)
    model.save(path)
    return path


def test_model_announced_on_learner_topic_is_loaded_and_checked(rig, tmp_path):
    r = rig(156)
    center = r.node.robot.neutral()
    good = _fit_model(tmp_path / "good.npz", JOINTS, center)
    r.models.publish(String(data=str(good)))
    r.spin(0.3)
    assert r.node.model_path == str(good) and r.node.control.policy is not None
    r.enable(True)
    r.spin(0.3)
    assert np.linalg.norm(r.commands[-1]) > 1e-6
    wrong = _fit_model(tmp_path / "wrong.npz", [j.replace("left", "right") for j in JOINTS],
                       center)
    r.models.publish(String(data=str(wrong)))
    r.spin(0.3)
    assert r.node.model_path == str(good)  # refused: trained on other joints


def test_sigint_to_the_executor_process_leaves_a_zero_command(tmp_path):
    """The installed-style process (``main()``) stops the robot when interrupted."""
    import os
    import signal
    import subprocess
    import sys

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
        code = "import sys; from policy_align_ros.nodes.executor import main; sys.exit(main())"
        params = []
        for k, v in (("robot", "talos"), ("joints", "[" + ",".join(JOINTS) + "]"),
                     ("model_path", str(model)), ("start_enabled", "true")):
            params += ["-p", f"{k}:={v}"]
        log = tmp_path / "executor.log"
        with open(log, "wb") as out:
            proc = subprocess.Popen([sys.executable, "-c", code, "--ros-args", *params],
                                    env=dict(os.environ, ROS_DOMAIN_ID="157"), stdout=out,
                                    stderr=subprocess.STDOUT)
        q = np.full(len(JOINTS), 0.3)
        end = time.monotonic() + 30.0
        while not (commands and np.any(commands[-1])) and time.monotonic() < end:
            states.publish(JointState(name=JOINTS, position=q.tolist()))
            executor.spin_once(timeout_sec=0.01)
        assert commands and np.any(commands[-1]), log.read_text()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10.0) == 0, log.read_text()
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.01)
        assert not np.any(commands[-1]), log.read_text()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        probe.destroy_node()
        rclpy.try_shutdown(context=context)
