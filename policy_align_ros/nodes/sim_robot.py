"""``sim_robot``: a kinematic simulation of a robot driven by joint velocity commands.

Subscribes ``/velocity_controller/commands`` (std_msgs/Float64MultiArray, rad/s, order =
``joints``), publishes ``/joint_states`` (sensor_msgs/JointState: rad, rad/s, stamped) at
``rate_hz``, and offers ``~/reset`` (std_srvs/Trigger) back to ``initial_positions``.
Commands older than ``command_timeout_s`` are dropped and the robot holds still. The
integration itself is :class:`policy_align_ros.sim.simulator.KinematicSim`. With
``wrap_continuous`` the continuous joints' positions are published on ``[-pi, pi)``, as a
real driver reports them; the motion is still integrated without wrapping.

Simulated time: with ``publish_clock`` the node owns the graph's time. Every tick advances
it by exactly one period (``1 / rate_hz``), publishes it on ``/clock``
(rosgraph_msgs/Clock) and stamps the joint states with it; ticks come
``real_time_factor`` times faster than real time, so the graph runs faster (or slower)
than real time. Other nodes follow with ``use_sim_time:=true``. The simulated clock starts
at 1 s (a zero stamp reads as "no stamp"), so a restarted simulation makes the clock jump
backwards, which the executor treats as a reason to disarm. Without ``publish_clock``
the node's own clock times everything (it honours ``use_sim_time`` like every node).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from rclpy.clock import Clock as RclClock
from rclpy.clock import ClockType
from rclpy.parameter import Parameter
from rclpy.time import Time
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from policy_align_ros.nodes._common import (
    StartNode,
    accept,
    declare_robot,
    descriptor,
    load_robot,
    optional_parameter,
    reject,
    run_node,
)
from policy_align_ros.sim.simulator import KinematicSim, wrap_continuous

__all__ = ["SIM_CLOCK_START_NS", "SimRobot", "main"]

#: The simulated clock's first reading [ns] (not 0: a zero stamp means "unstamped").
SIM_CLOCK_START_NS = 1_000_000_000


class SimRobot(StartNode):
    """The ``sim_robot`` node (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__("sim_robot", **kwargs)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        # The joints left out are locked at the reference posture.
        setup = declare_robot(self, "simulated")
        self.declare_parameter("initial_positions", Parameter.Type.DOUBLE_ARRAY, descriptor(
            "start and ~/reset positions [rad], one per joint; unset = robot_config's home, "
            "else the reference posture"))
        self.declare_parameter("rate_hz", 100.0, descriptor(
            "integration and /joint_states publishing rate [Hz]", read_only=True,
            float_range=(1.0, 1000.0)))
        self.declare_parameter("command_timeout_s", 0.2, descriptor(
            "commands older than this are ignored and the robot holds still [s]",
            float_range=(0.001, 10.0)))
        self.declare_parameter("publish_clock", False, descriptor(
            "own the graph's time: publish /clock, one period per tick", read_only=True))
        self.declare_parameter("real_time_factor", 1.0, descriptor(
            "with publish_clock: simulated seconds per wall-clock second", read_only=True,
            float_range=(0.1, 100.0)))
        self.declare_parameter("wrap_continuous", False, descriptor(
            "publish continuous joints' positions on [-pi, pi), as a real driver does",
            read_only=True))

        self.robot = load_robot(setup)
        self._home = setup.home
        joints = list(self.robot.joint_names)
        self.sim = KinematicSim(
            self.robot.lower, self.robot.upper, self._initial_positions(),
            command_timeout_s=self.get_parameter("command_timeout_s").value,
            velocity_limit=_positive_or_inf(self.robot.velocity_limit),
        )
        self._period = 1.0 / self.get_parameter("rate_hz").value
        self._sim_clock = bool(self.get_parameter("publish_clock").value)
        # Wrapping only what is published keeps the integrated motion smooth across pi.
        self._wrapped = (self.robot.continuous
                         if self.get_parameter("wrap_continuous").value else None)
        self._sim_ns = SIM_CLOCK_START_NS
        self._last_step = self._now()
        self._bad_commands = 0

        self._clock_pub = (self.create_publisher(Clock, "/clock", 10)
                           if self._sim_clock else None)
        self._pub = self.create_publisher(JointState, "/joint_states", 10)
        self.create_subscription(
            Float64MultiArray, "/velocity_controller/commands", self._on_command, 10)
        self.create_service(Trigger, "~/reset", self._on_reset)
        factor = self.get_parameter("real_time_factor").value if self._sim_clock else 1.0
        # With a simulated clock the ticks are paced by the wall clock, whatever
        # use_sim_time says: this node is the source of /clock.
        self.create_timer(self._period / factor, self._on_timer,
                          clock=self._wall_clock() if self._sim_clock else None)
        self.get_logger().info(
            f"simulating {self.robot.name} with {len(joints)} joints at "
            f"{1.0 / self._period:g} Hz"
            + (f", publishing /clock at {factor:g}x real time" if self._sim_clock else ""))

    @staticmethod
    def _wall_clock() -> RclClock:
        return RclClock(clock_type=ClockType.STEADY_TIME)

    def _now(self) -> float:
        """Seconds on the simulated clock (``publish_clock``) or the node's clock."""
        if self._sim_clock:
            return self._sim_ns * 1e-9
        return self.get_clock().now().nanoseconds * 1e-9

    def _initial_positions(self) -> np.ndarray:
        values = optional_parameter(self, "initial_positions")
        if values is None:
            return self.robot.neutral() if self._home is None else np.array(self._home)
        return np.asarray(values, dtype=float)

    def _on_set_parameters(self, params: Sequence[Parameter]):
        for param in params:
            if param.name == "joints" and not param.value:
                # ``joints:=[]`` on the command line arrives unset (None), not as a list.
                return reject("joints: need at least one joint name")
            if param.name == "joints" and len(set(param.value)) != len(param.value):
                return reject("joints: a joint is listed twice")
            if param.name == "initial_positions" and param.value is not None:
                values = np.asarray(param.value, dtype=float)
                n = len(self.get_parameter("joints").value) if self.has_parameter(
                    "joints") else values.size
                if values.size != n or not np.all(np.isfinite(values)):
                    return reject(
                        f"initial_positions: need {n} finite values, got {values.size}")
        return accept()

    def _after_set_parameters(self, params: Sequence[Parameter]) -> None:
        for param in params:
            if param.name == "command_timeout_s" and hasattr(self, "sim"):
                self.sim.command_timeout_s = float(param.value)

    def _on_command(self, msg: Float64MultiArray) -> None:
        try:
            self.sim.set_command(np.asarray(msg.data, dtype=float), self._now())
        except ValueError as err:
            self._bad_commands += 1
            self.get_logger().warning(
                f"ignored velocity command ({self._bad_commands} so far): {err}",
                throttle_duration_sec=2.0)

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response):
        q = self.sim.reset(self._initial_positions())
        # On its own clock the time stands still until the next tick, which publishes the
        # reset state: a message now would repeat the last stamp, and subscribers skip a
        # stamp that does not increase.
        if not self._sim_clock:
            self._publish(q)
        source = ("initial_positions" if optional_parameter(self, "initial_positions")
                  is not None else "the reference posture")
        response.success = True
        response.message = f"reset {self.sim.n_joints} joints to {source}"
        return response

    def _on_timer(self) -> None:
        if self._sim_clock:
            self._sim_ns += int(round(self._period * 1e9))
            self._clock_pub.publish(Clock(clock=self._stamp()))
        now = self._now()
        # A late timer tick must not turn into one big jump: cap the step at two periods.
        dt = min(max(now - self._last_step, 0.0), 2.0 * self._period)
        self._last_step = now
        self._publish(self.sim.step(dt, now))

    def _stamp(self):
        if self._sim_clock:
            return Time(nanoseconds=self._sim_ns).to_msg()
        return self.get_clock().now().to_msg()

    def _publish(self, q: np.ndarray) -> None:
        msg = JointState()
        msg.header.stamp = self._stamp()
        msg.name = list(self.robot.joint_names)
        msg.position = (q if self._wrapped is None
                        else wrap_continuous(q, self._wrapped)).tolist()
        msg.velocity = self.sim.qdot.tolist()
        self._pub.publish(msg)


def _positive_or_inf(limits: np.ndarray) -> np.ndarray:
    # URDFs often give 0 for "no velocity limit".
    return np.where(limits > 0.0, limits, np.inf)


def main(args: Sequence[str] | None = None) -> int:
    """Console script ``sim_robot``."""
    return run_node(SimRobot, args)


if __name__ == "__main__":
    raise SystemExit(main())
