"""Constraint models ``A(q)`` in joint space from Pinocchio frame Jacobians.

Notation (paper, eq. 2): a constraint ``A(q) qdot = 0`` with ``A`` of shape (k, n) over
the robot's selected joints ``q`` (n,) in rad / m. Frame positions ``p`` (3,) are in m in
the world frame, translational Jacobians ``J`` (3, n) are LOCAL_WORLD_ALIGNED. Rows are
unit-free combinations of ``J`` rows (m/rad), so only the row space of ``A`` matters.

Constraint kinds (each also available as data through :func:`constraint_from_spec`):

- ``plane``: the frame stays on a plane with normal ``n``: ``A = n^T J`` (1, n);
- ``position``: the frame is held along chosen world axes: ``A = S J`` (len(axes), n);
  :meth:`PositionConstraint.hold_position` gives the held coordinates ``S p`` so that a
  controller can latch them and correct the drift of integrating ``A qdot = 0``;
- ``barrier``: a plane (point ``c``, normal ``n``, optional rectangular ``region``) that
  blocks the frame's motion along ``n`` while the frame is within ``distance`` of it
  (``|n^T (p - c)| <= distance``); with ``unilateral`` (default) and a given intended
  velocity only when that velocity approaches the plane, so a hand may always recede.
  Inactive -> k = 0 rows. This is the paper's ball-grasp barrier (section IV-C);
- ``joints``: locked joints (selection rows of the identity);
- a list of specs: the stacked constraint.

The Cartesian maths (:func:`barrier_rows`) is shared with the task-space experiments, in
which the state is the frame position itself and ``J = I``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np
import yaml

from policy_align_ros.kinematics.robot import Robot, closest_names

__all__ = [
    "Constraint",
    "ConstraintModel",
    "PlaneConstraint",
    "PositionConstraint",
    "BarrierConstraint",
    "JointLockConstraint",
    "StackedConstraint",
    "constraint_from_spec",
    "parse_constraint_specs",
    "barrier_rows",
    "barrier_active",
]


class ConstraintModel(Protocol):
    """Anything giving ``A(q)`` of shape (k, n), k >= 0, given an intended ``qdot``."""

    def matrix(self, q: np.ndarray, qdot: np.ndarray | None = None) -> np.ndarray: ...


_AXES = {"x": 0, "y": 1, "z": 2}
# rcl reads a -p value as YAML: an unquoted list of mappings is no parameter type and kills
# the node ("Unknown YAML event"), so the list goes in YAML quotes inside the shell's.
_QUOTED_EXAMPLE = """-p 'constraints:="[{type: position, frame: tool0}]"'"""


def barrier_active(p: np.ndarray, point: np.ndarray, normal: np.ndarray, distance: float,
                   lower: np.ndarray | None = None, upper: np.ndarray | None = None,
                   velocity: np.ndarray | None = None, lookahead: float = 0.0) -> bool:
    """Whether a barrier blocks a frame at ``p`` (3,) moving with ``velocity`` (3,).

    Parameters
    ----------
    p, point, normal : numpy.ndarray, shape (3,)
        Frame position, a point on the barrier plane (m) and the unit plane normal.
    distance : float
        Activation distance in m: the barrier acts while ``|n^T (p - point)| <= distance``.
    lower, upper : numpy.ndarray, shape (3,), optional
        World box (m) outside of which the barrier does not exist (a finite panel: the
        gap between two panels is where neither box holds). Infinite entries allowed.
    velocity : numpy.ndarray, shape (3,), optional
        Intended Cartesian velocity of the frame; when given the barrier only acts if it
        approaches the plane (unilateral contact), so receding is never blocked.
    lookahead : float
        Time (s) over which ``velocity`` is extrapolated: the barrier also acts when the
        frame would cross the plane within it, so a discrete step of that length can
        never tunnel through a barrier thinner than the step.
    """
    signed = float(normal @ (p - point))
    crossing = False
    if velocity is not None and lookahead > 0.0:
        ahead = signed + lookahead * float(normal @ velocity)
        crossing = signed * ahead < 0.0
    if abs(signed) > distance and not crossing:
        return False
    if lower is not None and np.any(p < lower):
        return False
    if upper is not None and np.any(p > upper):
        return False
    if velocity is not None:
        # Approaching means reducing |signed distance|; exactly on the plane any normal
        # motion counts as approaching.
        towards = float(normal @ velocity) * (1.0 if signed >= 0.0 else -1.0)
        if towards >= 0.0 and signed != 0.0:
            return False
    return True


def barrier_rows(p: np.ndarray, point: np.ndarray, normal: np.ndarray, distance: float,
                 lower: np.ndarray | None = None, upper: np.ndarray | None = None,
                 velocity: np.ndarray | None = None, lookahead: float = 0.0) -> np.ndarray:
    """Cartesian constraint rows of a barrier: ``n^T`` (1, 3) if active, else (0, 3).

    Parameters are those of :func:`barrier_active`.
    """
    if barrier_active(p, point, normal, distance, lower, upper, velocity, lookahead):
        return np.asarray(normal, dtype=float).reshape(1, 3)
    return np.zeros((0, 3))


class Constraint:
    """Base class: a constraint on the robot's selected joints.

    Subclasses implement :meth:`matrix`. ``robot`` is the :class:`Robot` it acts on.
    """

    robot: Robot

    @property
    def n(self) -> int:
        """State (joint) dimension."""
        return self.robot.nq

    def matrix(self, q: np.ndarray, qdot: np.ndarray | None = None) -> np.ndarray:
        """Constraint matrix ``A(q)``, shape (k, n); ``k`` may be 0.

        Parameters
        ----------
        q : numpy.ndarray, shape (n,)
            Joint positions.
        qdot : numpy.ndarray, shape (n,), optional
            Intended (unconstrained) joint velocity; used by unilateral barriers only.
        """
        raise NotImplementedError

    def __add__(self, other: Constraint) -> StackedConstraint:
        return StackedConstraint([self, other])


class PlaneConstraint(Constraint):
    """A frame's position restricted to a plane of normal ``normal``: ``A = n^T J``."""

    def __init__(self, robot: Robot, frame: str, normal: Sequence[float]) -> None:
        robot.frame_id(frame)
        self.robot = robot
        self.frame = frame
        self.normal = _unit(normal, "normal")

    def matrix(self, q: np.ndarray, qdot: np.ndarray | None = None) -> np.ndarray:
        return (self.normal @ self.robot.frame_jacobian(q, self.frame)).reshape(1, -1)


