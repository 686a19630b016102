"""Integration tests of the ``demonstrator`` node (own rclpy.Context, domain ids 100, 180-189,
216).

The robot is the real ``sim_robot`` node (left arm of Talos); the recorder is faked by
Trigger services on a probe node, which also records the joint states in between.
"""


import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from log_rig import logged
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from policy_align_ros.kinematics import TaskSpaceMap
from policy_align_ros.kinematics.robot_config import load_robot_config
from policy_align_ros.nodes.demonstrator import Demonstrator
from policy_align_ros.nodes.sim_robot import SimRobot
from policy_align_ros.nodes.start_parameters import Cause, StartParameterError

JOINTS = [f"arm_left_{i}_joint" for i in range(1, 8)]
PARAMETER_FILE = Path(__file__).resolve().parents[2] / "config" / "demonstrator.yaml"
#: The module's domain for the start-up tests (nodes built, never spun).
START_DOMAIN = 216
HAND = "arm_left_7_link"


def _run(domain_id, refuse_start=False, num_demos=2, plane_switches=0, duration=0.6,
         extra=(), topic="/joint_states"):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    nodes = []
    try:
        common = [Parameter("robot", value="talos"), Parameter("joints", value=JOINTS),
                  Parameter("rate_hz", value=100.0)]
        # Both remapped as a user would remap the robot's topic (none by default).
        remap = ["--ros-args", "-r", f"/joint_states:={topic}"]
        sim = SimRobot(context=context, parameter_overrides=common, cli_args=remap)
        demo = Demonstrator(context=context, cli_args=remap, parameter_overrides=common + [
            Parameter("num_demos", value=num_demos),
            Parameter("demo_duration_s", value=duration),
            Parameter("plane_switches", value=plane_switches),
            Parameter("constraint_frames", value=[HAND]), Parameter("seed", value=3),
            Parameter("service_timeout_s", value=5.0), *extra])
        probe = Node("recorder", context=context)
        nodes += [sim, demo, probe]
        events, segments, stamps = [], [], []

        def start(request, response):
            events.append("start")
            segments.append([])
            stamps.append([])
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
                stamps[-1].append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)

        probe.create_service(Trigger, "~/start_demo", start)
        probe.create_service(Trigger, "~/stop_demo", stop)
        probe.create_subscription(JointState, topic, state, 100)
        executor = SingleThreadedExecutor(context=context)
        for node in nodes:
            executor.add_node(node)
        executor.spin_until_future_complete(demo.done, timeout_sec=30.0)
        return demo, sim, events, segments, stamps
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_demonstrations_are_bracketed_and_keep_the_hand_on_a_plane():
    demo, sim, events, segments, _ = _run(180)
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
    demo, sim, events, segments, stamps = _run(182, num_demos=1, plane_switches=2,
                                                duration=1.5)
    assert demo.done.result() == 0 and events == ["start", "stop"]
    hand = np.array([sim.robot.frame_position(q, HAND) for q in segments[0]])
    # The planes switch at thirds of the demonstration's time, not of its sample count
    # (a loaded machine delivers fewer states in some thirds than in others).
    t = np.asarray(stamps[0]) - stamps[0][0]
    third = np.minimum((t / 0.5).astype(int), 2)
    # Each third (trimmed at the switches) lies on its own plane; the whole does not.
    assert all(_planarity(hand[third == k][5:-5]) < 1e-2 for k in range(3))
    assert _planarity(hand) > 3e-2


def test_a_remapped_joint_state_topic_is_the_one_the_recorder_must_listen_on():
    # The robot's states on /arm/joint_states, the demonstrator and the recorder remapped
    # to it: the demonstrator waits for the recorder on that topic, not on /joint_states.
    demo, _, events, segments, _ = _run(100, num_demos=1, topic="/arm/joint_states")
    assert demo.done.result() == 0 and events == ["start", "stop"]
    assert len(segments[0]) > 10


def test_refused_start_ends_with_status_1():
    demo, _, events, _, _ = _run(181, refuse_start=True)
    assert demo.done.result() == 1 and events == ["start"]


