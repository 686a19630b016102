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
the executor's own thread (:class:`StopCheckRun`). The stops are compared in
the model's state (joint positions, or the frames' positions of a task-space model), over
the run's travel there. The executor arms either way: the check informs, it does not
refuse (a run that stops elsewhere stops within the constraints and limits).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Callable

import numpy as np

from policy_align_ros.control.output import Output
from policy_align_ros.control.step import ControlStep
from policy_align_ros.control.task_policy import TaskSpacePolicy
from policy_align_ros.learning.fold_stops import StopSpread, check_horizon, spread_of

__all__ = ["ArmingStopCheck", "StopCheckRun", "fold_policies", "stop_check_answer",
           "stop_check_note"]


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
        Its number of steps (:func:`~policy_align_ros.learning.fold_stops.check_horizon`).
    state : callable
        The model's state at joint positions (n,) in controller order.
    floor : float
        The model's support spacing: the travel at least, state units.
    """

    policies: list
    dt: float
    steps: int
    state: Callable[[np.ndarray], np.ndarray]
    floor: float

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
        if isinstance(policy, TaskSpacePolicy):
            def state(q):
                return policy.state_map.kinematics(np.asarray(q, dtype=float))[0]
        else:
            def state(q):
                return np.asarray(q, dtype=float)[permutation]
        return cls([policy, *folds], *horizon, state, float(model.support_spacing_))

    def prepare(self, step: ControlStep, q0: np.ndarray) -> StopCheckRun:
        """The check of the run from ``q0`` (n,, controller order) under ``step`` as it is
        now (copied here: later changes to ``step`` do not reach it)."""
        fields = [_stepped(step, p, self.dt, q0) for p in self.policies]
        return StopCheckRun(fields, np.array(q0, dtype=float), self.dt, self.steps,
                            self.state, self.floor)


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
        As :class:`ArmingStopCheck`'s.
    """

    def __init__(self, fields: list, q0: np.ndarray, dt: float, steps: int,
                 state: Callable[[np.ndarray], np.ndarray], floor: float) -> None:
        self.fields, self.q0, self.dt, self.steps = fields, q0, dt, steps
        self.state, self.floor = state, floor
        self.done = 0  # steps taken by every run
        self._x = [q0.copy() for _ in fields]

    def advance(self, budget_s: float = math.inf) -> bool:
        """Euler steps of every run until ``budget_s`` s of wall time have passed (at
        least one step) or the runs are done; whether they are."""
        end = time.perf_counter() + budget_s
        while self.done < self.steps:
            for i, field in enumerate(self.fields):
                self._x[i] = self._x[i] + self.dt * field(self._x[i][None])[0]
            self.done += 1
            if time.perf_counter() >= end:
                break
        return self.done >= self.steps

    def result(self) -> StopSpread:
        """The :class:`StopSpread` of the runs, in the model's state units (advances them
        to the end first)."""
        self.advance()
        ends = [self.state(x) for x in self._x]
        return spread_of(self.state(self.q0), ends[0], ends[1:], self.floor)


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
    guard, its held frames latched at ``q0``, as a field of rows (1, n)."""
    mine = copy.copy(step)
    mine.policy, mine.guard, mine.dt = policy, None, dt
    mine.latch(q0)
    return lambda Q: mine(Q[0])[0][None]