class PositionConstraint(Constraint):
    """A frame's position held along world axes: ``A = S J`` with ``S`` selecting axes."""

    def __init__(self, robot: Robot, frame: str, axes: Sequence[str] = ("x", "y", "z")
                 ) -> None:
        robot.frame_id(frame)
        self.robot = robot
        self.frame = frame
        self.axes = _axes(axes)

    def matrix(self, q: np.ndarray, qdot: np.ndarray | None = None) -> np.ndarray:
        return self.robot.frame_jacobian(q, self.frame)[self.axes]

    def hold_position(self, q: np.ndarray) -> np.ndarray:
        """The held coordinates of the frame at ``q`` (n,): shape (len(axes),), m (world).

        The rows of :meth:`matrix` are their Jacobian, so a controller can latch them
        and correct drift (``ControlStep`` does).
        """
        return self.robot.frame_position(q, self.frame)[self.axes]


class BarrierConstraint(Constraint):
    """A plane barrier that blocks the frame's normal motion when within ``distance``.

    Parameters
    ----------
    robot : Robot
    frame : str
    point : sequence of 3 float
        A point of the barrier plane, m (world).
    normal : sequence of 3 float
        Plane normal (normalised here).
    distance : float
        Activation distance, m (> 0).
    lower, upper : sequence of 3 float, optional
        Box (m, world) limiting the barrier's extent; ``None`` entries/values = unbounded.
    unilateral : bool
        Block only approaching motion when ``qdot`` is passed to :meth:`matrix`.
    """

    def __init__(self, robot: Robot, frame: str, point: Sequence[float],
                 normal: Sequence[float], distance: float,
                 lower: Sequence[float | None] | None = None,
                 upper: Sequence[float | None] | None = None,
                 unilateral: bool = True) -> None:
        robot.frame_id(frame)
        self.robot = robot
        self.frame = frame
        self.point = _vec3(point, "point")
        self.normal = _unit(normal, "normal")
        if not np.isfinite(distance) or float(distance) <= 0.0:
            raise ValueError(f"distance: must be a positive number of m, got {distance!r}")
        self.distance = float(distance)
        self.lower = _bound(lower, "lower", -np.inf)
        self.upper = _bound(upper, "upper", np.inf)
        self.unilateral = bool(unilateral)

    def clearance(self, q: np.ndarray) -> tuple[float, np.ndarray | None]:
        """How far the frame is outside the activation shell, and the gradient.

        Returns
        -------
        c : float
            ``|n^T (p - point)| - distance`` (m): > 0 while the barrier cannot act yet.
        grad : ndarray, shape (n,), or None
            ``dc/dq`` (m/rad); None where the barrier does not exist (outside its box).
        """
        p = self.robot.frame_position(q, self.frame)
        if ((self.lower is not None and np.any(p < self.lower))
                or (self.upper is not None and np.any(p > self.upper))):
            return float("inf"), None
        signed = float(self.normal @ (p - self.point))
        side = 1.0 if signed >= 0.0 else -1.0
        grad = side * (self.normal @ self.robot.frame_jacobian(q, self.frame))
        return abs(signed) - self.distance, grad

    def active(self, q: np.ndarray, qdot: np.ndarray | None = None) -> bool:
        """Whether the barrier blocks motion at ``q`` (with intended ``qdot``)."""
        return self.matrix(q, qdot).shape[0] > 0

    def matrix(self, q: np.ndarray, qdot: np.ndarray | None = None) -> np.ndarray:
        p = self.robot.frame_position(q, self.frame)
        # Cheap distance test first: most states are far from the barrier.
        if abs(float(self.normal @ (p - self.point))) > self.distance:
            return np.zeros((0, self.n))
        jac = self.robot.frame_jacobian(q, self.frame)
        vel = None
        if self.unilateral and qdot is not None:
            vel = jac @ np.asarray(qdot, dtype=float)
        rows = barrier_rows(p, self.point, self.normal, self.distance, self.lower,
                            self.upper, vel)
        return rows @ jac