def test_hands_expert_in_lockstep_moves_the_hand_to_its_target_within_planes():
    # Hand-space expert, one step per joint state: the hand heads for its target along
    # pi_x = -gain (x - x_c) projected on the current plane, exactly per simulator tick.
    demo, sim, events, segments, _ = _run(
        183, num_demos=1, plane_switches=0, duration=1.0,
        extra=[Parameter("expert", value="hands"), Parameter("hand_frames", value=[HAND]),
               Parameter("step_on_joint_state", value=True),
               Parameter("startup_delay_s", value=0.2)])
    assert demo.done.result() == 0 and events == ["start", "stop"]
    smap = TaskSpaceMap(sim.robot, [HAND])
    target = smap.states(demo.attractor)  # hand_targets unset: the hand at the attractor
    hand = smap.states(np.array(segments[0]))
    moving = np.linalg.norm(np.diff(hand, axis=0), axis=1) > 1e-6
    assert moving.sum() >= 30  # one motion step per simulator tick (100 Hz, 1 s)
    assert _planarity(hand[1:]) < 1e-2  # on the plane drawn for this demonstration
    # Within the plane the hand approaches the target (projected gradient flow).
    dist = np.linalg.norm(hand - target, axis=1)
    assert dist[-1] < dist[1]
    # Late ticks depend on the machine's load, so they are counted, not asserted on.
    assert demo.hand_expert is not None and demo.demo_ticks > 0
    assert 0 <= demo.late_ticks <= demo.demo_ticks


def test_bad_expert_is_refused_at_start():
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=184)
    try:
        # The parameter callback refuses the value while it is declared, with the reason.
        with pytest.raises(StartParameterError, match="expert") as err:
            Demonstrator(context=context, parameter_overrides=[
                Parameter("robot", value="talos"), Parameter("joints", value=JOINTS),
                Parameter("expert", value="elbows")])
        assert err.value.problem.cause == Cause.REFUSED and err.value.problem.reason
    finally:
        rclpy.try_shutdown(context=context)


def _spin_until(executor, predicate, timeout: float) -> bool:
    """Spin until ``predicate()``; the timeout only bounds a failure."""
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.01)
    return predicate()


def _one_demo_demonstrator(context, lockstep: bool) -> Demonstrator:
    """A demonstrator of one unconstrained 1 s demonstration at 100 Hz, started at once."""
    return Demonstrator(context=context, parameter_overrides=[
        Parameter("robot", value="talos"), Parameter("joints", value=JOINTS),
        Parameter("rate_hz", value=100.0), Parameter("num_demos", value=1),
        Parameter("demo_duration_s", value=1.0), Parameter("constraint_frames", value=[""]),
        Parameter("reach_timeout_s", value=0.1), Parameter("startup_delay_s", value=0.0),
        Parameter("service_timeout_s", value=20.0),
        Parameter("step_on_joint_state", value=lockstep)])


def _fake_recorder(context, q: np.ndarray):
    """The fake recorder, robot and controller: one probe node.

    It answers ``~/start_demo`` and ``~/stop_demo`` (appending "start"/"stop" to
    ``events``), publishes the joint state ``q`` every 10 ms while ``publishing[0]``, and
    collects the velocity commands. Returns (probe, publishing, events, commands).
    """
    probe = Node("recorder", context=context)
    publishing, events, commands = [True], [], []

    def publish_state():
        if publishing[0]:
            msg = JointState(name=JOINTS, position=q.tolist())
            msg.header.stamp = probe.get_clock().now().to_msg()
            states.publish(msg)

    def trigger(name):
        def answer(request, response):
            events.append(name)
            response.success, response.message = True, name
            return response
        return answer

    states = probe.create_publisher(JointState, "/joint_states", 10)
    probe.create_timer(0.01, publish_state)
    probe.create_service(Trigger, "~/start_demo", trigger("start"))
    probe.create_service(Trigger, "~/stop_demo", trigger("stop"))
    probe.create_subscription(JointState, "/joint_states", lambda msg: None, 10)
    probe.create_subscription(Float64MultiArray, "/velocity_controller/commands",
                              lambda msg: commands.append(np.array(msg.data)), 100)
    return probe, publishing, events, commands


