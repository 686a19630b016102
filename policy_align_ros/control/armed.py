"""The armed controller: arming, stamps, staleness and ramps around a control step.

Everything runs on time stamps passed in (integer nanoseconds of the caller's clock, a ROS
node clock in the executor), so it runs and is tested without a graph and honours
simulated time:

* *arming*: commands follow the policy only between :meth:`ArmedController.arm` (refused
  without a model or with stale joint states) and the next disarm, which a disable, a
  model swap or any fault causes; nothing re-arms on its own;
* *acceleration ramp*: each joint's command changes by at most ``max_acceleration * dt``
  per step (:func:`~policy_align_ros.control.limits.ramp_toward`: ramp first, then
  project onto the constraints' null space). A disarm ramps the command down to zero the
  same way; only untrustworthy or lost joint states (and a clock jumping backwards) stop
  it at once, because without a trusted ``q`` there is no safe command to ramp through;
* *staleness*: joint states count as fresh by their arrival time and by their header
  stamp; zero stamps, stamps too old or too far in the future, and stamps going backwards
  are untrustworthy;
* *plausibility*: a position outside its joint limits by more than ``state_limit_margin``
  (a position of 1e6 rad, a wrong joint map) is untrustworthy too;
* *stall*: with a :class:`~policy_align_ros.control.stall.StallDetector`, a joint that
  the measured positions show not following its command for ``stall_time_s`` ramps the
  command down and disarms (:attr:`ArmedController.stalled`).

Every disarm says why twice: in words (:attr:`ArmedController.zero_reason`) and as a
:class:`~policy_align_ros.control.causes.ZeroCause` (:attr:`ArmedController.zero_cause`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from policy_align_ros.control.causes import ZeroCause
from policy_align_ros.control.limits import (
    DEFAULT_STATE_LIMIT_MARGIN,
    ROUNDOFF,
    position_outside_limits,
    ramp_toward,
    velocity_scale,
)
from policy_align_ros.control.output import Output
from policy_align_ros.control.stall import Stall, StallDetector
from policy_align_ros.control.stamp_hints import clock_mismatch_hint
from policy_align_ros.control.step import ControlStep, PolicyFn

__all__ = ["IMPLAUSIBLE_POSITION", "STAMP_REJECTIONS", "ArmedController", "Output"]


#: Keys of :attr:`Output.rejected` (values of their :class:`ZeroCause`): stamp zero,
#: earlier than the last one, older than ``state_timeout_s + max_clock_skew_s``, later
#: than the clock by ``max_clock_skew_s``.
STAMP_REJECTIONS: tuple[str, ...] = tuple(c.value for c in (
    ZeroCause.ZERO_STAMP, ZeroCause.STAMP_BACKWARDS, ZeroCause.STAMP_TOO_OLD,
    ZeroCause.STAMP_IN_FUTURE))
#: Zero causes a restarted clock explains (stamps that then look old, early or late).
_STAMP_CAUSES = (ZeroCause.STAMP_BACKWARDS, ZeroCause.STAMP_TOO_OLD,
                 ZeroCause.STAMP_IN_FUTURE, ZeroCause.STALE_STATE)
#: Key of :attr:`Output.rejected` for a position outside its limits beyond the margin.
IMPLAUSIBLE_POSITION = ZeroCause.POSITION_OUTSIDE_LIMITS.value

#: Minimum time between two reports of a constraint forcing a larger change (ns).
_FORCED_REPORT_NS = 1_000_000_000
#: Relative excess over the ramp's bound that counts as a forced change (not round-off).
_FORCED_TOLERANCE = 1e-6


class ArmedController:
    """Arming, staleness and acceleration ramps around a :class:`ControlStep`.

    Times are integer nanoseconds of the caller's clock (the executor node's clock, so
    simulated time works); nothing here reads a clock. Per control period the caller
    passes the latest valid joint state (:meth:`joint_state`), reports broken ones
    (:meth:`reject_state`) and those without every controlled joint
    (:meth:`unusable_state`) and calls :meth:`tick`; every call returns an :class:`Output`
    whose ``command``, when not None, must be published at once. A tick sooner than one
    period after the last published command may change it by the acceleration bound
    times the time in between only, so calling :meth:`tick` more often (one step per
    joint state of a driver faster than the period) cannot exceed ``max_acceleration``.

    Parameters
    ----------
    step : ControlStep
        The control law (policy, constraints, limits, period ``dt`` in s).
    max_acceleration : float
        Per-joint acceleration bound of the command (rad/s^2), > 0.
    state_timeout_s : float
        Joint states older than this (by arrival, or by stamp beyond the allowed skew)
        are stale (s), > 0.
    max_clock_skew_s : float
        Allowed offset between the joint states' stamps and this clock (s), >= 0.
    joint_names : sequence of str, optional
        Names used in log lines (controller order).
    state_limit_margin : float, optional
        How far outside the step's joint limits a measured position may lie and still be
        accepted (rad), >= 0.
    stall : StallDetector, optional
        Stall detection while armed (None: off).
    state_topic : str, optional
        Where the joint states come from, for the reasons (the executor's subscription).

    Attributes
    ----------
    armed : bool
        Whether commands follow the policy.
    command : ndarray, shape (n,)
        The last command published (rad/s).
    faulted : bool
        Whether the last disarm was caused by a fault (joint states, clock, policy output,
        a stall) rather than requested; cleared when armed again.
    zero_reason : str
        Why the command is zero or ramping to zero, in words; empty while armed.
    zero_cause : ZeroCause or None
        The same as a stable identifier; None while armed.
    stalled : bool
        Whether the last disarm was a stall (:attr:`zero_reason` describes it); cleared
        when armed again.
    last_stall : Stall or None
        That stall: the joints, the commanded and the measured speed; None unless
        :attr:`stalled`.
    clock_jump_s : float
        How far the clock last jumped back (s); 0 until it does.
    context : str
        Appended to arm and disarm log lines (the caller puts the model and the
        constraint specs there).
    ramp_scale : float
        ``alpha`` of the last step (:func:`ramp_toward`; 1 = on target).
    extrapolation_scale : float
        The extrapolation guard's scale at the last step that followed the policy.
    stop_spread : StopSpread or None
        The fold-stop check at the last arming (:mod:`~policy_align_ros.control.
        stop_check`, set by the executor); None when none ran, or the model or the
        constraints changed since.
    """

    def __init__(
        self,
        step: ControlStep,
        max_acceleration: float,
        state_timeout_s: float,
        max_clock_skew_s: float = 0.0,
        joint_names: Sequence[str] | None = None,
        state_limit_margin: float = DEFAULT_STATE_LIMIT_MARGIN,
        stall: StallDetector | None = None,
        state_topic: str = "/joint_states",
    ) -> None:
        self.step = step
        self.state_topic = state_topic
        self.stall = stall
        self.stalled = False
        self.last_stall: Stall | None = None
        self.clock_jump_s = 0.0
        self.max_acceleration = max_acceleration
        self.state_timeout_s = state_timeout_s
        self.max_clock_skew_s = max_clock_skew_s
        self.state_limit_margin = state_limit_margin
        n = step.n_joints
        self.joint_names = (list(joint_names) if joint_names is not None
                            else [f"joint {i}" for i in range(n)])
        self.armed = False
        self.faulted = False
        self.command = np.zeros(n)
        self.context = ""
        self.zero_reason = "not enabled yet"
        self.zero_cause: ZeroCause | None = ZeroCause.NOT_ENABLED
        self.ramp_scale = 1.0
        self.extrapolation_scale = 1.0
        self.stop_spread = None
        # Nothing left to publish: disarmed and the zero command has gone out.
        self._silent = True
        self._q: np.ndarray | None = None
        self._rejection = ""  # why the last joint state was refused (until one is taken)
        self._rejection_cause = ZeroCause.NO_STATE
        # Why the joint states received since the last valid one cannot be used (messages
        # without every controlled joint); cleared by a valid one.
        self._unusable = ""
        self._stamp_ns: int | None = None
        self._arrival_ns: int | None = None
        self._repeat_ns: int | None = None  # arrival of the last repeat of that stamp
        self._last_now_ns: int | None = None
        self._fault_ns: int | None = None  # the clock when the last fault went to zero
        self._forced_reported_ns: int | None = None
        self._published_ns: int | None = None  # when the last ramped command went out
        self._forced_suppressed = 0
        self._events: list[tuple[str, str]] = []

    # -- settings -------------------------------------------------------------------
    @property
    def max_acceleration(self) -> float:
        """Acceleration bound (rad/s^2); also the step's braking limit near joint limits."""
        return self.step.max_acceleration

    @max_acceleration.setter
    def max_acceleration(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"max_acceleration: must be finite and > 0, got {value}")
        self.step.max_acceleration = value

    @property
    def state_timeout_s(self) -> float:
        """Joint-state timeout (s)."""
        return self._timeout_ns / 1e9

    @state_timeout_s.setter
    def state_timeout_s(self, value: float) -> None:
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"state_timeout_s: must be finite and > 0, got {value}")
        self._timeout_ns = round(value * 1e9)

    @property
    def max_clock_skew_s(self) -> float:
        """Allowed stamp-to-clock offset (s)."""
        return self._skew_ns / 1e9

    @max_clock_skew_s.setter
    def max_clock_skew_s(self, value: float) -> None:
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"max_clock_skew_s: must be finite and >= 0, got {value}")
        self._skew_ns = round(value * 1e9)

    @property
    def state_limit_margin(self) -> float:
        """Allowed excursion of a measured position beyond its joint limits (rad)."""
        return self._state_limit_margin

    @state_limit_margin.setter
    def state_limit_margin(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"state_limit_margin: must be finite and >= 0, got {value}")
        self._state_limit_margin = value

    @property
    def max_delta(self) -> float:
        """Largest change of a joint's command in one step (rad/s)."""
        return self.max_acceleration * self.step.dt

    @property
    def last_q(self) -> np.ndarray | None:
        """The last accepted joint positions (n,), or None since a fault or at start."""
        return self._q

    @property
    def publishing(self) -> bool:
        """Whether :meth:`tick` still publishes (armed, or ramping down to zero)."""
        return not self._silent

    # -- joint states ---------------------------------------------------------------
    def joint_state(self, q: np.ndarray, stamp_ns: int, now_ns: int) -> Output:
        """Take a validated joint state ``q`` (n,) stamped ``stamp_ns``, received ``now_ns``.

        A stamp that is zero, earlier than the last one (told first: a stamp far back is a
        restarted clock), older than ``state_timeout_s + max_clock_skew_s`` or more than
        ``max_clock_skew_s`` in the future makes the state untrustworthy: the command goes
        to zero at once and the controller disarms. A stamp equal to the last one is
        ignored (a repeat is no news). So is a position outside its joint limits by more
        than ``state_limit_margin``: a robot cannot be there, so the state (a wrong joint
        map, a broken driver) cannot be trusted.
        """
        jumped = self._clock(now_ns)
        if jumped is not None:
            return jumped
        stamp_ns = int(stamp_ns)
        last = self._stamp_ns
        if last is not None and stamp_ns == last:
            self._repeat_ns = int(now_ns)  # messages come, the stamp does not advance
            return self._output(None)
        key: ZeroCause | None = None
        problem = ""
        if stamp_ns <= 0:
            key, problem = ZeroCause.ZERO_STAMP, "joint state without a header stamp"
        elif last is not None and stamp_ns < last:
            # Before the age: a stamp far back is a restarted clock, not a late message.
            key = ZeroCause.STAMP_BACKWARDS
            problem = f"joint state stamp went backwards by {(last - stamp_ns) / 1e9:.3f} s"
        elif now_ns - stamp_ns > self._timeout_ns + self._skew_ns:
            key = ZeroCause.STAMP_TOO_OLD
            problem = (f"joint state stamp {(now_ns - stamp_ns) / 1e9:.3f} s old "
                       f"(> state_timeout_s + max_clock_skew_s)")
        elif stamp_ns - now_ns > self._skew_ns:
            key = ZeroCause.STAMP_IN_FUTURE
            problem = (f"joint state stamp {(stamp_ns - now_ns) / 1e9:.3f} s in the future "
                       f"(> max_clock_skew_s)")
        else:
            outside = position_outside_limits(q, self.step.lower, self.step.upper,
                                              self._state_limit_margin, self.joint_names)
            if outside:
                key = ZeroCause.POSITION_OUTSIDE_LIMITS
                problem = f"implausible joint state: {outside}"
        if key is not None:
            hint = clock_mismatch_hint(key.value, stamp_ns, now_ns)
            out = self.reject_state(f"{problem}; {hint}" if hint else problem, key)
            out.rejected = key.value
            return out
        self._q = np.asarray(q, dtype=float)
        self._rejection = self._unusable = ""
        self._stamp_ns = stamp_ns
        self._arrival_ns = int(now_ns)
        self._repeat_ns = None
        if self.stall is not None:
            self.stall.position(self._q, stamp_ns)
        return self._output(None)

    def reject_state(self, reason: str, cause: ZeroCause) -> Output:
        """A broken joint state (NaN, duplicate names, bad lengths, bad stamp) arrived.

        The last good state is forgotten, so arming needs a fresh valid one, and the
        command goes to zero at once, with ``reason`` (words) and ``cause``.
        """
        self._forget_state()
        self._rejection = f"the last joint state on {self.state_topic} was rejected: {reason}"
        self._rejection_cause = cause
        return self.fault(reason, cause)

    def unusable_state(self, reason: str) -> None:
        """A joint-state message without every controlled joint arrived (``reason`` says
        which are missing and what it names).

        Nothing stops: such messages are normal on a topic that other publishers share,
        and the last valid state stays in force until it goes stale. Until a valid state
        arrives, ``reason`` is why arming is refused (cause
        :attr:`~policy_align_ros.control.causes.ZeroCause.NO_STATE`) and is added to the
        stale-state reason, so the refusal and :attr:`zero_reason` name the missing joints.
        """
        self._unusable = reason
        if self._q is None:
            self._rejection = f"no valid joint state received on {self.state_topic}: {reason}"
            self._rejection_cause = ZeroCause.NO_STATE

    def state_problem(self, now_ns: int) -> str:
        """Why the joint states are not fresh at ``now_ns``; empty when they are."""
        return self.state_check(now_ns)[1]

    def state_check(self, now_ns: int) -> tuple[ZeroCause | None, str]:
        """As :meth:`state_problem`: ``(cause, reason)``, ``(None, "")`` when fresh.

        Without a valid state since the last one was refused, the cause and the reason are
        that refusal's. The reasons name the topic and the parameter that bounds the age.
        """
        topic = self.state_topic
        if self._q is None:
            if self._rejection:  # a rejected message, or ones without every joint
                return self._rejection_cause, self._rejection
            return ZeroCause.NO_STATE, (f"no valid joint state received on {topic}: is the "
                                        f"robot's joint state publisher running?")
        age = now_ns - self._arrival_ns
        stamp_age = now_ns - self._stamp_ns
        if age <= self._timeout_ns and stamp_age <= self._timeout_ns + self._skew_ns:
            return None, ""
        repeat = self._repeat_ns
        if repeat is not None and now_ns - repeat <= self._timeout_ns:
            return ZeroCause.FROZEN_STAMP, (
                f"joint states stale: stamp frozen at {self._stamp_ns / 1e9:.3f} s while "
                f"{topic} messages keep arriving (the last {(now_ns - repeat) / 1e9:.3f} s "
                f"ago, no new stamp for {age / 1e9:.3f} s > state_timeout_s "
                f"{self.state_timeout_s:g} s): a paused simulation or a driver that "
                f"repeats its stamp")
        if age > self._timeout_ns:
            problem = (f"joint states stale: the last valid {topic} message arrived "
                       f"{age / 1e9:.3f} s ago (state_timeout_s {self.state_timeout_s:g} s); "
                       f"is the robot's joint state publisher running, faster than "
                       f"1/state_timeout_s?")
        else:
            problem = (f"joint states stale: the last {topic} stamp is {stamp_age / 1e9:.3f} "
                       f"s old (> state_timeout_s + max_clock_skew_s = "
                       f"{self.state_timeout_s + self.max_clock_skew_s:g} s)")
        if self._unusable:
            problem += f"; the {topic} messages since then: {self._unusable}"
        return ZeroCause.STALE_STATE, problem

    def _forget_state(self) -> None:
        self._q = None
        self._rejection = self._unusable = ""
        self._stamp_ns = None
        self._arrival_ns = None
        self._repeat_ns = None

    def _clock(self, now_ns: int) -> Output | None:
        """Check that the clock runs forwards; a jump back (restarted sim) disarms."""
        last = self._last_now_ns
        self._last_now_ns = int(now_ns)
        if last is None or now_ns >= last:
            return None
        self._forget_state()
        self._forced_reported_ns = None
        self.clock_jump_s = (last - now_ns) / 1e9
        reason = f"clock jumped back by {self.clock_jump_s:.3f} s (restarted simulation?)"
        # Already at zero for a stamp the restart made look wrong, just before it (within
        # the joint states' timeout): the jump is the cause. An older fault stands.
        window = self._timeout_ns + self._skew_ns
        if (self._silent and self.zero_cause in _STAMP_CAUSES and self._fault_ns is not None
                and last - self._fault_ns <= window):
            self.zero_reason, self.zero_cause = reason, ZeroCause.CLOCK_JUMPED_BACK
            self._log("warning", f"{reason}: the joint-state fault before it came from it")
        return self.fault(reason, ZeroCause.CLOCK_JUMPED_BACK)

    # -- arming ---------------------------------------------------------------------
    def arm_check(self, now_ns: int) -> tuple[ZeroCause | None, str]:
        """Why :meth:`arm` at ``now_ns`` would be refused, as ``(cause, reason)``;
        ``(None, "")`` when it would arm.

        No side effects, so a caller can check before a slower step (the executor node
        asks the controller for its joint order only when arming would go ahead).
        """
        cause, problem = self.step.model_check()  # none loaded, or forced and not allowed
        if cause is None:
            cause, problem = self.state_check(now_ns)
        if cause is not None:
            return cause, problem
        return self.step.constraint_check(self._q)

    def arm(self, now_ns: int) -> tuple[bool, str, Output]:
        """Request to follow the policy.

        Returns
        -------
        (accepted, reason, output)
            Refused, with the reason, when :meth:`arm_check` gives one.
        """
        jumped = self._clock(now_ns)
        cause, refusal = self.arm_check(now_ns)
        if cause is not None:
            return False, refusal, jumped or self._output(None)
        if self.armed:
            return True, "already enabled", self._output(None)
        self.armed = True
        self.faulted = self.stalled = False
        self.last_stall = None
        if self.stall is not None:
            self.stall.reset()  # the window starts at the arming
        self._silent = False
        self.zero_reason = ""
        self.zero_cause = None
        # Held frames stay where they are at enable; drift is measured from here.
        self.step.latch(self._q)
        # The ramp starts from the last command sent (zero, or partway down a ramp).
        self._log("info", "armed: following the policy")
        return True, "enabled", self._output(None)

    def disarm(self, reason: str, cause: ZeroCause = ZeroCause.DISABLED) -> Output:
        """Stop following the policy and ramp the command down to zero (``reason`` logged,
        ``cause`` its identifier: a request unless told otherwise)."""
        if self.armed:
            self.armed = False
            self.zero_reason = reason
            self.zero_cause = cause
            # A disarm asked for (a disable, a new model) is news; any other (constraints
            # that over-constrain the robot, a stall) is a warning, as /diagnostics says.
            level = "info" if cause in (ZeroCause.DISABLED, ZeroCause.MODEL_SWAP) \
                else "warning"
            self._log(level, f"disarmed: {reason}; ramping down at "
                             f"{self.max_acceleration:g} rad/s^2")
        return self._output(None)

    def fault(self, reason: str, cause: ZeroCause) -> Output:
        """Zero command at once and disarm, for ``reason`` (words) and ``cause`` (nothing
        to publish, and the reason kept, when already silent)."""
        if self._silent:
            return self._output(None)
        was_armed = self.armed
        self.armed = False
        self.faulted = True
        self._silent = True
        self._fault_ns = self._last_now_ns
        self.zero_reason = reason
        self.zero_cause = cause
        self.ramp_scale = 1.0
        self.command = np.zeros(self.step.n_joints)
        self._log("warning", f"{'disarmed' if was_armed else 'ramp-down cut short'}: "
                             f"{reason}; zero command at once")
        return self._output(self.command.copy())

    def set_policy(self, policy: PolicyFn | None, permutation: np.ndarray | None = None,
                   reason: str = "model swap") -> Output:
        """Swap the model; an armed controller disarms and ramps down (``reason``)."""
        out = self.disarm(reason, ZeroCause.MODEL_SWAP)
        self.step.policy = policy
        self.step.permutation = (np.arange(self.step.n_joints) if permutation is None
                                 else np.asarray(permutation, dtype=int))
        return out

    # -- the control period ---------------------------------------------------------
    def tick(self, now_ns: int) -> Output:
        """One control period at ``now_ns``: the command to publish, if any."""
        jumped = self._clock(now_ns)
        if jumped is not None:
            return jumped
        if self._silent:
            return self._output(None)
        cause, problem = self.state_check(now_ns)
        if cause is not None:
            return self.fault(problem, cause)
        if self.armed and self.stall is not None:
            self._disarm_on_stall()
        q = self._q
        step = self.step
        previous = self.command
        projector = None
        if self.armed:
            try:
                target, reason, cause, projector = step.evaluate(q, previous)
            except Exception as err:  # noqa: BLE001 - e.g. an SVD that did not converge
                target, projector = np.zeros(step.n_joints), None
                reason = f"control step failed: {type(err).__name__}: {err}"
                cause = ZeroCause.STEP_FAILED
            self.extrapolation_scale = step.extrapolation_scale
            if cause is not None:
                # The policy cannot be trusted here, but q and the constraints still
                # can: ramp down like a disable. (disarm() hands its log line back in
                # an Output; keep it for this tick's.)
                logged = self.disarm(reason, cause).events
                self._events.extend(logged)
                self.faulted = True
        if not self.armed:
            target = np.zeros(step.n_joints)
            try:
                projector = step.hold_projector(q, previous)
            except Exception as err:  # noqa: BLE001 - the ramp down needs none of it
                return self.fault(f"constraints failed: {type(err).__name__}: {err}",
                                  ZeroCause.CONSTRAINTS_FAILED)
            if projector is None:
                return self.fault("constraint matrix not finite",
                                  ZeroCause.CONSTRAINTS_NOT_FINITE)
        limit = self.max_delta
        if self._published_ns is not None:
            since = max(0, now_ns - self._published_ns) / 1e9
            limit = self.max_acceleration * min(step.dt, since)
        command, alpha, forced = ramp_toward(previous, target, projector, limit)
        # Round-off of the projection (1e-17 rad/s on a joint locked at its limit) would
        # read as "pushed outwards" below and stop every joint.
        command[np.abs(command) < ROUNDOFF] = 0.0
        # Safety net, rarely active: the projection of the previous command may exceed a
        # speed limit, or it may head for a position limit faster than the target did. A
        # speed limit lowered at run time is reached by the ramp, not in one step: a joint
        # that was already faster keeps its last speed as its bound while it slows down.
        speed_bound = np.maximum(step.max_velocity, np.abs(previous))
        s = velocity_scale(q, command, step.dt, step.control_lower, step.control_upper,
                           speed_bound)
        if s < 1.0:
            command = s * command
        self._report_forced(command - previous, forced, s, now_ns, limit)
        self.command = command
        self._published_ns = now_ns
        self.ramp_scale = alpha
        if self.armed and self.stall is not None:
            self.stall.command(command, now_ns)
        if not self.armed and not np.any(command):
            self._silent = True
            self._log("info", f"command at zero ({self.zero_reason})")
        return self._output(command.copy())

    def _disarm_on_stall(self) -> None:
        """Ramp down and disarm when a joint does not follow its command (ERROR level)."""
        stall = self.stall.find()
        if stall is not None:
            self.armed = False
            self.faulted = self.stalled = True
            self.last_stall = stall
            self.zero_reason = stall.text
            self.zero_cause = ZeroCause.STALL
            self._log("warning", f"disarmed: {stall.text}; ramping down at "
                                 f"{self.max_acceleration:g} rad/s^2")

    def _report_forced(self, change: np.ndarray, forced: np.ndarray, s: float,
                       now_ns: int, limit: float) -> None:
        size_all = np.abs(change)
        size = float(size_all.max(initial=0.0))
        # Relative tolerance: a blend step is exactly max_delta up to round-off.
        if size <= limit * (1.0 + _FORCED_TOLERANCE) + ROUNDOFF:
            return
        worst = int(np.argmax(size_all))
        # Throttled on the caller's clock: a barrier can stay in contact for many steps.
        last = self._forced_reported_ns
        if last is not None and now_ns - last < _FORCED_REPORT_NS:
            self._forced_suppressed += 1
            return
        cause = ("speed or position limit" if s < 1.0 else "constraint")
        more = (f" ({self._forced_suppressed} more since the last report)"
                if self._forced_suppressed else "")
        self._forced_reported_ns = int(now_ns)
        self._forced_suppressed = 0
        self._events.append(("warning", (
            f"{cause} forces a command change of {size:.4g} rad/s on "
            f"{self.joint_names[worst]} in one step (ramp allows {limit:.4g}; largest "
            f"forced part {float(np.max(np.abs(forced))):.4g}){more}")))

    def _log(self, level: str, text: str) -> None:
        self._events.append((level, f"{text}{'; ' + self.context if self.context else ''}"))

    def _output(self, command: np.ndarray | None) -> Output:
        events, self._events = self._events, []
        return Output(command, self.zero_reason, self.ramp_scale, events,
                      extrapolation_scale=self.extrapolation_scale,
                      zero_cause=self.zero_cause)
