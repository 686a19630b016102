"""``executor``: drive a robot with a learnt policy under the configured constraints.

At ``rate_hz`` it publishes ``qdot = s N(q) pi_hat(q)`` (rad/s, order = ``joints``) on
``/velocity_controller/commands`` (std_msgs/Float64MultiArray), from the latest
``/joint_states`` (sensor_msgs/JointState, matched by name). ``N(q)`` comes from the
``constraints`` parameter (a YAML list of constraint specs, see
``policy_align_ros.kinematics.constraint_from_spec``) and ``s`` keeps every joint under
``max_velocity`` (rad/s) and inside its limits (:mod:`policy_align_ros.control`). The robot
and ``joints`` are the explicit parameters, else the model file's at ``model_path``, else
the robot config's (``robot_config``; docs/design.md section 4). A model file given at
start whose robot or joints contradict a ``robot_config`` given is not loaded: the
executor starts without a model and logs an error naming both and the fixes.

A model learnt on frame positions (its header's state definition is ``{"type": "frames",
...}``) gives a task-space policy ``pi_x(x)`` (m/s) over the stacked positions ``x`` (3F,)
of its frames; the executor checks that the definition matches its own robot (URDF,
joints, frames, locked posture) and refuses the model otherwise, then commands
``qdot = (J N_A)^+ pi_x + (N_A - (J N_A)^+ J N_A) z``, the joint velocity closest to moving
the frames along ``pi_x`` with ``A(q) qdot = 0`` for the constraints in force (``J`` the
frames' Jacobian, ``z`` a pull towards the demonstrations' rest posture,
:mod:`policy_align_ros.control.task_policy`). Limits and ramps apply as in joint space.

Safety (the logic is ROS-free, :class:`policy_align_ros.control.armed.ArmedController`;
docs/executor_safety.md explains it for robot owners):

* the executor is *armed* only by ``~/enable`` (std_srvs/SetBool) true, which is refused,
  with the reason (and the fix), while no model is loaded or the one loaded was refused by
  learn and written only because it was forced (unless ``allow_forced_model``; a warning
  names the refusals at load), no valid joint state arrived
  (naming the controlled joints the messages lack), the joint states are stale or the
  constraints cannot be enforced at the current state (a near-singular or non-finite
  constraint matrix: a frame that the controlled joints do not move, more constraint rows
  than joints); a disable, a model swap and any fault (the policy raising included)
  disarm it, and it stays disarmed until enabled again. Every arm and disarm is logged
  with the model and the constraints in force;
* each joint's command changes by at most ``max_acceleration * period`` per period, both
  when following the policy and when ramping down to zero after a disarm (published until
  the command is zero, then the topic is left alone), and when ``max_velocity`` is lowered
  while armed; joints brake to rest ``joint_limit_margin`` inside their URDF limits and
  before barriers, and a constraint added at run time is blended in at that rate;
* joint states that are lost (none received for ``state_timeout_s``, or the last stamped
  longer ago than ``state_timeout_s + max_clock_skew_s``), broken
  (a joint twice, NaN/inf, arrays of other lengths; counted, warned about at most every
  2 s) or untrustworthy by their header stamp (zero, too old, too far ahead of the node
  clock beyond ``max_clock_skew_s``, going backwards) send a zero command at once and
  disarm; so does the node clock jumping backwards (a restarted simulation), and so does
  a position outside its URDF limits by more than ``state_limit_margin`` (a position of
  1e6 rad, a wrong joint map), naming the joint and the value;
* ``~/enable`` also reads the ``joints`` parameter of the ros2_control controller named by
  ``controller`` (GetParameters, waiting at most 1 s of wall time while the node keeps
  running) and refuses when its order differs from ``joints``, and when the order cannot
  be read (no such node, no string-array ``joints``), naming the fix; only an explicit
  ``controller:=none`` (or an empty string from a parameter file) arms without the check;
  ``controller`` set while the check waits refuses that enable (the new controller's
  order was never read);
* the extrapolation guard scales down commands that lead further than
  ``max_extrapolation`` spacings of the training data away from it, to zero within a band
  at least the stopping distance at ``max_velocity``, and at most
  ``max_extrapolation_rad`` from the data in joint space (a robot held there stays armed;
  the log says so once and ``/diagnostics`` names the limit that binds; a learnt goal
  beyond that reach is warned about at load); frames held by position
  constraints are latched at enable and their drift pulled back (``drift_gain``,
  ``drift_clamp_m``); a constraint matrix whose smallest singular value falls below
  ``min_singular_value`` ramps down and disarms, with the reason;
* a joint that does not follow its command (measured positions moving along it by less
  than a quarter of the expected motion for ``stall_time_s`` while commanded at least
  0.05 rad/s; :mod:`policy_align_ros.control.stall`) ramps down, disarms and is reported
  at ERROR level;
* at ``~/enable`` (``stop_check``), and for constraints set while armed (in a fifth of
  each period, after its command), the model and its CV folds' models are run from the
  current state under the constraints in force; where their stops disagree by more than
  5 % of the travel, the answer, the log and ``/diagnostics`` say the stop is uncertain
  (:mod:`policy_align_ros.control.stop_check`);
* all control timing uses the node clock, so ``use_sim_time`` works;
* ``/diagnostics`` (diagnostic_msgs/DiagnosticArray, every second of the steady clock and
  on arming changes) reports the arming state, the model, why the command is zero, the
  ramp scale, the extrapolation scale, the held frames' error and whether the node clock
  advances (a paused simulation stops it, and every control step with it).

A ros2_control JointGroupVelocityController holds its last command forever, so the
executor also publishes a zero when it shuts down; pair it with a controller-side command
timeout for the case it is killed. Models load from ``model_path`` (at start, and when it
is set) or from ``/learner/model`` announcements when it follows the learner
(``follow_learner``, or no ``model_path`` given at start); one that does not load is
refused with the reason (at start: the node stops) and the current one stays.
"""

