"""Integration tests of the ``sim_robot`` node (own rclpy.Context, domain ids 170-179 and
223)."""

import contextlib
import time

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from policy_align_ros.kinematics.robot import robots_dir
from policy_align_ros.nodes.sim_robot import SimRobot

JOINTS = ["arm_left_1_joint", "arm_left_2_joint", "arm_left_4_joint"]
START = [0.1, 0.4, -0.5]


@pytest.fixture
def rig():
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=170)
    nodes = []
    try:
        sim = SimRobot(context=context, parameter_overrides=[
            Parameter("robot", value="talos"), Parameter("joints", value=JOINTS),
            Parameter("initial_positions", value=START), Parameter("rate_hz", value=100.0),
            Parameter("command_timeout_s", value=0.1)])
        probe = Node("probe", context=context)
        nodes += [sim, probe]
        states: list[JointState] = []
        probe.create_subscription(JointState, "/joint_states", states.append, 100)
        commands = probe.create_publisher(Float64MultiArray, "/velocity_controller/commands", 10)
        reset = probe.create_client(Trigger, "/sim_robot/reset")
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(sim)
        executor.add_node(probe)

        def spin(seconds, command=None):
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                if command is not None:
                    commands.publish(Float64MultiArray(data=list(command)))
                executor.spin_once(timeout_sec=0.005)

        yield sim, states, spin, reset, executor
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_publishes_stamped_joint_states_at_the_start_position(rig):
    sim, states, spin, _, _ = rig
    spin(0.3)
    assert len(states) >= 15  # 100 Hz nominal; generous for a loaded machine
    msg = states[-1]
    assert list(msg.name) == JOINTS
    np.testing.assert_allclose(msg.position, START)
    assert msg.header.stamp.sec > 0


def test_integrates_commands_then_holds_still_when_they_stop(rig):
    sim, states, spin, _, _ = rig
    spin(0.5, command=[0.2, 0.0, -0.1])
    moved = np.array(states[-1].position) - START
    # 0.1 and -0.05 nominally; timer jitter on a loaded machine only loses motion.
    assert 0.03 < moved[0] < 0.11 and moved[1] == 0.0 and -0.055 < moved[2] < -0.015
    spin(0.2)  # no more commands: stale after 0.1 s
    held = np.array(states[-1].position)
    spin(0.2)
    np.testing.assert_array_equal(states[-1].position, held)
    np.testing.assert_array_equal(states[-1].velocity, 0.0)


def test_stays_within_joint_limits(rig):
    sim, states, spin, _, _ = rig
    spin(0.5, command=[5.0, 5.0, 5.0])
    q = np.array(states[-1].position)
    assert np.all(q <= sim.robot.upper) and np.any(q == sim.robot.upper)


def test_ignores_commands_of_the_wrong_length(rig):
    sim, states, spin, _, _ = rig
    spin(0.3, command=[1.0, 1.0])
    np.testing.assert_allclose(states[-1].position, START)
    assert sim._bad_commands > 0


def test_reset_returns_to_the_initial_positions(rig):
    sim, states, spin, reset, executor = rig
    spin(0.3, command=[0.3, 0.3, 0.3])
    assert not np.allclose(states[-1].position, START)
    spin(0.2)
    assert reset.wait_for_service(timeout_sec=5.0)
    future = reset.call_async(Trigger.Request())
    executor.spin_until_future_complete(future, timeout_sec=5.0)
    assert future.result().success
    spin(0.1)
    np.testing.assert_allclose(states[-1].position, START)


def test_bad_initial_positions_are_refused(rig):
    sim = rig[0]
    result = sim.set_parameters([Parameter("initial_positions", value=[0.0, 1.0])])[0]
    assert not result.successful and "initial_positions" in result.reason
    kept = sim.get_parameter("initial_positions").value
    assert kept is None or len(kept) == 3  # the refused value was not taken


def test_process_with_an_unknown_robot_exits_with_status_1_and_a_reason(node_process):
    done = node_process("sim_robot", 175, "robot:=talso")
    assert done.returncode == 1
    assert "Traceback" not in done.stderr and "talso" in done.stderr  # names the value


def test_process_with_an_empty_joint_list_exits_with_status_1_and_a_reason(node_process):
    # rcl gives ``joints:=[]`` to rclpy as an unset parameter (None), not as an empty list.
    done = node_process("sim_robot", 176, "joints:=[]")
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    assert "joints" in done.stderr  # names the parameter


def test_command_timeout_can_be_changed_at_run_time(rig):
    sim = rig[0]
    assert sim.set_parameters([Parameter("command_timeout_s", value=0.5)])[0].successful
    assert sim.sim.command_timeout_s == 0.5
    assert not sim.set_parameters([Parameter("command_timeout_s", value=0.0)])[0].successful
    assert sim.sim.command_timeout_s == 0.5