@pytest.mark.parametrize(("domain_id", "lockstep"), [(185, False), (186, True)])
def test_stale_joint_states_pause_with_zero_commands_and_destroy_sends_zero(domain_id,
                                                                            lockstep):
    # A JointGroupVelocityController holds the last command forever: when the joint states
    # stop, the demonstrator must command zero (not keep integrating a stale q) and pause
    # the demonstration; destroying the node must leave a zero command behind.
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    nodes = []
    try:
        demo = _one_demo_demonstrator(context, lockstep)
        nodes.append(demo)
        bad = demo.set_parameters([Parameter("state_timeout_s", value=float("nan"))])
        assert not bad[0].successful and "state_timeout_s" in bad[0].reason
        assert not demo.set_parameters([Parameter("state_timeout_s", value=0.0)])[0].successful
        assert demo.set_parameters([Parameter("state_timeout_s", value=0.1)])[0].successful
        lower, upper = demo.robot.lower, demo.robot.upper
        q = np.clip(demo.attractor + 0.2, lower, upper)  # away from it: the expert moves
        probe, publishing, events, commands = _fake_recorder(context, q)
        nodes.append(probe)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(demo)
        executor.add_node(probe)

        def moving_in_demo():
            return demo._state == "demo" and bool(commands) and np.abs(commands[-1]).max() > 0

        assert _spin_until(executor, moving_in_demo, 30.0), (demo._state, events)
        publishing[0] = False
        stopped = len(commands)
        assert _spin_until(executor, lambda: any(
            not c.any() for c in commands[stopped:]), 10.0), "no zero after the states stop"
        first_zero = stopped + next(k for k, c in enumerate(commands[stopped:]) if not c.any())
        # Longer than the whole demonstration (1 s) without joint states: zeros only, and
        # the demonstration is paused, not run to its end on a stale state.
        paused_at = time.monotonic()
        _spin_until(executor, lambda: time.monotonic() - paused_at > 1.5, 3.0)
        zeros = commands[first_zero:]
        assert len(zeros) >= 10 and not any(c.any() for c in zeros)
        assert events == ["start"] and demo._state == "demo"
        # Joint states again: the demonstration goes on where it was.
        publishing[0] = True
        resumed = len(commands)
        assert _spin_until(executor, lambda: any(
            c.any() for c in commands[resumed:]), 10.0), "no motion after the states return"
        assert demo._state == "demo" and np.abs(commands[-1]).max() > 0
        # Destroyed mid-motion: the last command the controller receives is a zero.
        executor.remove_node(demo)
        nodes.remove(demo)
        before = len(commands)
        demo.destroy_node()
        publishing[0] = False
        assert _spin_until(executor, lambda: len(commands) > before and not commands[-1].any(),
                           5.0), "no zero command on destroy_node"
        _spin_until(executor, lambda: False, 0.3)  # nothing may follow it
        assert not commands[-1].any()
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


_LoggedDemonstrator = logged(Demonstrator)