from __future__ import annotations

import functools
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool

from policy_align_ros.control import (
    SLICE_S,
    ArmedController,
    ArmedRecheck,
    ClockWatch,
    GuardHoldLog,
    Output,
    StartModel,
    ZeroCause,
    apply_setting,
    arming_status,
    build_controller,
    check_in_slices,
    clock_mismatch_hint,
    constraints_from_text,
    constraints_problem,
    enable_answer,
    install_model,
    load_policy,
    model_text,
    no_model_fix,
    rejection_note,
    setting_problem,
    stop_check_answer,
    stop_check_note,
    unchanged,
    untrustworthy_reason,
)
from policy_align_ros.data.messages import UNTRUSTWORTHY, JointSelector, UnusableReasons
from policy_align_ros.kinematics import Robot
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.fold_stops import StopSpread
from policy_align_ros.nodes._common import (
    LATCHED_QOS,
    StartNode,
    accept,
    declare_robot,
    descriptor,
    load_robot,
    next_cycle,
    optional_parameter,
    publish_zero_command,
    reject,
    run_node,
)
from policy_align_ros.nodes.controller_client import ControllerClient
from policy_align_ros.nodes.executor_parameters import declare_control_parameters
from policy_align_ros.nodes.start_parameters import StartParameterError

__all__ = ["Executor", "main"]

#: Period of the /diagnostics status (s, steady clock); every arming change, by ~/enable,
#: a stale or broken state or a fault, also goes out at once (through ``_emit``).
DIAGNOSTICS_PERIOD_S = 1.0


