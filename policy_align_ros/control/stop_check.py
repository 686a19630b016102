"""Before the executor arms: where the run from where the robot stands would stop, and
whether the model's CV folds agree (:mod:`policy_align_ros.learning.fold_stops`), ROS-free.

Under a constraint no demonstration showed, a run settles where the learnt potential is
lowest on the constraint, which may be an extrapolation across the demonstrated paths:
the extrapolation guard does not hold it (the run stays near the data), and the fit's
held-out errors do not show it. The CV folds' models, each fitted without some
demonstrations, tell: where they stop the same run elsewhere than the model, its stop is
uncertain by as much.

:class:`ArmingStopCheck` runs the model's policy and each fold model's through copies of
the executor's own :class:`~policy_align_ros.control.step.ControlStep` (the constraints in
force, held frames latched at the start, locked joints, speed and position limits; no
extrapolation guard, which would hold the folds' runs where the data ends), from the
joint positions at arming, for the model's
:func:`~policy_align_ros.learning.fold_stops.check_horizon`, in slices of wall time on
the executor's own thread (:class:`StopCheckRun`); constraints set while armed are checked
so too, from where the robot stands, a slice after each control step
(:class:`ArmedRecheck`). The stops are compared in
the model's state (joint positions, or the frames' positions of a task-space model), over
the run's travel there. The executor arms either way: the check informs, it does not
refuse (a run that stops elsewhere stops within the constraints and limits).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Awaitable, Callable

import numpy as np

from policy_align_ros.control.output import Output
from policy_align_ros.control.step import ControlStep
from policy_align_ros.control.task_policy import TaskSpacePolicy
from policy_align_ros.learning.fold_stops import (
    StopSpread,
    check_horizon,
    settled_speed,
    spread_of,
    typical_speed,
)

__all__ = ["MAX_SLOWDOWN", "RECHECK_SHARE", "SLICE_S", "ArmedRecheck", "ArmingStopCheck",
           "StopCheckRun", "check_in_slices", "fold_policies", "stop_check_answer",
           "stop_check_note", "unchanged"]

#: Runs slowed by the executor's speed limit are lengthened by at most this factor.
MAX_SLOWDOWN = 4.0
#: Share of the wall time between control steps (at most one period) that a check of
#: constraints set while armed (:class:`ArmedRecheck`) takes once a step's command is out;
#: a check of about 0.35 s of computing then ends within about 2 s.
RECHECK_SHARE = 0.2
#: Longest slice of a check (s): the executor's callbacks wait at most about this long,
#: and one run's step (:meth:`StopCheckRun.advance`).
SLICE_S = 0.005


def fold_policies(model, policy: Callable) -> list[Callable]:
    """The executor's policy made of each CV fold's model of ``model``.

    Parameters
    ----------
    model : PolicyAlign
        As loaded, with its ``fold_regressors_`` (none for files written before them).
    policy : callable
        The executor's policy of ``model`` (:func:`~policy_align_ros.control.loading.
        load_policy`): ``model.policy``, or a :class:`TaskSpacePolicy` of it.

    Returns
    -------
    list of callable
        One per fold model, taking and returning rows as ``policy`` does.
    """
    out = []
    for regressor in getattr(model, "fold_regressors_", ()):
        fold = copy.copy(model)
        fold.regressor_ = regressor
        out.append(policy.with_model(fold) if isinstance(policy, TaskSpacePolicy)
                   else fold.policy)
    return out


@dataclasses.dataclass(frozen=True)
class ArmingStopCheck:
    """A loaded model's fold-stop check (see the module's docstring); made by
    :meth:`for_model` at load, run at each arming.

    Attributes
    ----------
    policies : list of callable
        The executor's policy of the model, then each fold model's (:func:`fold_policies`).
    dt : float
        Step of a checked run (s).
    steps : int
        Its most steps (:func:`~policy_align_ros.learning.fold_stops.check_horizon`): a
        run that has stopped (``settled``) ends earlier.
    state : callable
        The model's state at joint positions (n,) in controller order.
    floor : float
        The model's support spacing: the travel at least, state units.
    settled : float
        A run whose state moves at most this fast (state units/s) has stopped
        (:func:`~policy_align_ros.learning.fold_stops.settled_speed`).
    speed : float or None
        The demonstrations' typical speed (rad/s) of a joint-state model: where the
        step's speed limit is below it, the runs are lengthened as they are slowed (at
        most :data:`MAX_SLOWDOWN` times); None for a task-space model.
    """

    policies: list
    dt: float
    steps: int
    state: Callable[[np.ndarray], np.ndarray]
    floor: float
    settled: float
    speed: float | None = None

    @classmethod
    def for_model(cls, model, policy: Callable, permutation: np.ndarray
                  ) -> ArmingStopCheck | None:
        """The check of ``model`` with its executor ``policy`` and joint ``permutation``
        (controller to model order); None when there is nothing to check: no fold models
        (a file written before they were kept) or no horizon (an untimed model, or a
        summary without the goal report)."""
        folds = fold_policies(model, policy)
        horizon = check_horizon(model)
        if not folds or horizon is None:
            return None
        speed = None
        if isinstance(policy, TaskSpacePolicy):
            def state(q):
                return policy.state_map.kinematics(np.asarray(q, dtype=float))[0]
        else:
            speed = typical_speed(model)

            def state(q):
                return np.asarray(q, dtype=float)[permutation]
        return cls([policy, *folds], *horizon, state, float(model.support_spacing_),
                   settled_speed(model), speed)

    def prepare(self, step: ControlStep, q0: np.ndarray) -> StopCheckRun:
        """The check of the run from ``q0`` (n,, controller order) under ``step`` as it is
        now (copied here: later changes to ``step`` do not reach it). Raises what latching
        the held frames at ``q0`` raises."""
        fields = [_stepped(step, p, self.dt, q0) for p in self.policies]
        slowdown = 1.0
        if self.speed is not None:
            slowdown = min(max(self.speed / float(np.min(step.max_velocity)), 1.0),
                           MAX_SLOWDOWN)
        return StopCheckRun(fields, np.array(q0, dtype=float), self.dt,
                            math.ceil(slowdown * self.steps), self.state, self.floor,
                            self.settled)


class StopCheckRun:
    """The runs of one :meth:`ArmingStopCheck.prepare`, advanced in slices of wall time,
    so that the executor's thread serves its other callbacks in between (no second
    thread shares the robot's kinematics data with it).

    Parameters
    ----------
    fields : list of callable
        Each run's command at rows (1, n): the model's first, then each fold model's.
    q0 : ndarray (n,)
        The start, rad, controller order.
    dt, steps, state, floor
        As :class:`ArmingStopCheck`'s (``steps``: at most).
    settled : float
        A run whose state would move at most this fast (state units/s) has stopped, and
        is not stepped further (0: every run takes ``steps`` steps).
    """

    def __init__(self, fields: list, q0: np.ndarray, dt: float, steps: int,
                 state: Callable[[np.ndarray], np.ndarray], floor: float,
                 settled: float = 0.0) -> None:
        self.fields, self.q0, self.dt, self.steps = fields, q0, dt, steps
        self.state, self.floor, self.settled = state, floor, settled
        self.done = 0  # sweeps over the runs still moving, counted as they start
        self.stepped = 0  # the runs' Euler steps, over all sweeps
        self._x = [q0.copy() for _ in fields]
        self._s = [state(q0)] * len(fields)  # each run's state, for its speed there
        self._moving = [True] * len(fields)
        self._next = 0  # the run whose step is next in this sweep

    def advance(self, budget_s: float = math.inf) -> bool:
        """Euler steps of the runs still moving, one run's step at a time, until
        ``budget_s`` s of wall time have passed (at least one step) or the runs are done;
        whether they are. One step is the finest slice: a budget below one policy call
        (a short control period) is overrun by at most one."""
        end = time.perf_counter() + budget_s
        while not self.finished:
            i = self._next
            self.done += i == 0
            self._next = (i + 1) % len(self.fields)
            if not self._moving[i]:
                continue
            x = self._x[i] + self.dt * self.fields[i](self._x[i][None])[0]
            s = self.state(x)
            self._moving[i] = bool(np.linalg.norm(s - self._s[i]) > self.settled * self.dt)
            if self._moving[i]:
                self._x[i], self._s[i] = x, s
            self.stepped += 1
            if time.perf_counter() >= end:
                break
        return self.finished

    @property
    def finished(self) -> bool:
        """Every run has stopped, or taken ``steps`` steps."""
        return (self.done >= self.steps and self._next == 0) or not any(self._moving)

    def result(self) -> StopSpread:
        """The :class:`StopSpread` of the runs, in the model's state units (advances them
        to the end first)."""
        self.advance()
        return spread_of(self.state(self.q0), self._s[0], self._s[1:], self.floor)


def unchanged(step: ControlStep) -> Callable[[], bool]:
    """Whether ``step`` still has the model check and the constraints it has now: loading
    a model sets a new ``stop_check``, and setting constraints a new list, so identity
    tells a later change (a check of the ones before is moot)."""
    check, constraints = step.stop_check, step.constraints
    return lambda: step.stop_check is check and step.constraints is constraints


async def check_in_slices(run: StopCheckRun, lock, slice_s: float,
                          pause: Callable[[], Awaitable], wanted: Callable[[], bool]
                          ) -> StopSpread | None:
    """``run`` advanced in slices of about ``slice_s`` s, each under ``lock``, awaiting
    ``pause()`` between them (an executor's next cycle: its other callbacks run); its
    :class:`StopSpread`, or None as soon as ``wanted()`` is false (superseded)."""
    while True:
        with lock:
            if not wanted():
                return None
            if run.advance(slice_s):
                return run.result()
        await pause()


class ArmedRecheck:
    """The check of constraints set while armed: the run from where the robot stands
    when they were set, under them, advanced by the executor a slice after each control
    step, once its command is out. A slice is :data:`RECHECK_SHARE` of the wall time since
    the last one, at most of one period and of :data:`SLICE_S`: control steps that come
    faster than the period (driven by joint states, or by a simulation faster than real
    time) get shorter slices. Constraints set again, another model, a disarm or the check
    turned off make it moot: it ends without a result.

    Parameters
    ----------
    controller : ArmedController
        The executor's, armed, with the new constraints in force in its step and a
        ``stop_check`` (not None) there.
    clock : callable
        Wall time, s.

    Raises what :meth:`ArmingStopCheck.prepare` raises.
    """

    def __init__(self, controller, clock: Callable[[], float] = time.perf_counter) -> None:
        step = controller.step
        self._unchanged = unchanged(step)
        self.run = step.stop_check.prepare(step, controller.last_q)
        self._clock = clock
        self._last = clock()

    @classmethod
    def begin(cls, controller, on: bool, clock: Callable[[], float] = time.perf_counter
              ) -> ArmedRecheck | None:
        """The check of ``controller``'s constraints just set; None when there is nothing
        to check: not armed, no state or no ``stop_check``, or the check is off (``on``
        false)."""
        if not (on and controller.armed and controller.step.stop_check is not None
                and controller.last_q is not None):
            return None
        return cls(controller, clock)

    def advance(self, controller, on: bool) -> tuple[bool, StopSpread | None]:
        """One slice: ``(ended, found)``, ``found`` the result when the runs are done
        (None while they go on, or when the check has become moot: ended without it).
        Raises RuntimeError where the step cannot command a run (as
        :meth:`StopCheckRun.advance` does)."""
        if not (on and controller.armed and self._unchanged()):
            return True, None
        now = self._clock()
        budget = RECHECK_SHARE * min(now - self._last, controller.step.dt)
        self._last = now
        if not self.run.advance(min(budget, SLICE_S)):
            return False, None
        return True, self.run.result()


def stop_check_note(found: StopSpread | None) -> str:
    """What the executor says of a check at arming: empty when the folds agree or nothing
    was checked, else the spread and the fix."""
    if found is None or not found.uncertain:
        return ""
    return (f"the CV folds' models stop this run up to {100 * found.spread:.0f} % of its "
            "travel from where the model stops it: where it stops under these constraints "
            "is uncertain (the demonstrations do not fix the potential there); watch it, or "
            "record demonstrations under these constraints and learn again")


def stop_check_answer(found: StopSpread | None, out: Output) -> str:
    """The ~/enable answer's note of the check at arming (empty, or ``"; warning: ..."``),
    its warning added to the arming's log lines ``out.events``."""
    note = stop_check_note(found)
    if not note:
        return ""
    out.events.append(("warning", f"armed: {note}"))
    return f"; warning: {note}"


def _stepped(step: ControlStep, policy: Callable, dt: float, q0: np.ndarray
             ) -> Callable[[np.ndarray], np.ndarray]:
    """``policy`` commanded through a copy of ``step`` with a period of ``dt`` s and no
    guard, its held frames latched at ``q0``, as a field of rows (1, n). A task-space
    policy is bound to the copy's constraints and velocity bounds, not the live step's.
    A step that cannot command (a policy failing, a constraint turning singular) raises
    RuntimeError with its reason: the run did not happen, so it tells nothing."""
    mine = copy.copy(step)
    mine.guard, mine.dt = None, dt
    if isinstance(policy, TaskSpacePolicy):
        policy = policy.bound_to(mine.constraint_matrix, mine.velocity_bounds)
    mine.policy = policy
    mine.latch(q0)

    def field(Q: np.ndarray) -> np.ndarray:
        qdot, reason, cause = mine(Q[0])
        if cause is not None:
            raise RuntimeError(f"a checked run stopped: {reason}")
        return qdot[None]

    return field