def _started(args=(), **params) -> Demonstrator:
    """A demonstrator built (not spun) in its own context on START_DOMAIN, with ``args``
    as the command line after ``--ros-args`` and ``params`` as overrides."""
    context = rclpy.Context()
    rclpy.init(args=["--ros-args", *args] if args else None, context=context,
               domain_id=START_DOMAIN)
    try:
        demo = _LoggedDemonstrator(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        demo.destroy_node()
        return demo
    finally:
        rclpy.try_shutdown(context=context)


def test_the_shipped_parameter_file_leaves_the_frames_to_the_robot_config(tmp_path):
    # The file once set Talos's frames, which overrode every other robot config's: panda,
    # ur5 and a UR10 config of the user's stopped at start on arm_left_7_link.
    ur10 = tmp_path / "ur10.yaml"
    ur10.write_text(load_robot_config("ur5").path.read_text().replace(
        "robot: ur5 ", "robot: ur10 "))
    for config in ("panda", "ur5", str(ur10)):
        demo = _started(["--params-file", str(PARAMETER_FILE), "-p",
                         f"robot_config:={config}"])
        expected = load_robot_config(config)
        assert demo.robot.name == expected.robot
        assert demo.script.frames == expected.constraint_frames
        assert demo.sources == {"constraint_frames": "robot config",
                                "hand_frames": "robot config", "attractor": "robot config"
                                if expected.home else "default"}
        # Said once at start: the frames used, by name.
        said = [m for level, m in demo.log.records
                if level == "info" and expected.constraint_frames[0] in m]
        assert len(said) == 1


def test_frames_of_another_robot_are_refused_naming_their_parameter(tmp_path):
    # Given at start: the parameter, its value and the robot config's frames to fall back on.
    with pytest.raises(StartParameterError) as err:
        _started(robot_config="ur5", constraint_frames=["tool0", HAND])
    problem = err.value.problem
    assert problem.name == "constraint_frames" and problem.cause == Cause.REFUSED
    assert problem.value == ["tool0", HAND] and HAND in problem.reason
    assert "tool0" in problem.reason.split(HAND, 1)[1]  # the config's frames, after it
    with pytest.raises(StartParameterError) as err:
        _started(robot_config="ur5", expert="hands", hand_frames=[HAND])
    assert err.value.problem.name == "hand_frames"
    # The joints expert has no use for hand frames: they are not checked.
    demo = _started(robot_config="ur5", hand_frames=[HAND])
    assert demo.hand_expert is None and demo.script.frames == ["tool0"]
    # [''] is no constraint frame, and the node says where that came from.
    demo = _started(robot_config="ur5", constraint_frames=[""])
    assert demo.script.frames == [] and demo.sources["constraint_frames"] == "parameter"
    # A robot config's own bad frame names the parameter and the file.
    bad = tmp_path / "bad.yaml"
    bad.write_text(load_robot_config("ur5").path.read_text().replace(
        "constraint: [tool0]", "constraint: [no_such_link]"))
    with pytest.raises(ValueError, match="constraint_frames") as err:
        _started(robot_config=str(bad))
    assert str(bad) in str(err.value) and "no_such_link" in str(err.value)
    # No robot config (a robot none is shipped for): the default, Talos's hands, is named.
    with pytest.raises(ValueError, match="constraint_frames") as err:
        _started(robot="ur10", joints=["shoulder_pan_joint", "shoulder_lift_joint"])
    assert not isinstance(err.value, StartParameterError) and HAND in str(err.value)


def test_a_clock_jump_back_stops_the_demonstration_under_way(monkeypatch):
    # A simulator reset during a demonstration: the node clock goes from 10 s back to 2 s.
    # The demonstration is stopped (the recorder discards one recorded across the reset)
    # with a zero command, not run on for the 8 s the reset added to its elapsed time.
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=START_DOMAIN)
    try:
        demo = _LoggedDemonstrator(context=context, parameter_overrides=[
            Parameter("robot", value="talos"), Parameter("joints", value=JOINTS)])
        sent = []
        monkeypatch.setattr(demo, "_send", lambda qdot: sent.append(np.array(qdot)))
        monkeypatch.setattr(demo, "_now", lambda: 2.0)
        demo._q, demo._q_received = demo.attractor.copy(), 9.99
        demo._state, demo._since, demo._last_now = "demo", 7.0, 10.0
        demo._on_timer()
        assert demo._state == "stop_demo" and np.all(sent[-1] == 0.0)
        assert any(level == "warning" for level, _ in demo.log.records)
        # The recorder discards it: done again from a new start, no retry spent.
        demo._stopped(Trigger.Response(success=False, message="discarded"))
        assert demo._state == "reach" and demo._failures == 0 and demo.demos_done == 0
        # Waiting states start their wait again on the new clock.
        demo._state, demo._since, demo._last_now = "reach", 9.0, 10.0
        demo._on_timer()
        assert demo._since == 2.0
        # A step back under CLOCK_RESET_S (a system clock's correction) is no reset.
        demo._state, demo._since, demo._last_now = "wait", 1.5, 2.5
        demo._on_timer()
        assert demo._since == 1.5
        demo.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