@contextlib.contextmanager
def _sim_on_its_own_clock(domain_id: int, **probe_parameters):
    """``sim_robot`` publishing ``/clock`` at 5x, and a probe node collecting its joint
    states: yields ``(probe, executor, states)``; nothing spins until the test does."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    nodes = []
    try:
        sim = SimRobot(context=context, parameter_overrides=[
            Parameter("joints", value=JOINTS), Parameter("initial_positions", value=START),
            Parameter("rate_hz", value=100.0), Parameter("publish_clock", value=True),
            Parameter("real_time_factor", value=5.0)])
        probe = Node("probe", context=context, parameter_overrides=[
            Parameter(name, value=value) for name, value in probe_parameters.items()])
        nodes += [sim, probe]
        states: list[JointState] = []
        probe.create_subscription(JointState, "/joint_states", states.append, 1000)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(sim)
        executor.add_node(probe)
        yield probe, executor, states
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_publishes_its_clock_one_period_per_tick_and_stamps_states_with_it():
    from rosgraph_msgs.msg import Clock

    from policy_align_ros.nodes.sim_robot import SIM_CLOCK_START_NS

    with _sim_on_its_own_clock(178, use_sim_time=True) as (probe, executor, states):
        clocks = []
        probe.create_subscription(Clock, "/clock", clocks.append, 1000)
        while len(clocks) < 30:  # count ticks, not wall time
            executor.spin_once(timeout_sec=0.05)
        now = probe.get_clock().now().nanoseconds
        # The probe's clock and this subscription take each /clock message separately:
        # let the subscription catch up with the tick the clock reads.
        while _ns(clocks[-1].clock) < now:
            executor.spin_once(timeout_sec=0.05)
        ns = [_ns(c.clock) for c in clocks]
        assert ns[0] > SIM_CLOCK_START_NS
        assert set(np.diff(ns)) == {10_000_000}  # exactly one period per tick
        stamps = {_ns(s.header.stamp) for s in states}
        assert stamps <= set(ns)
        # A node on sim time reads the simulated clock: one of its ticks.
        assert now > SIM_CLOCK_START_NS and now in set(ns)


def _ns(stamp) -> int:
    return stamp.sec * 10**9 + stamp.nanosec


def test_reset_on_its_own_clock_never_repeats_a_stamp():
    with _sim_on_its_own_clock(172) as (probe, executor, states):
        reset = probe.create_client(Trigger, "/sim_robot/reset")
        while len(states) < 10:
            executor.spin_once(timeout_sec=0.05)
        assert reset.wait_for_service(timeout_sec=5.0)
        future = reset.call_async(Trigger.Request())
        executor.spin_until_future_complete(future, timeout_sec=5.0)
        assert future.result().success
        count = len(states)
        while len(states) < count + 5:
            executor.spin_once(timeout_sec=0.05)
        stamps = [s.header.stamp.sec * 10**9 + s.header.stamp.nanosec for s in states]
        assert np.all(np.diff(stamps) > 0)
        np.testing.assert_allclose(states[-1].position, START)


def test_wrap_continuous_publishes_continuous_joints_on_one_turn():
    # Kinova's Jaco: joints 1 and 4 are continuous, joint 2 a revolute with limits.
    urdf = robots_dir() / "kinova_description" / "robots" / "kinova.urdf"
    joints = ["j2s6s200_joint_1", "j2s6s200_joint_2", "j2s6s200_joint_4"]
    start = [np.pi - 0.02 + 2 * np.pi, 2.0, -4.0]  # joint 1 just short of 3 pi
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=223)
    nodes = []
    try:
        sim = SimRobot(context=context, parameter_overrides=[
            Parameter("robot", value=str(urdf)), Parameter("joints", value=joints),
            Parameter("initial_positions", value=start), Parameter("rate_hz", value=100.0),
            Parameter("wrap_continuous", value=True)])
        probe = Node("probe", context=context)
        nodes += [sim, probe]
        states: list[JointState] = []
        probe.create_subscription(JointState, "/joint_states", states.append, 1000)
        commands = probe.create_publisher(Float64MultiArray, "/velocity_controller/commands", 10)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(sim)
        executor.add_node(probe)
        deadline = time.monotonic() + 20.0
        while not states and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert states
        np.testing.assert_allclose(states[0].position,
                                   [np.pi - 0.02, 2.0, -4.0 + 2 * np.pi], atol=1e-12)
        # Turn joint 1 on across +pi (a generous bound: a loaded machine only slows it).
        deadline = time.monotonic() + 20.0
        while states[-1].position[0] > 0.0 and time.monotonic() < deadline:
            commands.publish(Float64MultiArray(data=[0.5, 0.0, 0.0]))
            executor.spin_once(timeout_sec=0.005)
        positions = np.array([s.position for s in states])
        assert np.all(positions[:, [0, 2]] >= -np.pi) and np.all(positions[:, [0, 2]] < np.pi)
        assert positions[-1, 0] < 0.0  # came round to -pi + a little
        # Wrapped in what is published only: the integration went on past 3 pi, at the
        # commanded speed.
        assert sim.sim.q[0] > 3 * np.pi
        assert max(s.velocity[0] for s in states) == pytest.approx(0.5)
        np.testing.assert_allclose(positions[:, 1], 2.0)
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