class JointLockConstraint(Constraint):
    """Locked joints: one selection row ``e_j^T`` per joint."""

    def __init__(self, robot: Robot, joints: Sequence[str]) -> None:
        if isinstance(joints, str) or not isinstance(joints, Sequence) or not joints:
            raise ValueError(f"joints: must be a non-empty list of joint names, got {joints!r}")
        idx = []
        for j in joints:
            if j not in robot.joint_names:
                raise ValueError(
                    f"joints: unknown joint {j!r}; closest valid names: "
                    f"{closest_names(str(j), robot.joint_names)}"
                )
            idx.append(robot.joint_names.index(j))
        if len(set(idx)) != len(idx):
            # Two rows e_j would make the constraint matrix singular: never enforceable.
            raise ValueError(f"joints: a joint is listed twice in {list(joints)!r}")
        self.robot = robot
        self.joints = list(joints)
        self._rows = np.eye(robot.nq)[idx]

    def matrix(self, q: np.ndarray, qdot: np.ndarray | None = None) -> np.ndarray:
        return self._rows.copy()


class StackedConstraint(Constraint):
    """Several constraints together: their rows stacked (k = sum of the k's)."""

    def __init__(self, parts: Sequence[Constraint]) -> None:
        parts = list(parts)
        if not parts:
            raise ValueError("constraints: empty list")
        robots = {id(c.robot) for c in parts}
        if len(robots) != 1:
            raise ValueError("constraints: all stacked constraints must use the same robot")
        self.robot = parts[0].robot
        self.parts = parts

    def matrix(self, q: np.ndarray, qdot: np.ndarray | None = None) -> np.ndarray:
        return np.vstack([c.matrix(q, qdot) for c in self.parts])


