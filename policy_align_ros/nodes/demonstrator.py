"""``demonstrator``: the teacher that produces constrained demonstrations.

The expert, its random starts and planes and its commands are
:class:`policy_align_ros.sim.script.DemonstrationScript` (parameter ``expert``: ``joints``
or ``hands``); this node runs it on a robot and brackets each demonstration with the
recorder's services.

For each of ``num_demos`` demonstrations it:

1. drives the robot to a random start ``q0 ~ N(attractor, start_variance I)`` (clipped
   to the joint limits) with a proportional controller;
2. draws a random plane for every frame of ``constraint_frames`` (by default both hands),
   re-drawn ``plane_switches`` times at regular intervals during the demonstration;
3. calls the recorder's ``start_demo`` (std_srvs/Trigger), runs the constrained expert
   for ``demo_duration_s`` seconds, stops the robot and calls ``stop_demo``.

All timing is on the node clock, so with ``use_sim_time`` the demonstrations run on the
simulator's ``/clock``; when it jumps back by ``CLOCK_RESET_S`` or more (a restarted
simulation) a demonstration under way is stopped and done again (the recorder discards it;
no retry is spent), and a wait starts again. Control ticks during a demonstration that come
later than 1.5 periods after the previous one are counted as late (the simulator then
integrated an older command). With ``step_on_joint_state`` the node steps once per received
joint state instead (lockstep with a simulator that publishes one state per tick: the
command the simulator integrates next is computed from the state it just published, an exact
Euler step of the expert as long as the node keeps up).

The frames and the attractor it uses, and where each came from (a parameter, the robot
config, a default), are logged once at start. A frame that is not one of the robot's
stops the node at start with an error naming the parameter it came from and the fix: a
``constraint_frames`` or ``hand_frames`` given for another robot (a parameter file
written for Talos, say) overrides the robot config's frames.

It starts once the recorder's services exist and the recorder subscribes to
``/joint_states``. A demonstration that the recorder refuses to write at ``stop_demo`` is
redone (``max_retries`` in total); a refused ``start_demo`` ends the run.

Commands go to ``/velocity_controller/commands`` (std_msgs/Float64MultiArray, rad/s,
order = ``joints``); the state comes from ``/joint_states``. A JointGroupVelocityController
holds the last command forever, so the node never commands from an old state: while the
last joint state arrived more than ``state_timeout_s`` ago (node clock), it publishes zeros
every period and the demonstration (or the move to its start) pauses, its clock stopped,
and it goes on where it was when joint states come back (also in lockstep, where a timer
still watches for joint states that stop). ``destroy_node`` publishes a zero command.

Progress is published on ``~/progress`` (std_msgs/String, transient local) as
``k/K late_ticks=m/t``: ``k`` of ``K`` demonstrations done, ``m`` late control ticks among
``t`` during demonstrations. With ``exit_when_done`` the process exits after the last
demonstration (status 0, or 1 when the recorder refused a call).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from rclpy.parameter import Parameter
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from policy_align_ros.control import speed_limits
from policy_align_ros.data.messages import CLOCK_RESET_S, JointSelector
from policy_align_ros.kinematics import Robot, RobotConfig, RobotSetup
from policy_align_ros.nodes._common import (
    LATCHED_QOS,
    StartNode,
    accept,
    declare_robot,
    descriptor,
    load_robot,
    optional_parameter,
    publish_zero_command,
    reject,
    run_node,
    start_overrides,
)
from policy_align_ros.nodes.start_parameters import StartParameterError, start_parameter_problem
from policy_align_ros.sim.script import (
    DEFAULT_FRAMES,
    EXPERTS,
    DemonstrationScript,
    plane_segment,
    stale_joint_state,
)

__all__ = ["Demonstrator", "main", "unknown_frame"]

#: A control tick later than this many periods after the previous one counts as late.
LATE_TICK_PERIODS = 1.5
#: States that command motion computed from the joint states (paused while they are stale).
MOVING_STATES = ("reach", "demo")
#: The robot config's key (``frames:``) behind each frame parameter's default.
_CONFIG_KEYS = {"constraint_frames": "constraint", "hand_frames": "hands"}


def unknown_frame(robot: Robot, frames: Sequence[str]) -> str:
    """Why one of ``frames`` is no frame of ``robot``, with the closest names; "" when
    every one is (an empty name, the parameters' "none", is skipped).

    Parameters
    ----------
    robot : Robot
    frames : sequence of str

    Returns
    -------
    str
    """
    for frame in frames:
        if not frame:
            continue
        try:
            robot.frame_id(frame)
        except ValueError as err:
            return str(err).removeprefix("frame: ")
    return ""


def _shown_frames(frames: Sequence[str]) -> str:
    names = [f for f in frames if f]
    return f"[{', '.join(names)}]" if names else "none"


class Demonstrator(StartNode):
    """The ``demonstrator`` node (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__("demonstrator", **kwargs)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        setup = declare_robot(self, "commanded")
        self._declare_parameters(setup.config)
        value = self.get_parameter
        robot = load_robot(setup)
        joints = list(robot.joint_names)
        self.period = 1.0 / value("rate_hz").value
        #: Where the frames and the attractor came from: "parameter", "robot config" or
        #: "default" (Talos's hands without a robot config; the reference posture).
        self.sources = {name: self._source(name, setup.config)
                        for name in ("constraint_frames", "hand_frames")}
        self._check_frames(robot, "constraint_frames", setup.config)
        if value("expert").value == "hands":  # the joints expert never uses hand_frames
            self._check_frames(robot, "hand_frames", setup.config)
        attractor = optional_parameter(self, "attractor")
        self.sources["attractor"] = "parameter"
        if attractor is None:
            attractor = setup.home
            self.sources["attractor"] = "default" if attractor is None else "robot config"
        self.script = DemonstrationScript(
            robot, attractor, value("gain").value,
            str(value("expert").value), value("constraint_frames").value,
            value("hand_frames").value, optional_parameter(self, "hand_targets"),
            speed_limits(robot.velocity_limit, value("max_velocity").value), self.period,
            np.random.default_rng(value("seed").value))
        self.robot, self.attractor = robot, self.script.attractor
        self.hand_expert = self.script.hand_expert
        self.num_demos = int(value("num_demos").value)
        self.done = Future()
        self.demos_done = 0
        self._failures = 0
        self._selector = JointSelector(joints)
        self._q: np.ndarray | None = None
        self._q_received: float | None = None  # arrival of self._q [s, node clock]
        self._rejected: str | None = None  # why the last joint state was not usable
        self._paused_at: float | None = None  # start of a pause for stale joint states
        self._state = "wait"
        self._since = self._now()
        self._last_tick: float | None = None
        self._last_now: float | None = None  # the node clock at the last step [s]
        self._redo = False  # the demonstration was stopped for a clock reset
        self._ready_since: float | None = None
        #: Control ticks during demonstrations, and those later than LATE_TICK_PERIODS.
        self.demo_ticks = 0
        self.late_ticks = 0
        self._pending: Future | None = None
        self._segment = 0
        self._q0 = self.attractor

        recorder = value("recorder").value.rstrip("/")
        self._start = self.create_client(Trigger, f"{recorder}/start_demo")
        self._stop = self.create_client(Trigger, f"{recorder}/stop_demo")
        self._cmd = self.create_publisher(Float64MultiArray, "/velocity_controller/commands", 10)
        self._progress = self.create_publisher(String, "~/progress", LATCHED_QOS)
        self._lockstep = bool(value("step_on_joint_state").value)
        self._states = self.create_subscription(JointState, "/joint_states",
                                                self._on_joint_state, 10)
        # In lockstep the joint states drive the steps; the timer still catches joint
        # states that stop coming (no step would then replace the last command).
        self.create_timer(self.period, self._on_watchdog if self._lockstep else self._on_timer)
        self.get_logger().info(self._settings_line(setup))

    def _source(self, name: str, config: RobotConfig | None) -> str:
        """Where parameter ``name``'s value came from (see ``self.sources``)."""
        # A value given at start is the user's, whatever the robot config says.
        if name in start_overrides(self):
            return "parameter"
        return "robot config" if config is not None else "default"

    def _check_frames(self, robot: Robot, name: str, config: RobotConfig | None) -> None:
        """Stop at start on a frame of parameter ``name`` that ``robot`` lacks, naming the
        parameter, where its value came from and the fix (StartParameterError for a value
        given at start, ValueError for a default)."""
        frames = list(self.get_parameter(name).value)
        problem = unknown_frame(robot, frames)
        if not problem:
            return
        source = self.sources[name]
        # No constraint frame is a choice (unconstrained demonstrations); the hands expert
        # needs a hand frame.
        none = " ([''] for none)" if name == "constraint_frames" else ""
        if source == "parameter":
            fix = f"set {name} to frames of robot {robot.name!r}{none}"
            own = [] if config is None else (
                config.hands if name == "hand_frames" else config.constraint_frames)
            if own:
                fix += (f", or leave it unset (remove it from the parameter file) so that the "
                        f"robot config's frames ({_shown_frames(own)}) are used")
            raise StartParameterError(start_parameter_problem(
                self.get_fully_qualified_name(), name, frames, expected_type="STRING_ARRAY",
                given_type="STRING_ARRAY", reason=f"{problem}; {fix}"))
        if source == "robot config":
            raise ValueError(
                f"{name}: {problem}, from frames.{_CONFIG_KEYS[name]} of robot config "
                f"{config.path}; correct it there, or set {name} to frames of this "
                f"robot{none}")
        raise ValueError(
            f"{name}: {problem}; without a robot config for robot {robot.name!r} it "
            f"defaults to Talos's hands: set {name} to frames of this robot{none}, or "
            "robot_config")

    def _settings_line(self, setup: RobotSetup) -> str:
        """The frames and attractor used and where each came from, said once at start (a
        value given at start and one left to the robot config look the same otherwise)."""
        config = f"robot config {setup.config.name}" if setup.config is not None else ""
        defaults = {"constraint_frames": "Talos's hands, no robot config",
                    "hand_frames": "Talos's hands, no robot config",
                    "attractor": "the robot's reference posture"}

        def origin(name: str) -> str:
            source = self.sources[name]
            return config if source == "robot config" else (
                defaults[name] if source == "default" else source)

        hands = (f"{_shown_frames(self.script.hand_frames)} ({origin('hand_frames')})"
                 if self.hand_expert is not None else "unused (expert joints)")
        attractor = ", ".join(f"{x:.3f}" for x in self.attractor)
        return (f"demonstrations on robot {self.robot.name}: constraint frames "
                f"{_shown_frames(self.script.frames)} ({origin('constraint_frames')}), "
                f"hand frames {hands}, attractor [{attractor}] rad ({origin('attractor')})")

    def _declare_parameters(self, config: RobotConfig | None) -> None:
        """The expert's and the schedule's parameters; frame lists default to those of
        the robot config (``config``), else Talos's hands."""
        p = self.declare_parameter
        hands = config.hands if config is not None else DEFAULT_FRAMES
        planes = config.constraint_frames if config is not None else DEFAULT_FRAMES
        p("attractor", Parameter.Type.DOUBLE_ARRAY, descriptor(
            "minimum of the expert potential [rad]; unset = robot_config's home, else the "
            "reference posture 0.1 rad inside the limits", read_only=True))
        p("gain", 1.0, descriptor("expert gain: pi = -gain (q - attractor) [1/s]",
                                  read_only=True, float_range=(0.01, 20.0)))
        p("expert", "joints", descriptor(
            "joints: potential in joint space; hands: potential in the stacked positions "
            "of hand_frames, pi_x = -gain (x - hand_targets) realised through the "
            "Jacobian", read_only=True, constraints="joints | hands"))
        p("hand_frames", hands or [""], descriptor(
            "frames whose stacked positions are the hands expert's state; unset = "
            "robot_config's frames.hands", read_only=True))
        p("hand_targets", Parameter.Type.DOUBLE_ARRAY, descriptor(
            "hands expert: target positions [m], 3 per hand frame in the world frame; "
            "unset = the hands' positions at the attractor posture", read_only=True))
        p("start_variance", 0.1, descriptor(
            "variance of the random start around the attractor [rad^2] (paper: 0.1)",
            read_only=True, float_range=(0.0, 4.0)))
        p("num_demos", 20, descriptor("number of demonstrations", read_only=True,
                                      int_range=(1, 100000)))
        p("demo_duration_s", 3.0, descriptor("length of one demonstration [s]",
                                             read_only=True, float_range=(0.1, 600.0)))
        p("constraint_frames", planes or [""], descriptor(
            "frames each restricted to a plane of random orientation per demonstration "
            "(empty string list entry '' = unconstrained); unset = robot_config's "
            "frames.constraint", read_only=True))
        p("plane_switches", 2, descriptor(
            "times the planes are re-drawn at regular intervals within a demonstration",
            read_only=True, int_range=(0, 100)))
        p("rate_hz", 100.0, descriptor("command rate [Hz]", read_only=True,
                                       float_range=(1.0, 1000.0)))
        p("step_on_joint_state", False, descriptor(
            "lockstep with a simulator: one control step per received joint state instead "
            "of on the rate_hz timer, so the command the simulator integrates next comes "
            "from the latest state (rate_hz is then the simulator's rate)", read_only=True))
        p("state_timeout_s", 0.2, descriptor(
            "joint states older than this (by arrival) pause the demonstration and command "
            "zero [s]", float_range=(0.001, 10.0)))
        p("max_velocity", 2.0, descriptor("joint speed limit [rad/s]; the URDF's applies "
                                          "where lower", read_only=True,
                                          float_range=(0.01, 10.0)))
        p("reach_gain", 5.0, descriptor("gain of the move to each start [1/s]",
                                        read_only=True, float_range=(0.1, 50.0)))
        p("reach_tolerance", 0.01, descriptor("start reached when max |q - q0| is below [rad]",
                                              read_only=True, float_range=(1e-4, 1.0)))
        p("reach_timeout_s", 5.0, descriptor("give up reaching a start after this [s]",
                                             read_only=True, float_range=(0.1, 600.0)))
        p("recorder", "/recorder", descriptor("recorder node whose start_demo/stop_demo "
                                              "services bracket each demonstration",
                                              read_only=True))
        p("service_timeout_s", 30.0, descriptor("wait this long for the recorder [s]",
                                                read_only=True, float_range=(0.1, 3600.0)))
        p("max_retries", 3, descriptor(
            "demonstrations the recorder refused to write are redone this often in total",
            read_only=True, int_range=(0, 1000)))
        p("startup_delay_s", 1.0, descriptor(
            "wait this long after the recorder appears before the first demonstration [s]",
            read_only=True, float_range=(0.0, 60.0)))
        p("seed", 0, descriptor("random seed", read_only=True, int_range=(0, 2**31 - 1)))
        p("exit_when_done", True, descriptor("exit after the last demonstration",
                                             read_only=True))

    def _now(self) -> float:
        """Seconds on the node clock (the simulator's /clock with use_sim_time)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_set_parameters(self, params: Sequence[Parameter]):
        for param in params:
            if param.name == "joints" and (not param.value
                                           or len(set(param.value)) != len(param.value)):
                return reject("joints: must be a non-empty list without repeats")
            if param.name in ("attractor", "hand_targets") and param.value is not None \
                    and not np.all(np.isfinite(param.value)):
                return reject(f"{param.name}: contains NaN or inf")
            if param.name == "expert" and param.value not in EXPERTS:
                return reject(f"expert: must be one of {', '.join(EXPERTS)}, "
                              f"got {param.value!r}")
            # rclpy's range check comes first; the rule is stated here too, as in the
            # executor, so that it holds whatever range the descriptor is given.
            if param.name == "state_timeout_s" and not (math.isfinite(param.value)
                                                        and param.value > 0.0):
                return reject(f"state_timeout_s: must be finite and > 0, got {param.value}")
        return accept()

    def _on_joint_state(self, msg: JointState) -> None:
        q = self._selector.vector(msg.name, msg.position, msg.velocity, msg.effort)
        if isinstance(q, str):  # a str is why the message was rejected
            self._rejected = q
        else:
            self._q = q
            self._q_received = self._now()
            if self._lockstep:
                self._on_timer()

    # -- state machine, one step per timer tick ---------------------------------------
    def _enter(self, state: str) -> None:
        self._state = state
        self._since = self._now()

    def _send(self, qdot: np.ndarray) -> None:
        self._cmd.publish(Float64MultiArray(data=qdot.tolist()))

    def publish_zeros(self, why: str) -> None:
        """Publish one zero command and wait briefly for subscribers to acknowledge it."""
        publish_zero_command(self, self._cmd, len(self._selector.joints), why)

    def destroy_node(self) -> None:
        """Stop the robot (zero command) before the node goes away."""
        if self.context.ok() and hasattr(self, "_cmd"):
            self.publish_zeros("shutdown")
        super().destroy_node()

    def _finish(self, code: int, why: str) -> None:
        self._send(np.zeros(len(self._selector.joints)))
        (self.get_logger().info if code == 0 else self.get_logger().error)(why)
        self._enter("done")
        if self.get_parameter("exit_when_done").value and not self.done.done():
            self.done.set_result(code)

    def _call(self, client, what: str) -> None:
        self._pending = client.call_async(Trigger.Request())
        self._enter(what)

    def _answer(self) -> Trigger.Response | None:
        """The pending service answer, None while waiting; finishes on a timeout."""
        if self._pending.done():
            response = self._pending.result()
            if response is None:
                self._finish(1, f"recorder gave no answer to {self._state}")
            return response
        if self._now() - self._since > self.get_parameter("service_timeout_s").value:
            self._finish(1, f"recorder did not answer {self._state}")
        return None

    def _recorder_listens(self) -> bool:
        recorder = "/" + self.get_parameter("recorder").value.strip("/")
        # The topic as remapped, which the recorder must record from too.
        for info in self.get_subscriptions_info_by_topic(self._states.topic_name):
            if f"{info.node_namespace.rstrip('/')}/{info.node_name}" == recorder:
                return True
        return False

    def _on_timer(self) -> None:
        now = self._now()
        if now <= 0.0:
            return  # use_sim_time and no /clock yet: time would jump at the first message
        if self._since <= 0.0:
            self._since = now
        if self._last_now is not None and self._last_now - now >= CLOCK_RESET_S:
            self._clock_jumped(self._last_now - now, now)
        self._last_now = now
        if not self._fresh(now):
            return
        elapsed = now - self._since
        if self._state == "demo" and self._last_tick is not None:
            self.demo_ticks += 1
            if now - self._last_tick > LATE_TICK_PERIODS * self.period:
                self.late_ticks += 1
        self._last_tick = now
        if self._state == "wait":
            self._wait(now, elapsed)
        elif self._state == "reach":
            self._reach(self._q, elapsed)
        elif self._state == "start_demo":
            response = self._answer()
            if response is not None and not response.success:
                self._finish(1, f"recorder refused start_demo: {response.message}")
            elif response is not None:
                self._enter("demo")
        elif self._state == "demo":
            self._demo(self._q, elapsed)
        elif self._state == "stop_demo":
            response = self._answer()
            if response is not None:
                self._stopped(response)

    def _wait(self, now: float, elapsed: float) -> None:
        """Start the first demonstration once the robot and the recorder are there."""
        if self._q is not None and self._start.service_is_ready() and \
                self._stop.service_is_ready() and self._recorder_listens():
            # The recorder's subscription shows in the graph before the transport has
            # matched it with the robot's publisher: give discovery time to finish,
            # or the first demonstration is recorded from its middle.
            if self._ready_since is None:
                self._ready_since = now
            if now - self._ready_since >= self.get_parameter("startup_delay_s").value:
                self._new_start()
        elif elapsed > self.get_parameter("service_timeout_s").value:
            self._finish(1, f"gave up after service_timeout_s: {self._not_ready()}")

    def _clock_jumped(self, back: float, now: float) -> None:
        """The node clock went back by ``back`` s, :data:`CLOCK_RESET_S` or more (a
        restarted simulation, as the recorder tells it): a demonstration under way is
        stopped and done again (the recorder discards it, and no retry is spent); any
        other state starts its wait again on the new clock."""
        self._last_tick = self._paused_at = self._ready_since = None
        self._q_received = None  # a joint state from before the reset is not fresh
        if self._state == "done":
            return
        then = ("demonstration stopped, to be done again" if self._state == "demo"
                else f"{self._state} waits again")
        self.get_logger().warning(f"the clock jumped back by {back:.3f} s (a simulator "
                                  f"reset?): {then}")
        if self._state == "demo":
            self._send(np.zeros(len(self._selector.joints)))
            self._redo = True
            self._call(self._stop, "stop_demo")
        else:
            self._since = now

    def _not_ready(self) -> str:
        """What the first demonstration still waits for, and what to check."""
        topic, recorder = self._states.topic_name, self.get_parameter("recorder").value
        missing = []
        if self._q is None:
            missing.append(f"no usable joint state on {topic} ("
                           + (f"the last was rejected: {self._rejected})" if self._rejected
                              else "none received)"))
        missing += [f"no service {c.srv_name} (is the recorder {recorder} running?)"
                    for c in (self._start, self._stop) if not c.service_is_ready()]
        if not missing and not self._recorder_listens():
            missing.append(f"{recorder} does not subscribe to {topic} (remap it the same "
                           "way, or set the recorder parameter to its name)")
        return "; ".join(missing)

    def _reach(self, q: np.ndarray, elapsed: float) -> None:
        """Move to the start; once there (or out of time), draw planes and start_demo."""
        tolerance = self.get_parameter("reach_tolerance").value
        if self.script.start_distance(q, self._q0) < tolerance or \
                elapsed > self.get_parameter("reach_timeout_s").value:
            self._send(np.zeros_like(q))
            self.script.draw_planes()
            self._segment = 0
            self._call(self._start, "start_demo")
            return
        self._send(self.script.reach_command(q, self._q0,
                                             self.get_parameter("reach_gain").value))

    def _demo(self, q: np.ndarray, elapsed: float) -> None:
        """One expert command; new planes at each switch; stop_demo at the end."""
        duration = self.get_parameter("demo_duration_s").value
        if elapsed >= duration:
            self._send(np.zeros_like(q))
            self._call(self._stop, "stop_demo")
            return
        segment = plane_segment(elapsed, duration, self.get_parameter("plane_switches").value)
        if segment > self._segment:
            self._segment = segment
            self.script.draw_planes()
        self._send(self.script.command(q))

    def _stopped(self, response: Trigger.Response) -> None:
        """Count a written demonstration, or redo a refused one (``max_retries``, not spent
        on one stopped for a clock reset)."""
        redo, self._redo = self._redo, False
        if redo and not response.success:
            self.get_logger().warning(f"recorder discarded the demonstration cut by the "
                                      f"reset ({response.message}); redoing demonstration "
                                      f"{self.demos_done + 1}")
            self._new_start()
            return
        if not response.success:
            # The recorder kept nothing (e.g. its subscription was not matched yet):
            # redo this demonstration from a new start, a few times at most.
            self._failures += 1
            if self._failures > self.get_parameter("max_retries").value:
                self._finish(1, f"recorder refused stop_demo: {response.message}")
            else:
                self.get_logger().warning(
                    f"recorder refused stop_demo ({response.message}); redoing "
                    f"demonstration {self.demos_done + 1}")
                self._new_start()
            return
        self.demos_done += 1
        self._progress.publish(String(
            data=f"{self.demos_done}/{self.num_demos} "
                 f"late_ticks={self.late_ticks}/{self.demo_ticks}"))
        self.get_logger().info(f"demonstration {self.demos_done}/{self.num_demos} recorded")
        if self.demos_done >= self.num_demos:
            self._finish(0, f"all {self.num_demos} demonstrations recorded")
        else:
            self._new_start()

    def _fresh(self, now: float) -> bool:
        """Whether a moving state may command from the last joint state; pauses if not.

        While it is stale the command is zero on every call (a dropped zero must not leave
        the robot moving) and the state's clock stands still, so the demonstration goes on
        where it was, its full length on the planes drawn for it.
        """
        if self._state not in MOVING_STATES:
            return True
        problem = stale_joint_state(self._q_received, now,
                                    self.get_parameter("state_timeout_s").value)
        if problem:
            if self._paused_at is None:
                self._paused_at = now
                self.get_logger().warning(f"{problem}: command zero, {self._state} paused")
            self._send(np.zeros(len(self._selector.joints)))
            self._last_tick = None  # a pause is not a late control tick
            return False
        if self._paused_at is not None:
            paused = max(0.0, now - self._paused_at)
            self._since += paused
            self._paused_at = None
            self.get_logger().info(f"joint states back: {self._state} resumed after "
                                   f"{paused:.3f} s")
        return True

    def _on_watchdog(self) -> None:
        """Lockstep mode's timer: zero commands once the joint states stop."""
        now = self._now()
        if now > 0.0:  # use_sim_time and no /clock yet: nothing to measure against
            self._fresh(now)

    def _new_start(self) -> None:
        self._q0 = self.script.new_start(self.get_parameter("start_variance").value)
        self._enter("reach")


def main(args: Sequence[str] | None = None) -> int:
    """Console script ``demonstrator``."""
    return run_node(Demonstrator, args)


if __name__ == "__main__":
    raise SystemExit(main())