class Executor(StartNode):
    """The ``executor`` node (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__("executor", **kwargs)
        # ~/enable runs in its own callback group so the node keeps running while it waits
        # for the controller; under a multi-threaded executor this lock keeps it from
        # touching the controller while another callback does.
        self._lock = threading.RLock()
        self.robot: Robot | None = None
        self.controller: ArmedController | None = None
        self.model_path = ""
        # A model loaded while validating ``model_path``, applied once the set succeeds.
        self._staged: tuple[str, PolicyAlign, Callable, np.ndarray, str] | None = None
        #: The model file given at start: read once for the robot and the policy, and
        #: whether it was refused, failed to load or wins over /learner/model.
        self._start_model = StartModel()
        #: What the loaded model's state is: "joints" or "frames F1, F2".
        self.model_state = ""
        # The controller's parameter client; ``controller`` is validated with it.
        self._order_client = ControllerClient(self)
        self.add_on_set_parameters_callback(self._locked(self._on_set_parameters))
        self.add_post_set_parameters_callback(self._locked(self._after_set_parameters))
        self._declare_robot_parameters()
        self._declare_control_parameters()
        self.controller = build_controller(
            self.robot, lambda name: self.get_parameter(name).value,
            constraints_from_text(self._constraints_text(), self.robot))
        self._selector = JointSelector(self.robot.joint_names)
        #: Rejected joint-state messages by reason, over the node's lifetime.
        self.rejected_states: Counter[str] = Counter()
        self._last = Output(None, self.controller.zero_reason, 1.0,
                            zero_cause=self.controller.zero_cause)
        #: The arming state the last /diagnostics status reported.
        self._diag_armed = False
        self._recheck: ArmedRecheck | None = None  # of constraints set while armed
        self._hold_log = GuardHoldLog()  # says once when the guard starts holding the robot
        self._create_interfaces()

    def _declare_robot_parameters(self) -> None:
        """The read-only parameters the robot and the control period are built from:
        robot and joints explicit, else the model file's, else robot_config's."""
        setup = declare_robot(self, "controlled", model_path="model_path",
                              read_fields=self._start_model.robot_fields)
        self.robot, self._default_controller = load_robot(setup), setup.controller
        self._start_model.refused = setup.model_refused
        self.declare_parameter("rate_hz", 100.0, descriptor(
            "control rate [Hz]", read_only=True, float_range=(1.0, 1000.0)))

    def _declare_control_parameters(self) -> None:
        """The run-time parameters (declared once the robot is loaded: their set callback
        loads models and checks constraint specs on it).

        A model file given at start that does not load stops the node with
        :attr:`~policy_align_ros.control.loading.StartModel.load_error`, which also says
        where a relative path was looked for (rather than the StartParameterError of
        any other refused value); one that contradicts ``robot_config`` is left out with
        an error logged, and ``model_path`` reads empty.
        """
        try:
            declare_control_parameters(self, self._default_controller)
        except StartParameterError:
            if self._start_model.load_error:
                raise ValueError(self._start_model.load_error) from None
            raise
        if self._start_model.given(self.get_parameter("model_path").value):
            self.set_parameters([Parameter("model_path", value="")])

    def _create_interfaces(self) -> None:
        """Publishers, subscriptions, the ~/enable service and the timers."""
        self._pub = self.create_publisher(Float64MultiArray, "/velocity_controller/commands", 10)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        if self._staged is not None:
            self._apply_staged()
        self._update_context()
        self._arm_at_start = bool(self.get_parameter("start_enabled").value)
        self._follow_learner = self._start_model.follows_learner(
            bool(self.get_parameter("follow_learner").value))
        self._lockstep = bool(self.get_parameter("step_on_joint_state").value)
        if self._arm_at_start and self.controller.step.policy is None:
            self.get_logger().warning(
                "start_enabled ignored: no model_path loaded at start; call ~/enable once "
                "a model is loaded")
            self._arm_at_start = False
        states = self.create_subscription(JointState, "/joint_states",
                                          self._locked(self._on_joint_state), 10)
        self.controller.state_topic = states.topic_name  # as remapped, for the reasons
        self._unusable_reason = UnusableReasons(
            self.robot.joint_names, "Publish every joint of the executor's joints parameter "
            "on the topic, or start the executor with the robot's joints (-p joints:=[...] "
            "or -p robot_config:=NAME)")
        self.create_subscription(String, "/learner/model", self._locked(self._on_model),
                                 LATCHED_QOS)
        self._order_client.use(self.get_parameter("controller").value)
        #: Counts ~/enable requests, so a check that finishes late knows it was superseded.
        self._enable_requests = 0
        self.create_service(SetBool, "~/enable", self._on_enable,
                            callback_group=ReentrantCallbackGroup())
        # Timers run on the node clock (rclpy's default), hence on /clock with use_sim_time.
        self.create_timer(self.controller.step.dt, self._locked(self._on_timer))
        # The status alone runs on the steady clock: a paused simulation stops the node
        # clock, and /diagnostics then says so rather than falling silent.
        self._clock_watch = ClockWatch(round(DIAGNOSTICS_PERIOD_S * 1e9))
        self.create_timer(DIAGNOSTICS_PERIOD_S, self._locked(self.publish_diagnostics),
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _locked(self, callback: Callable) -> Callable:
        """``callback`` run under the node's lock (see ``_lock``)."""
        @functools.wraps(callback)
        def run(*args):
            with self._lock:
                return callback(*args)
        return run

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    # -- parameters -------------------------------------------------------------------
    def _constraint_matrix(self, q: np.ndarray, qdot: np.ndarray | None = None
                           ) -> np.ndarray:
        """The constraints in force at call time (a task-space policy's ``A(q)``)."""
        return self.controller.step.constraint_matrix(q, qdot)

    def _joint_bounds(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Velocity bounds in force at call time: those ``ControlStep`` scales to."""
        return self.controller.step.velocity_bounds(q)

    def _on_set_parameters(self, params: Sequence[Parameter]):
        """Validate (and load a new model); :meth:`_after_set_parameters` applies."""
        for param in params:
            if problem := setting_problem(param.name, param.value):
                return reject(problem)
            if param.name == "constraints" and self.robot is not None:
                if problem := constraints_problem(param.value, self.robot):
                    return reject(problem)
            elif param.name == "model_path":
                result = self._stage_model(param.value)
                if result is not None:
                    return result
            elif param.name == "controller":
                if problem := self._order_client.name_problem(param.value):
                    return reject(problem)
        return accept()

    def _stage_model(self, path: str):
        """Load ``path`` for a ``model_path`` set; a refusal result, or None when loaded."""
        self._staged = None
        starting = self.controller is None
        if not path:
            if starting:
                return None  # the default at start: wait for /learner/model
            return reject("model_path: empty; the loaded model stays (disable with "
                          "~/enable to stop)")
        if starting and (refusal := self._start_model.refusal(path)):
            self.get_logger().error(refusal)
            return None  # model_path is then set empty (_declare_control_parameters)
        try:
            model, policy, perm, state = load_policy(
                path, self.robot, self._constraint_matrix, self._joint_bounds,
                self._start_model.take(path))
        except (ValueError, OSError) as err:
            if starting:
                self._start_model.load_failed(path, err)
            return reject(f"model_path: not loaded: {err}")
        self._staged = (path, model, policy, perm, state)
        return None

    def _after_set_parameters(self, params: Sequence[Parameter]) -> None:
        if self.controller is None:
            return  # still declaring: __init__ builds the controller from the values
        for param in params:
            if apply_setting(self.controller, param.name, param.value,
                             self.robot.velocity_limit):
                continue
            if param.name == "constraints":
                self.controller.step.constraints = constraints_from_text(param.value,
                                                                         self.robot)
                self.controller.stop_spread = None  # it was of the constraints before
                self._recheck = self._start_recheck()
                self._update_context()
                self.get_logger().info(f"constraints now {param.value or '[]'}")
            elif param.name == "model_path" and self._staged is not None:
                self._apply_staged()
            elif param.name == "controller":
                self._order_client.use(param.value)

    # -- model ------------------------------------------------------------------------
    def _apply_staged(self) -> None:
        path, model, policy, perm, state = self._staged
        self._staged = None
        self._arm_at_start = False  # a swapped model is never armed without ~/enable
        # Its log lines (a forced model, a goal beyond the guard's reach) come with ``out``.
        out = install_model(
            self.controller, self.robot, path, model, policy, perm, state,
            max_extrapolation=self.get_parameter("max_extrapolation").value,
            max_extrapolation_rad=self.get_parameter("max_extrapolation_rad").value)
        self.model_state, self.model_path = state, path
        self._update_context()
        self._emit(out)

    def _on_model(self, msg: String) -> None:
        if not self._follow_learner:
            self.get_logger().info(self._start_model.ignored_announcement(msg.data))
            return
        result = self.set_parameters([Parameter("model_path", value=msg.data)])[0]
        if not result.successful:
            self.get_logger().error(
                f"model announced on /learner/model refused: {result.reason}")

    def _constraints_text(self) -> str:
        # ``-p constraints:=[]`` reaches rcl as no value: the parameter stays unset.
        return optional_parameter(self, "constraints") or "[]"

    def _update_context(self) -> None:
        constraints = self._constraints_text()
        self.controller.context = (f"model {self.model_path or '(none)'}; "
                                   f"constraints {constraints}")

    # -- inputs -----------------------------------------------------------------------
    def _on_joint_state(self, msg: JointState) -> None:
        now = self._now_ns()
        q = self._selector.vector(msg.name, msg.position, msg.velocity, msg.effort)
        if isinstance(q, str):
            if q in UNTRUSTWORTHY:
                self._count_rejected(q)
                self._emit(self.controller.reject_state(untrustworthy_reason(
                    q, self.robot.joint_names, msg.name, msg.position, msg.velocity,
                    msg.effort), ZeroCause(q)))
            else:  # unknown_joints, missing_joints: counted, named, nothing stops
                reason = self._unusable_reason(msg.name)
                self._count_rejected(q, reason)
                self.controller.unusable_state(reason)
            return
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        out = self.controller.joint_state(q, stamp, now)
        if out.rejected:
            self._count_rejected(out.rejected, clock_mismatch_hint(out.rejected, stamp, now))
        self._emit(out)
        if self._lockstep and not out.rejected:
            self._emit(self.controller.tick(now))
            self._advance_recheck()
        if self._arm_at_start and not out.rejected and self.executor is not None:
            # Armed like ~/enable, with the controller check, without blocking this thread.
            self._arm_at_start = False
            self.executor.create_task(self._enable_at_start)

    def _count_rejected(self, reason: str, hint: str = "") -> None:
        self.rejected_states[reason] += 1
        routine, text = rejection_note(reason, sum(self.rejected_states.values()), hint)
        if routine:
            self.get_logger().debug(text, throttle_duration_sec=2.0)
        else:
            self.get_logger().warning(text, throttle_duration_sec=2.0)

    async def _on_enable(self, request: SetBool.Request, response: SetBool.Response):
        """Arm (after the controller's joint order check) or disarm.

        A coroutine in its own callback group: while it waits for the controller's answer
        the node keeps serving joint states and control ticks (no deadlock in a single
        thread); a disable meanwhile makes the pending enable fail.
        """
        if request.data:
            response.success, response.message = await self._enable()
            return response
        with self._lock:
            self._arm_at_start = False
            self._enable_requests += 1
            self._recheck = None  # of the run disarmed
            self._emit(self.controller.disarm("disabled by ~/enable", ZeroCause.DISABLED))
            response.success = True
            response.message = f"disabled ({model_text(self.model_path)})"
        return response

    async def _enable_at_start(self) -> None:
        accepted, message = await self._enable()
        if not accepted:
            self.get_logger().error(f"start_enabled: not armed: {message}")

    async def _enable(self) -> tuple[bool, str]:
        """Arm unless refused; ``(accepted, message)`` for the ~/enable answer."""
        with self._lock:
            self._arm_at_start = False
            self._enable_requests += 1
            ticket = self._enable_requests
            path = self.model_path
            cause, reason = self.controller.arm_check(self._now_ns())
            if cause == ZeroCause.NO_MODEL:
                fix = no_model_fix(self.get_fully_qualified_name(), self._follow_learner)
                reason += f"; {fix}"
            accepted = not reason
            check = accepted and not self.controller.armed
            client = self._order_client.begin() if check else self._order_client.client
        note = ""
        if check:
            try:
                reason, note = await self._check_controller(client)
            finally:
                with self._lock:
                    self._order_client.end()
            accepted = not reason
        spread, current = (await self._stop_check(ticket) if check and accepted
                           else (None, lambda: True))
        with self._lock:
            if check and ticket != self._enable_requests:
                accepted, reason = False, "superseded by a later ~/enable request"
            elif check and client is not self._order_client.client:
                accepted, reason = False, "the controller changed while it was checked"
            elif check and (path != self.model_path or not current()):
                accepted, reason = False, ("the model or the constraints changed while "
                                           "~/enable checked them")
            if accepted:
                accepted, reason, out = self.controller.arm(self._now_ns())
                if accepted and check:
                    self._recheck, self.controller.stop_spread = None, spread
                    note += stop_check_answer(spread, out)
                self._emit(out)
            message = enable_answer(accepted, reason, note, self.model_path)
            if not accepted:
                self.get_logger().warning(f"~/enable {message}")
        return accepted, message

    async def _stop_check(self, ticket: int
                          ) -> tuple[StopSpread | None, Callable[[], bool]]:
        """The fold-stop check of the run from the current state (:mod:`policy_align_ros.
        control.stop_check`) in slices, between which the node serves its other
        callbacks: its spread (None when off, nothing to check, superseded, or failed,
        which is logged), and whether the model and constraints checked are still those in
        force and the enable request ``ticket`` the last."""
        with self._lock:
            step, q = self.controller.step, self.controller.last_q
            check, same = step.stop_check, unchanged(step)

            def current() -> bool:
                return ticket == self._enable_requests and same()

            if check is None or q is None or not self.get_parameter("stop_check").value:
                return None, current
        try:
            with self._lock:
                run = check.prepare(step, q)
            return await check_in_slices(run, self._lock, SLICE_S, next_cycle,
                                         current), current
        except Exception as err:  # noqa: BLE001 - an unchecked stop does not stop arming
            self._stop_check_failed(err)
            return None, current

    async def _check_controller(self, client) -> tuple[str, str]:
        """The controller's joint order check (:meth:`ControllerClient.order_refusal`)."""
        return await self._order_client.order_refusal(
            client, self.get_parameter("controller").value, self.robot.joint_names)

    # -- output -----------------------------------------------------------------------
    def _on_timer(self) -> None:
        now = self._now_ns()
        # In lockstep the joint states drive the steps; a second step per period would
        # double the ramp's rate. The timer still catches joint states that stop coming.
        if self._lockstep and not self.controller.state_problem(now):
            return
        self._emit(self.controller.tick(now))
        self._advance_recheck()

    def _start_recheck(self) -> ArmedRecheck | None:
        """The fold-stop check of constraints just set while armed (None: none)."""
        try:
            return ArmedRecheck.begin(self.controller, self.get_parameter("stop_check").value)
        except Exception as err:  # noqa: BLE001 - an unchecked stop does not disarm
            self._stop_check_failed(err)
            return None

    def _advance_recheck(self) -> None:
        """A slice of it once the period's command is out; its result shown and said."""
        if self._recheck is None:
            return
        try:
            ended, found = self._recheck.advance(self.controller,
                                                 self.get_parameter("stop_check").value)
        except Exception as err:  # noqa: BLE001 - an unchecked stop does not disarm
            self._stop_check_failed(err)
            ended, found = True, None
        if ended:
            self._recheck = None
        if found is not None:
            self.controller.stop_spread = found
            if note := stop_check_note(found):
                self.get_logger().warning(f"constraints {self._constraints_text()}: {note}")
            self.publish_diagnostics()

    def _stop_check_failed(self, err: Exception) -> None:  # logged: it does not disarm
        self.get_logger().warning(f"stop check failed: {type(err).__name__}: {err}")

    def _emit(self, out: Output) -> None:
        """Publish the command the controller asks for and log its events."""
        if out.command is not None:
            self._pub.publish(Float64MultiArray(data=out.command.tolist()))
        logger = self.get_logger()
        held = self._hold_log.update(self.controller, self._now_ns())  # once, as it begins
        for level, text in out.events + held:
            # One call site per severity: rclpy keys its logging context on the caller.
            if level == "warning":
                logger.warning(text)
            else:
                logger.info(text)
        self._last = out
        # A disarm by a stale state or a fault, or the guard beginning to hold the robot,
        # must not wait for the next periodic status.
        if self.controller.armed != self._diag_armed or held:
            self.publish_diagnostics()

    def publish_diagnostics(self) -> None:
        """Publish the executor's status on ``/diagnostics``."""
        control, now_ns = self.controller, self._now_ns()
        level, message, values = arming_status(
            control, now_ns, model=self.model_path, model_state=self.model_state,
            constraints=self._constraints_text(), rejected=self.rejected_states,
            checking=self._recheck is not None and control.armed)
        values["node_clock"] = self._clock_watch.update(now_ns, time.monotonic_ns())
        status = DiagnosticStatus(
            level=(DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)[level],
            name=f"{self.get_name()}: arming", message=message,
            hardware_id=str(self.get_parameter("robot").value),
            values=[KeyValue(key=k, value=v) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(array)
        self._diag_armed = control.armed

    def publish_zeros(self, why: str) -> None:
        """Publish one zero command and wait briefly for subscribers to acknowledge it."""
        publish_zero_command(self, self._pub, self.controller.step.n_joints, why)

    def destroy_node(self) -> None:
        """Stop the robot (zero command) before the node goes away."""
        if self.context.ok() and hasattr(self, "_pub") and self.controller is not None:
            self.publish_zeros("shutdown")
        super().destroy_node()


def main(args: Sequence[str] | None = None) -> int:
    """Console script ``executor``."""
    return run_node(Executor, args)


if __name__ == "__main__":
    raise SystemExit(main())
