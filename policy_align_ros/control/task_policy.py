"""A task-space policy run as a joint-space one, and its construction from a model header.

``pi_x(x)`` (3F,) in m/s over the stacked frame positions ``x = phi(q)`` (3F,) is mapped to
the joint velocity (rad/s) closest to it under the constraints in force
(:func:`~policy_align_ros.control.resolved_rate.joint_velocity_within_limits`).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from policy_align_ros.control.resolved_rate import (
    joint_velocity_within_limits,
    secondary_velocity,
    task_to_joint_velocity,
)
from policy_align_ros.control.turns import nearest_turn
from policy_align_ros.kinematics.constraints import ConstraintModel
from policy_align_ros.kinematics.robot import Robot
from policy_align_ros.kinematics.state_definition import FrameStateDefinition
from policy_align_ros.kinematics.task_space import TaskSpaceMap

__all__ = ["TaskSpacePolicy", "policy_for_state"]


class TaskSpacePolicy:
    """A task-space policy run as a joint-space one: ``q`` -> ``qdot`` (rad/s).

    Callable like ``PolicyAlign.policy`` (rows ``Q`` (m, n) in the state map's joint order
    -> (m, n)), so the executor can use it in place of a joint-space policy; its output
    already satisfies the constraints, so the executor's own projection leaves it as is.

    Parameters
    ----------
    policy : object with ``policy(X)`` or callable
        Task-space policy ``X`` (m, 3F) -> (m, 3F) in m/s, e.g. a fitted ``PolicyAlign``
        learnt on the map's states.
    state_map : TaskSpaceMap
    constraint : object with ``matrix(q, qdot) -> (k, n)``, or such a callable, optional
        Joint-space constraints in force (for example the executor's
        ``ControlStep.constraint_matrix``, which follows its parameter changes); barriers
        are judged with the velocity the task asks for without them.
    rest : array_like, shape (n,), optional
        Rest posture of the redundant joints (default the robot's reference posture),
        for example the demonstrations' mean final posture.
    rest_gain, limit_gain, limit_margin, max_secondary : float
        Secondary term, see :func:`secondary_velocity` (``max_secondary`` is its
        ``max_speed``).
    threshold, damping : float
        Damping of ``(J N_A)^+``, m/rad, see
        :func:`~policy_align_ros.control.resolved_rate.damped_pinv`.
    bounds : callable ``q (n,) -> (lo, hi)``, optional
        Per-joint velocity bounds (rad/s) the command must respect, for example the
        executor's speed, position and braking limits
        (:func:`~policy_align_ros.control.limits.joint_velocity_bounds`).
        A joint reaching one is held there and the task redistributed over the others
        (:func:`joint_velocity_within_limits`), so the executor does not have to slow the
        whole command down for one joint. Default: only joints at a limit are held.
    """

    def __init__(self, policy: Any, state_map: TaskSpaceMap,
                 constraint: ConstraintModel | None = None, *,
                 rest: np.ndarray | None = None, rest_gain: float = 0.5,
                 limit_gain: float = 1.0, limit_margin: float = 0.1,
                 max_secondary: float = 0.5, threshold: float = 0.05,
                 damping: float = 0.05,
                 bounds: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None
                 ) -> None:
        if constraint is not None and not hasattr(constraint, "matrix"):
            if not callable(constraint):
                raise ValueError("constraint: must have matrix(q, qdot) or be callable")
            constraint = _RowsFn(constraint)
        fn = getattr(policy, "policy", policy)
        if not callable(fn):
            raise ValueError("policy: must be callable or have a policy(X) method")
        dim = getattr(policy, "n_features_in_", None)
        if dim is not None and dim != state_map.dim:
            raise ValueError(f"policy: learnt on {dim}-D states, the state map gives "
                             f"{state_map.dim}-D states ({len(state_map.frames)} frames)")
        self._policy: Callable[[np.ndarray], np.ndarray] = fn
        self.state_map = state_map
        self.constraint = constraint
        robot = state_map.robot
        self.rest = robot.neutral() if rest is None else np.asarray(rest, dtype=float)
        if self.rest.shape != (robot.nq,) or not np.all(np.isfinite(self.rest)):
            raise ValueError(f"rest: must be a finite ({robot.nq},) posture, got shape "
                             f"{self.rest.shape}")
        for name, value in (("rest_gain", rest_gain), ("limit_gain", limit_gain),
                            ("max_secondary", max_secondary), ("threshold", threshold),
                            ("damping", damping)):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name}: must be a finite number >= 0, got {value!r}")
        if not 0.0 < limit_margin <= 0.5:
            raise ValueError(f"limit_margin: must be in (0, 0.5], got {limit_margin!r}")
        self.gains = {"rest_gain": rest_gain, "limit_gain": limit_gain,
                      "limit_margin": limit_margin, "max_speed": max_secondary}
        self.threshold = float(threshold)
        self.damping = float(damping)
        self.bounds = bounds
        self.lower = np.asarray(robot.lower, dtype=float)
        self.upper = np.asarray(robot.upper, dtype=float)
        self._continuous = np.asarray(robot.continuous, dtype=bool)

    def with_model(self, policy: Any) -> TaskSpacePolicy:
        """This policy with another task-space model's ``policy`` (a CV fold's model of
        the same state, :mod:`~policy_align_ros.control.stop_check`): the same map,
        constraint, rest posture, gains and bounds."""
        other = copy.copy(self)
        other._policy = getattr(policy, "policy", policy)
        return other

    def bound_to(self, constraint: ConstraintModel | Callable | None,
                 bounds: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None
                 ) -> TaskSpacePolicy:
        """This policy under another ``constraint`` and velocity ``bounds`` (as the
        constructor takes them): a copy of the executor's control step, run ahead of the
        robot (:mod:`~policy_align_ros.control.stop_check`)."""
        other = copy.copy(self)
        other.constraint = (constraint if constraint is None or hasattr(constraint, "matrix")
                            else _RowsFn(constraint))
        other.bounds = bounds
        return other

    def task_policy(self, x: np.ndarray) -> np.ndarray:
        """``pi_x(x)`` (3F,) in m/s at the state ``x`` (3F,)."""
        return np.asarray(self._policy(np.asarray(x, dtype=float)[None]),
                          dtype=float).reshape(-1)

    def command(self, q: np.ndarray) -> np.ndarray:
        """Joint velocity (n,) in rad/s at ``q`` (n,); NaN if the task-space policy or the
        constraint matrix is not finite, so that a controller stops and reports a fault
        (:class:`~policy_align_ros.control.step.ControlStep` does) rather than take
        a silent zero for a valid command and carry on once the output is finite again.

        Joints at a limit that the command would push further out (or beyond
        ``bounds``) are held by adding unit rows to ``A`` and solving again, so the task
        is redistributed over the joints that can still move.
        """
        q = np.asarray(q, dtype=float)
        x, J = self.state_map.kinematics(q)
        pi_x = self.task_policy(x)
        n = q.shape[0]
        if pi_x.shape != (J.shape[0],) or not np.all(np.isfinite(pi_x)):
            return np.full(n, np.nan)
        # A continuous joint's rest on the turn of its measured angle (drivers report it
        # modulo a turn): the rest term then turns it the short way, not up to a turn.
        rest = nearest_turn(self.rest, np.where(self._continuous, q, np.nan))
        z = secondary_velocity(q, rest, self.lower, self.upper, **self.gains)
        solve = {"threshold": self.threshold, "damping": self.damping}
        A = np.zeros((0, n))
        if self.constraint is not None:
            free = task_to_joint_velocity(J, pi_x, A, z, **solve)
            A = np.asarray(self.constraint.matrix(q, free), dtype=float).reshape(-1, n)
            if not np.all(np.isfinite(A)):
                return np.full(n, np.nan)
        bounds = None if self.bounds is None else self.bounds(q)
        return joint_velocity_within_limits(q, J, pi_x, A, z, self.lower, self.upper,
                                            bounds=bounds, **solve)

    def __call__(self, Q: np.ndarray) -> np.ndarray:
        """Joint velocities (m, n) at rows ``Q`` (m, n) (or (n,) -> (n,))."""
        arr = np.asarray(Q, dtype=float)
        if arr.ndim == 1:
            return self.command(arr)
        return np.array([self.command(q) for q in arr]).reshape(arr.shape)

    policy = __call__



class _RowsFn:
    """A ``(q, qdot) -> A`` callable seen as a constraint model."""

    def __init__(self, fn: Callable[[np.ndarray, np.ndarray | None], np.ndarray]) -> None:
        self.matrix = fn


def policy_for_state(model: Any, state: Mapping[str, Any], robot: Robot,
                     constraint: ConstraintModel | Callable | None = None, *,
                     rest: np.ndarray | None = None, **options: float) -> TaskSpacePolicy:
    """The joint-space policy callable of a model learnt on frame states.

    What an executor does with a model whose header's state definition is
    ``{"type": "frames", ...}``: check the definition against its own ``robot`` (same
    URDF, joints in any order, frames, locked posture), then map the task-space policy to
    joint velocities in the robot's joint order under ``constraint``.

    Parameters
    ----------
    model : object with ``policy(X (m, 3F)) -> (m, 3F)``
        The fitted task-space model.
    state : dict
        The model header's state definition (:meth:`FrameStateDefinition.to_dict`); its
        optional ``rest`` (dict joint -> rad) is the rest posture unless ``rest`` is given.
    robot : Robot
        The executor's robot, in its joint order.
    constraint : constraint model or callable ``(q, qdot) -> A (k, n)``, optional
    rest : array_like, shape (n,), optional
        Rest posture in the robot's joint order.
    **options
        Gains and damping of :class:`TaskSpacePolicy`.

    Returns
    -------
    TaskSpacePolicy
        Taking and returning rows in ``robot.joint_names`` order.

    Raises
    ------
    ValueError
        If the definition is malformed or does not match ``robot`` (naming what differs).
    """
    definition = FrameStateDefinition.from_dict(state)
    definition.check(robot, same_order=False)
    smap = TaskSpaceMap(robot, definition.frames, definition.root_frame)
    if rest is None and isinstance(state.get("rest"), Mapping):
        named = state["rest"]
        missing = [j for j in robot.joint_names if j not in named]
        if missing:
            raise ValueError(f"state definition: field 'rest' lacks joints {missing}")
        try:
            rest = np.array([float(named[j]) for j in robot.joint_names])
        except (TypeError, ValueError):
            raise ValueError("state definition: field 'rest' must map joints to "
                             "numbers") from None
    return TaskSpacePolicy(model, smap, constraint, rest=rest, **options)