_SPEC_FIELDS: dict[str, tuple[set[str], set[str]]] = {
    # type -> (required fields, optional fields)
    "plane": ({"frame", "normal"}, set()),
    "position": ({"frame"}, {"axes"}),
    "barrier": ({"frame", "point", "normal", "distance"}, {"lower", "upper", "unilateral"}),
    "joints": ({"joints"}, set()),
}


def constraint_from_spec(spec: Mapping[str, Any] | Sequence[Mapping[str, Any]],
                         robot: Robot) -> Constraint:
    """Build a constraint from data (dicts that YAML or ROS parameters can carry).

    Parameters
    ----------
    spec : dict or list of dict
        ``{"type": "plane", "frame": F, "normal": [nx, ny, nz]}``,
        ``{"type": "position", "frame": F, "axes": ["x", "z"]}`` (default all axes),
        ``{"type": "barrier", "frame": F, "point": [..], "normal": [..], "distance": d,
        "lower": [..], "upper": [..], "unilateral": true}`` (box optional, ``null``
        entries unbounded), ``{"type": "joints", "joints": [names]}``; a list stacks.
    robot : Robot

    Returns
    -------
    Constraint

    Raises
    ------
    ValueError
        Naming the wrong field (missing, unknown, or bad value) and, for lists, the item.
    """
    if isinstance(spec, Mapping):
        return _one_spec(spec, robot)
    if isinstance(spec, (str, bytes)) or not isinstance(spec, Sequence):
        raise ValueError(
            f"constraint spec: expected a dict or a list of dicts, got {type(spec).__name__}"
        )
    if not spec:
        raise ValueError("constraint spec: empty list")
    parts = []
    for i, item in enumerate(spec):
        if not isinstance(item, Mapping):
            raise ValueError(f"constraint spec [{i}]: expected a dict, got "
                             f"{type(item).__name__}")
        try:
            parts.append(_one_spec(item, robot))
        except ValueError as err:
            raise ValueError(f"constraint spec [{i}]: {err}") from None
    return parts[0] if len(parts) == 1 else StackedConstraint(parts)


def parse_constraint_specs(text: str | Sequence[Any] | None) -> list[dict]:
    """Parse the ``constraints`` parameter: a YAML/JSON list of constraint specs.

    Parameters
    ----------
    text : str, None or empty sequence
        For example ``"[{type: plane, frame: arm_left_7_link, normal: [0, 0, 1]}]"``; an
        empty string, ``"[]"``, None or an empty list means no constraint (rcl passes
        ``-p constraints:=[]`` on the command line as None: a list whose type it cannot
        tell).

    Returns
    -------
    list of dict

    Raises
    ------
    ValueError
        If the text is not YAML or not a list of mappings, or the value is of another
        type than a string (a non-empty list, a number: YAML on the command line that rcl
        read as something else), naming the parameter and the form it takes.
    """
    if text is None or (isinstance(text, (list, tuple)) and not text):
        return []
    if not isinstance(text, str):
        raise ValueError(
            f"constraints: expected a string holding a YAML list of constraint specs, got "
            f"{type(text).__name__} {text!r}; quote the list on the command line: "
            f"{_QUOTED_EXAMPLE}")
    if not text.strip():
        return []
    try:
        specs = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ValueError(f"constraints: not valid YAML: {err}") from None
    if specs is None:
        return []
    if isinstance(specs, dict):
        specs = [specs]
    if not isinstance(specs, list) or not all(isinstance(s, dict) for s in specs):
        raise ValueError("constraints: must be a list of mappings like {type: plane, ...}")
    return specs


