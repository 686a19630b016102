"""Loading a model file as the executor's joint-space policy for its robot.

At start the executor needs the model file twice: the robot and joints it names (to build
the robot) and then the model (to make its policy for that robot). :class:`StartModel`
reads the file once for both, so they also come from one version of a file that the
learner may replace at any time, and holds what the executor decides about that file
before it runs: refused, failed to load, or given (and so preferred to the learner's).

:func:`install_model` makes a loaded model the armed controller's: its policy, guard and
turns, and what the executor says about it (a model that ``learn`` refused and wrote only
because it was forced, a learnt goal beyond the guard's reach or in a joint's margin:
:mod:`policy_align_ros.control.model_checks`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from policy_align_ros.control.armed import ArmedController, Output
from policy_align_ros.control.guard import (
    ExtrapolationGuard,
    FrameSupportDistance,
    SupportDistance,
)
from policy_align_ros.control.joint_order import model_permutation
from policy_align_ros.control.limits import goal_in_margin
from policy_align_ros.control.model_checks import GoalReach, forced_model_warning, model_refusals
from policy_align_ros.control.stop_check import ArmingStopCheck
from policy_align_ros.control.task_policy import policy_for_state
from policy_align_ros.control.turns import turn_centres
from policy_align_ros.kinematics.robot import ROBOTS, Robot
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.goal import learnt_goal_index
from policy_align_ros.learning.policy_file import model_robot_fields, read_robot_fields

__all__ = ["StartModel", "goal_margin_problem", "goal_reach", "install_model", "learnt_goal",
           "load_policy", "model_guard", "model_load_error", "model_turn_centres",
           "no_model_fix"]


@dataclass
class StartModel:
    """The model file given at start: read once for its robot fields and its policy, and
    the executor's decisions about it.

    :meth:`robot_fields` serves as the ``read_fields`` of
    :func:`~policy_align_ros.nodes._common.declare_robot`; :meth:`take` hands the model
    read then to :func:`load_policy` when the same path is loaded. The decisions, in the
    order the executor meets them: :meth:`refusal` (a file refused for the robot config),
    :meth:`load_failed` (a file that does not load stops the node), :meth:`given` (the
    ``model_path`` that was given), :meth:`follows_learner` and :meth:`ignored_announcement`
    (whether ``/learner/model`` replaces it).

    Attributes
    ----------
    refused : str
        Why the file given at start is not loaded (it contradicts ``robot_config``: the
        robot setup's ``model_refused``); empty when it is not refused.
    given_path : str
        The ``model_path`` given at start, loaded or not; empty without one.
    load_error : str
        The start-up error of a ``model_path`` given at start that does not load
        (:func:`model_load_error`); empty when it loaded or none was given.
    """

    refused: str = ""
    given_path: str = ""
    load_error: str = ""
    _path: str | None = field(default=None, init=False, repr=False)
    _model: PolicyAlign | None = field(default=None, init=False, repr=False)

    def robot_fields(self, path: str) -> tuple[str | None, list[str] | None]:
        """``(robot, joints)`` the model file at ``path`` names, as
        :func:`~policy_align_ros.learning.policy_file.read_robot_fields` reads them.

        The whole model is read and kept for :meth:`take`. A file that does not load as a
        model may still name them in its header: then the header is read (and the load's
        error is reported when the node loads the model).

        Raises
        ------
        ValueError, OSError
            For a file that is no policy_align model file.
        """
        try:
            self._model, self._path = PolicyAlign.load(path), path
        except (OSError, ValueError):
            self._model = self._path = None
            return read_robot_fields(path)
        return model_robot_fields(self._model)

    def take(self, path: str) -> PolicyAlign | None:
        """The model read by :meth:`robot_fields` when it was read from ``path``, else None;
        given once (a later load of the path reads the file again)."""
        model = self._model if path == self._path else None
        self._model = self._path = None
        return model

    def refusal(self, path: str) -> str:
        """The error to log when ``path``, the ``model_path`` given at start, is not loaded
        because it contradicts the robot config (:attr:`refused`), naming the file, why
        and what the executor does instead; empty when it is not refused (load it).

        A refused file's model, read for its robot fields, is released.
        """
        if not self.refused:
            return ""
        self.take(path)
        return (f"model_path {path} not loaded: {self.refused}. The executor starts "
                f"without a model (~/enable is refused until one loads)")

    def load_failed(self, path: str, err: Exception) -> None:
        """Note that ``path``, given at start, did not load (``err``): the node stops with
        :attr:`load_error` instead of rclpy's parameter-set failure."""
        self.load_error = model_load_error(path, err)

    def given(self, path: str) -> bool:
        """Note ``path`` as the ``model_path`` given at start (empty: none given); whether
        the parameter must then be set empty (a refused file is no model in use)."""
        self.given_path = path
        return bool(self.refused and path)

    def follows_learner(self, follow_learner: bool) -> bool:
        """Whether the executor loads the ``/learner/model`` announcements: when asked
        (``follow_learner``) or when no ``model_path`` was given at start.

        An explicit model file wins otherwise, also when it was refused at start: the file
        named is the one meant, not the learner's.
        """
        return follow_learner or not self.given_path

    def ignored_announcement(self, announced: str) -> str:
        """The note logged for a ``/learner/model`` announcement of ``announced`` that is not
        followed (:meth:`follows_learner` false): the model file given at start and the
        switch that follows the learner."""
        return (f"model announced on /learner/model ignored: {announced} (model_path "
                f"{self.given_path} was given at start; -p follow_learner:=true follows "
                f"the learner)")


def load_policy(path: str, robot: Robot, constraint: Callable | None = None,
                bounds: Callable | None = None, model: PolicyAlign | None = None
                ) -> tuple[PolicyAlign, Callable[[np.ndarray], np.ndarray], np.ndarray, str]:
    """Load a PolicyAlign model file and make its joint-space policy for ``robot``.

    A model naming the robot it was learnt for (``robot_``) must name ``robot`` (when
    both are example-robot-data names). A model learnt on joint positions must have been
    trained on ``robot``'s joints (in any order). A model learnt on frame positions (its
    ``state_definition_`` is ``{"type": "frames", ...}``) must have been learnt on the same
    robot (URDF, joints, locked posture) and frames; its task-space policy ``pi_x`` is
    mapped to joint velocities satisfying ``constraint`` by
    :func:`policy_align_ros.control.task_policy.policy_for_state`.

    Parameters
    ----------
    path : str
        Model file (.npz).
    robot : Robot
        The executor's robot, joints in command order.
    constraint : callable ``(q (n,), qdot (n,) or None) -> A (k, n)``, optional
        The joint-space constraints in force (the executor passes its
        ``ControlStep.constraint_matrix``, so parameter changes apply at once).
    bounds : callable ``q (n,) -> (lo, hi)``, optional
        Joint velocity bounds (rad/s) a task-space policy keeps to by redistributing its
        task (the executor passes its speed, position and braking limits).
    model : PolicyAlign, optional
        The model already read from ``path`` (:meth:`StartModel.take`); None reads it.

    Returns
    -------
    (model, policy, permutation, state)
        The model; ``policy(Q (m, n)) -> (m, n)`` in rad/s on rows in model joint order;
        the index array mapping command order to model order; a description of the
        model's state ("joints" or "frames F1, F2").

    Raises
    ------
    ValueError, FileNotFoundError, OSError
        For a missing or unreadable file, or a model that does not fit ``robot``.
    """
    if model is None:
        model = PolicyAlign.load(path)
    joints = list(robot.joint_names)
    learnt_for = getattr(model, "robot_", None)
    # Two robot names can be compared; a URDF path may be spelt differently for the same file.
    if learnt_for in ROBOTS and robot.name in ROBOTS and learnt_for != robot.name:
        raise ValueError(f"model {path}: learnt for robot {learnt_for!r}, the executor "
                         f"controls {robot.name!r}")
    state = getattr(model, "state_definition_", None)
    if state is None:
        if model.joint_names_ is None and model.n_features_in_ != len(joints):
            raise ValueError(f"model {path}: has {model.n_features_in_} state dimensions, "
                             f"the executor {len(joints)} joints")
        return model, model.policy, model_permutation(model.joint_names_, joints), "joints"
    kind = state.get("type") if isinstance(state, Mapping) else None
    if kind != "frames":
        raise ValueError(f"model {path}: state definition of type {kind!r} is not supported "
                         "(expected 'frames' or none for joint positions)")
    try:
        policy = policy_for_state(model, state, robot, constraint, bounds=bounds)
    except ValueError as err:
        raise ValueError(f"model {path}: {err}") from None
    # TaskSpacePolicy takes and returns rows in the robot's (command) joint order.
    frames = ", ".join(policy.state_map.frames)
    return model, policy, np.arange(len(joints)), f"frames {frames}"


def model_guard(model: PolicyAlign, policy: Callable, permutation: np.ndarray, state: str,
                max_extrapolation: float, max_extrapolation_rad: float
                ) -> tuple[ExtrapolationGuard | None, str]:
    """The extrapolation guard of a model that :func:`load_policy` loaded.

    Parameters
    ----------
    model, policy, permutation, state
        As :func:`load_policy` returns them.
    max_extrapolation, max_extrapolation_rad : float
        The executor's parameters of the same names.

    Returns
    -------
    (guard, problem)
        The guard on the distance to the model's data (in joint space for a joint-state
        model, in frame positions for a frames model) and ""; or None and why the model
        cannot have one (the command is then not guarded).
    """
    try:
        if state == "joints":
            distance = SupportDistance(model, permutation)
        else:
            distance = FrameSupportDistance(model, policy.state_map)
        return ExtrapolationGuard(distance, max_extrapolation,
                                  max_extrapolation_rad=max_extrapolation_rad), ""
    except (ValueError, AttributeError) as err:
        return None, f"extrapolation guard off for this model: {err}"


def model_turn_centres(model: PolicyAlign, state: str, robot: Robot,
                       permutation: np.ndarray) -> np.ndarray | None:
    """The turn each of ``robot``'s continuous joints was learnt on
    (:func:`~policy_align_ros.control.turns.turn_centres`) for a joint-state model; None
    for a frames model, which sees them through the kinematics on every turn alike, and
    for a model without its support states."""
    support = getattr(model, "support_states_", None)
    if state != "joints" or support is None:
        return None
    return turn_centres(support, robot.continuous, permutation)


def no_model_fix(node: str, follows_learner: bool) -> str:
    """How to give the executor ``node`` (its full name) a model, for an enable refused
    without one; ``follows_learner``: whether it loads the ``/learner/model``
    announcements."""
    fix = f"set model_path (policy-align param set {node} model_path FILE)"
    if follows_learner:
        return f"{fix} or run the learner, whose /learner/model the executor follows"
    return (f"{fix}; /learner/model is not followed because model_path was given at start "
            f"(-p follow_learner:=true follows it)")


def model_load_error(path: str, err: Exception) -> str:
    """The start-up error for a ``model_path`` that does not load: the file, why, and the
    fix (for a missing file, where a relative path was looked for)."""
    if isinstance(err, FileNotFoundError):
        where = Path(path).expanduser()
        fix = ("check the path" + ("" if where.is_absolute() else
                                   f" (a relative path is read from {Path.cwd()})"))
    else:
        fix = ("give a model file learnt for this robot's joints (by policy-align learn or "
               "the learner)")
    why = str(err)
    for prefix in (f"{path}: ", f"model {path}: "):  # the loaders' own naming of the file
        why = why.removeprefix(prefix)
    return (f"model_path: cannot load {path}: {why}; {fix}, or leave model_path unset to "
            f"start without a model and wait for /learner/model")


def learnt_goal(model: PolicyAlign) -> np.ndarray | None:
    """Where runs of ``model``'s policy are meant to come to rest (n,), in the model's state
    order and units: the minimum of its goal report (``fit_summary_["goal"]``) that
    :func:`~policy_align_ros.learning.goal.learnt_goal_index` calls the learnt goal; None
    when the fit found no minimum or has no goal report."""
    goal = (getattr(model, "fit_summary_", None) or {}).get("goal") or {}
    index = learnt_goal_index(goal)
    return None if index is None else np.asarray(goal["minima"][index]["point"], dtype=float)


def _goal_posture(model: PolicyAlign, permutation: np.ndarray) -> np.ndarray | None:
    """:func:`learnt_goal` as a posture in command order (``permutation`` maps command to
    model order); None for a model learnt on frame positions (its goal is no posture) or
    without a learnt minimum."""
    goal = None if getattr(model, "state_definition_", None) is not None else learnt_goal(model)
    if goal is None or len(goal) != len(permutation):
        return None
    q = np.empty(len(permutation))
    q[np.asarray(permutation)] = goal
    return q


def goal_margin_problem(model: PolicyAlign, permutation: np.ndarray, robot: Robot,
                        margin: float) -> str:
    """:func:`~policy_align_ros.control.limits.goal_in_margin` of ``model``'s
    :func:`learnt_goal` on ``robot``, whose joints ``permutation`` maps to the model's
    order (:func:`load_policy`); "" for a model learnt on frame positions (its goal is not
    a posture) or without a learnt minimum."""
    q = _goal_posture(model, permutation)
    if q is None:
        return ""
    return goal_in_margin(q, robot.lower, robot.upper, margin, list(robot.joint_names))


def goal_reach(model: PolicyAlign, permutation: np.ndarray,
               guard: ExtrapolationGuard | None) -> GoalReach | None:
    """The distance of ``model``'s :func:`learnt_goal` to its data as ``guard`` measures
    it; None without a guard or a learnt minimum, for a model learnt on frame positions
    (the reach in rad depends on the posture there), and when the distance cannot be
    measured."""
    q = _goal_posture(model, permutation)
    if q is None or guard is None:
        return None
    try:
        d, grad = guard.distance(q)
    except ValueError:
        return None
    norm = math.nan if grad is None else float(np.linalg.norm(grad))
    if not math.isfinite(float(d)) or (grad is not None and not norm > 0.0):
        return None
    return GoalReach(float(d), norm)


def install_model(controller: ArmedController, robot: Robot, path: str, model: PolicyAlign,
                  policy: Callable, permutation: np.ndarray, state: str, *,
                  max_extrapolation: float, max_extrapolation_rad: float) -> Output:
    """Make ``model``, loaded from ``path`` by :func:`load_policy` (with its ``policy``,
    ``permutation`` and ``state``), ``controller``'s (a swap: an armed controller ramps
    down).

    Sets the step's guard (:func:`model_guard`, with the executor's ``max_extrapolation``
    and ``max_extrapolation_rad``), its fold-stop check
    (:class:`~policy_align_ros.control.stop_check.ArmingStopCheck`), turn centres, the
    refusals of a model written only because it was forced
    (:func:`~policy_align_ros.control.model_checks.model_refusals`, which make
    :meth:`~policy_align_ros.control.step.ControlStep.model_check` refuse to arm unless
    ``allow_forced_model``) and the learnt goal's distance to the data
    (:func:`goal_reach`).

    Returns
    -------
    Output
        The swap's, with the load's log lines added to its events: the model loaded, and
        warnings for a guard that cannot be made, a forced model (naming the refusals), a
        learnt goal beyond the guard's reach (both distances and the fixes) and a learnt
        goal within ``joint_limit_margin`` of a limit.
    """
    out = controller.set_policy(policy, permutation, reason=f"model swap to {path}")
    step = controller.step
    step.guard, guard_problem = model_guard(model, policy, permutation, state,
                                            max_extrapolation, max_extrapolation_rad)
    step.turn_centres = model_turn_centres(model, state, robot, permutation)
    step.model_refusals = model_refusals(model)
    step.goal_reach = goal_reach(model, permutation, step.guard)
    step.stop_check = ArmingStopCheck.for_model(model, policy, permutation)
    controller.stop_spread = None  # the last arming's check was of another model
    notes = [guard_problem]
    if step.model_refusals:
        notes.append(forced_model_warning(path, step.model_refusals, step.allow_forced_model))
    if step.goal_reach is not None:
        notes.append(step.goal_reach.problem(step.guard, step.max_velocity,
                                             step.max_acceleration))
    notes.append(goal_margin_problem(model, permutation, robot, step.joint_limit_margin))
    out.events.append(("info", f"model loaded from {path} (state: {state})"))
    out.events.extend(("warning", note) for note in notes if note)
    return out