def _one_spec(spec: Mapping[str, Any], robot: Robot) -> Constraint:
    if "type" not in spec:
        raise ValueError(f"field 'type' is missing (one of {', '.join(_SPEC_FIELDS)})")
    kind = spec["type"]
    if not isinstance(kind, str) or kind not in _SPEC_FIELDS:
        raise ValueError(
            f"field 'type': unknown constraint type {kind!r}; closest valid types: "
            f"{closest_names(str(kind), list(_SPEC_FIELDS))}"
        )
    required, optional = _SPEC_FIELDS[kind]
    for field in sorted(required):
        if field not in spec:
            raise ValueError(f"{kind} constraint: field {field!r} is missing")
    for field in spec:
        if field != "type" and field not in required | optional:
            raise ValueError(
                f"{kind} constraint: unknown field {field!r}; valid fields: "
                f"{', '.join(sorted(required | optional))}"
            )
    try:
        if kind == "plane":
            return PlaneConstraint(robot, _frame(spec), spec["normal"])
        if kind == "position":
            return PositionConstraint(robot, _frame(spec), spec.get("axes", ("x", "y", "z")))
        if kind == "barrier":
            unilateral = spec.get("unilateral", True)
            if not isinstance(unilateral, bool):
                raise ValueError(f"unilateral: must be true or false, got {unilateral!r}")
            dist = spec["distance"]
            if isinstance(dist, bool) or not isinstance(dist, (int, float)):
                raise ValueError(f"distance: must be a number of m, got {dist!r}")
            return BarrierConstraint(robot, _frame(spec), spec["point"], spec["normal"],
                                     float(dist), spec.get("lower"), spec.get("upper"),
                                     unilateral)
        return JointLockConstraint(robot, spec["joints"])
    except ValueError as err:
        raise ValueError(f"{kind} constraint: field {err}") from None


def _frame(spec: Mapping[str, Any]) -> str:
    frame = spec["frame"]
    if not isinstance(frame, str):
        raise ValueError(f"frame: must be a frame name, got {frame!r}")
    return frame


def _vec3(value: Any, name: str) -> np.ndarray:
    try:
        vec = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: must be 3 numbers, got {value!r}") from None
    if vec.shape != (3,):
        raise ValueError(f"{name}: must be 3 numbers, got shape {vec.shape}")
    if not np.all(np.isfinite(vec)):
        raise ValueError(f"{name}: contains NaN or inf")
    return vec


def _unit(value: Any, name: str) -> np.ndarray:
    vec = _vec3(value, name)
    norm = float(np.linalg.norm(vec))
    if norm < 1e-12:
        raise ValueError(f"{name}: must be a non-zero vector, got {value!r}")
    return vec / norm


def _bound(value: Any, name: str, default: float) -> np.ndarray | None:
    if value is None:
        return None
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 3:
        raise ValueError(f"{name}: must be 3 numbers or nulls, got {value!r}")
    try:
        out = np.array([default if v is None else v for v in value], dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: must be 3 numbers or nulls, got {value!r}") from None
    if np.any(np.isnan(out)):
        raise ValueError(f"{name}: contains NaN")
    return out


def _axes(axes: Any) -> list[int]:
    if isinstance(axes, str):
        axes = list(axes)
    if not isinstance(axes, Sequence) or not axes:
        raise ValueError(f"axes: must be a non-empty list of 'x', 'y', 'z', got {axes!r}")
    out = []
    for a in axes:
        if not isinstance(a, str) or a not in _AXES:
            raise ValueError(f"axes: unknown axis {a!r} (use 'x', 'y', 'z')")
        if _AXES[a] in out:
            raise ValueError(f"axes: axis {a!r} is listed twice")
        out.append(_AXES[a])
    return out
