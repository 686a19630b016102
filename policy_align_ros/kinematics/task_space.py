"""Task-space state: stacked frame positions, their Jacobian, and the map back to joints.

Notation and units:

- ``q`` (n,) joint positions of the robot's selected joints (rad or m), in the order of
  :attr:`Robot.joint_names`; ``Q`` (m, n) a joint trajectory;
- ``x`` (3F,) the task-space state: the positions (m) of ``F`` frames, stacked
  ``[p_1; ...; p_F]``, each expressed in the root frame (``universe``, the world, by
  default); ``X`` (m, 3F);
- ``J(q)`` (3F, n) the stacked translational Jacobian ``dx/dq`` (m/rad), taken with
  ``pin.LOCAL_WORLD_ALIGNED`` (origin at each frame, axes of the world) and rotated into
  the root frame;
- ``pi_x(x)`` (3F,) a task-space policy (m/s); ``A(q)`` (k, n) joint-space constraints
  ``A qdot = 0``; ``N_A = I - A^+ A`` (n, n);
- ``qdot`` (n,) the joint velocity (rad/s) that minimises ``||J qdot - pi_x||`` subject to
  ``A qdot = 0``::

      qdot = (J N_A)^+ pi_x + (N_A - (J N_A)^+ (J N_A)) z

  where ``z`` (n,) is a secondary joint velocity (rest posture, joint-limit avoidance)
  that only acts in the self-motion space (null space of both ``J`` and ``A``).

The pseudo-inverse of ``B = J N_A`` is damped on its small singular values only
(numerical filtering): a constraint creates singularities of ``B`` where neither ``J``
nor ``A`` is singular, and an undamped inverse turns them into unbounded joint speeds.

The state definition (:class:`FrameStateDefinition`) is what a model file records so a
model learnt in task space is only used on the robot whose kinematics produced its data.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from policy_align_ros.kinematics.control import ConstraintModel, joint_velocity_bounds
from policy_align_ros.kinematics.projection import DEFAULT_RCOND, nullspace_projector
from policy_align_ros.kinematics.robot import Robot, closest_names
from policy_align_ros.learning.state_spec import parse_state_spec
from policy_align_ros.learning.trajectory import Trajectory

__all__ = [
    "FrameStateDefinition",
    "TaskSpaceMap",
    "TaskSpacePolicy",
    "damped_pinv",
    "secondary_velocity",
    "task_to_joint_velocity",
    "joint_velocity_bounds",
    "joint_velocity_within_limits",
    "parse_state_spec",
    "policy_for_state",
    "LearningStateMap",
]

#: Default root frame: Pinocchio's world frame of a fixed-base model.
WORLD = "universe"


@dataclass(frozen=True)
class FrameStateDefinition:
    """What a task-space state is: which robot, joints and frames, and how it was built.

    Attributes
    ----------
    robot : str
        example-robot-data name or URDF path, as given to :meth:`Robot.load`.
    joints : tuple of str
        The ``n`` joints of the joint states, in state-map order.
    frames : tuple of str
        The ``F`` frames whose positions are stacked; the state has ``3F`` coordinates.
    root_frame : str
        Frame the positions are expressed in; must be fixed to the world.
    locked_posture : dict str -> list of float
        Configuration of every joint outside ``joints`` (rad or m).
    urdf_sha256 : str
        Hex SHA-256 of the URDF file.
    """

    robot: str
    joints: tuple[str, ...]
    frames: tuple[str, ...]
    root_frame: str
    locked_posture: dict[str, list[float]] = field(hash=False)
    urdf_sha256: str

    #: Tolerance (rad or m) when comparing locked postures.
    POSTURE_TOL = 1e-9

    @property
    def dim(self) -> int:
        """Task-space dimension ``3F``."""
        return 3 * len(self.frames)

    @classmethod
    def from_robot(cls, robot: Robot, frames: Sequence[str], root_frame: str = WORLD
                   ) -> FrameStateDefinition:
        """Definition of the stacked positions of ``frames`` of ``robot``.

        Raises
        ------
        ValueError
            For an unknown, repeated or empty frame list, or a root frame that moves
            with the robot's joints.
        """
        frames = _frame_list(frames)
        for f in frames:
            robot.frame_id(f)
        _check_root(robot, root_frame)
        return cls(robot=str(robot.name), joints=tuple(robot.joint_names),
                   frames=tuple(frames), root_frame=str(root_frame),
                   locked_posture={k: list(v) for k, v in robot.locked_posture.items()},
                   urdf_sha256=robot.urdf_sha256())

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict for a model header (``{"type": "frames", ...}``)."""
        return {"type": "frames", "robot": self.robot, "joints": list(self.joints),
                "frames": list(self.frames), "root_frame": self.root_frame,
                "locked_posture": {k: list(v) for k, v in self.locked_posture.items()},
                "urdf_sha256": self.urdf_sha256}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FrameStateDefinition:
        """Inverse of :meth:`to_dict`; raises ValueError naming a missing or bad field."""
        if not isinstance(data, Mapping):
            raise ValueError(f"state definition: expected a dict, got {type(data).__name__}")
        if data.get("type") != "frames":
            raise ValueError(f"state definition: field 'type' must be 'frames', got "
                             f"{data.get('type')!r}")
        for key in ("robot", "joints", "frames", "root_frame", "locked_posture",
                    "urdf_sha256"):
            if key not in data:
                raise ValueError(f"state definition: field {key!r} is missing")
        for key in ("robot", "root_frame", "urdf_sha256"):
            if not isinstance(data[key], str) or not data[key]:
                raise ValueError(f"state definition: field {key!r} must be a non-empty "
                                 f"string, got {data[key]!r}")
        for key in ("joints", "frames"):
            val = data[key]
            if (isinstance(val, str) or not isinstance(val, Sequence) or not val
                    or not all(isinstance(v, str) for v in val)):
                raise ValueError(f"state definition: field {key!r} must be a non-empty "
                                 f"list of names, got {val!r}")
        posture = data["locked_posture"]
        if not isinstance(posture, Mapping):
            raise ValueError("state definition: field 'locked_posture' must be a dict")
        clean: dict[str, list[float]] = {}
        for joint, values in posture.items():
            try:
                vec = [float(v) for v in values]
            except (TypeError, ValueError):
                raise ValueError(f"state definition: locked_posture[{joint!r}] must be a "
                                 f"list of numbers, got {values!r}") from None
            if not all(math.isfinite(v) for v in vec):
                raise ValueError(f"state definition: locked_posture[{joint!r}] is not "
                                 "finite")
            clean[str(joint)] = vec
        return cls(robot=data["robot"], joints=tuple(data["joints"]),
                   frames=tuple(_frame_list(data["frames"])), root_frame=data["root_frame"],
                   locked_posture=clean, urdf_sha256=data["urdf_sha256"])

    def check(self, robot: Robot, *, same_order: bool = True) -> None:
        """Raise ValueError naming what differs between this definition and ``robot``.

        Compared: the URDF's hash, the joints (and their order unless ``same_order`` is
        False: frame positions do not depend on it), the frames and root frame (they must
        exist) and the posture of the locked joints. A robot loaded by name and one
        loaded from the same URDF file match.
        """
        problems = []
        sha = robot.urdf_sha256()
        if sha != self.urdf_sha256:
            problems.append(f"URDF differs (model: robot {self.robot!r} sha256 "
                            f"{self.urdf_sha256[:12]}..., here: robot {robot.name!r} sha256 "
                            f"{sha[:12]}...)")
        if (list(robot.joint_names) != list(self.joints) if same_order
                else sorted(robot.joint_names) != sorted(self.joints)):
            missing = [j for j in self.joints if j not in robot.joint_names]
            extra = [j for j in robot.joint_names if j not in self.joints]
            what = (f"missing {missing}, extra {extra}" if missing or extra
                    else "same joints in another order")
            problems.append(f"joints differ ({what})")
        for f in (*self.frames, self.root_frame):
            if f not in robot.frame_names:
                problems.append(f"frame {f!r} does not exist on robot {robot.name!r}")
        mine, theirs = self.locked_posture, robot.locked_posture
        if set(mine) != set(theirs):
            problems.append(
                f"locked joints differ (model only: {sorted(set(mine) - set(theirs))}, "
                f"robot only: {sorted(set(theirs) - set(mine))})")
        else:
            moved = [j for j in mine
                     if len(mine[j]) != len(theirs[j])
                     or not np.allclose(mine[j], theirs[j], atol=self.POSTURE_TOL, rtol=0)]
            if moved:
                problems.append(f"locked posture differs at {moved[:5]}"
                                + (f" and {len(moved) - 5} more" if len(moved) > 5 else ""))
        if not problems:
            try:
                _check_root(robot, self.root_frame)
            except ValueError as err:
                problems.append(str(err))
        if problems:
            raise ValueError("state definition does not match the robot: "
                             + "; ".join(problems))

    def load_robot(self) -> Robot:
        """Load the robot this definition describes and :meth:`check` it.

        Raises
        ------
        ValueError
            If the robot cannot be loaded or no longer matches (for example its URDF
            file changed).
        """
        reference = {j: v[0] for j, v in self.locked_posture.items() if len(v) == 1}
        robot = Robot.load(self.robot, list(self.joints), reference=reference)
        self.check(robot)
        return robot


def _frame_list(frames: Sequence[str]) -> list[str]:
    if isinstance(frames, (str, bytes)) or not isinstance(frames, Sequence) or not frames:
        raise ValueError(f"frames: must be a non-empty list of frame names, got {frames!r}")
    out = [str(f) for f in frames]
    if len(set(out)) != len(out):
        raise ValueError(f"frames: a frame is listed twice in {out}")
    return out


def _check_root(robot: Robot, root_frame: str) -> None:
    if root_frame not in robot.frame_names:
        raise ValueError(f"root_frame: unknown frame {root_frame!r}; closest valid names: "
                         f"{closest_names(str(root_frame), robot.frame_names)}")
    fid = robot.frame_id(root_frame)
    # Positions in a moving root would need the root's Jacobian too; a frame attached to
    # the universe joint (0) of the reduced model does not move with any selected joint.
    if robot.model.frames[fid].parentJoint != 0:
        raise ValueError(f"root_frame: {root_frame!r} moves with the selected joints; "
                         "choose a frame fixed to the world (for example 'universe')")


class TaskSpaceMap:
    """Joint positions -> stacked frame positions, and their Jacobian, for one robot.

    The Pinocchio model is the robot's; the data is built once here, so a map shares no
    scratch state with the robot's own methods.

    Parameters
    ----------
    robot : Robot
    frames : sequence of str
        ``F`` frames.
    root_frame : str
        Frame (fixed to the world) the positions are expressed in.

    Attributes
    ----------
    definition : FrameStateDefinition
    """

    def __init__(self, robot: Robot, frames: Sequence[str], root_frame: str = WORLD
                 ) -> None:
        self.definition = FrameStateDefinition.from_robot(robot, frames, root_frame)
        self.robot = robot
        self.frames = list(self.definition.frames)
        self._fids = [robot.frame_id(f) for f in self.frames]
        model = robot.model
        self._model = model
        self._data = model.createData()
        # Public joint order -> Pinocchio configuration / tangent indices.
        ids = [model.getJointId(j) for j in robot.joint_names]
        self._iq = np.array([model.joints[i].idx_q for i in ids], dtype=int)
        self._iv = np.array([model.joints[i].idx_v for i in ids], dtype=int)
        self._q = pin.neutral(model)
        pin.forwardKinematics(model, self._data, self._q)
        root = pin.updateFramePlacement(model, self._data, robot.frame_id(root_frame))
        self._rot = np.array(root.rotation).T  # world -> root axes
        self._origin = np.array(root.translation)

    @property
    def n(self) -> int:
        """Joint dimension."""
        return self.robot.nq

    @property
    def dim(self) -> int:
        """Task-space dimension ``3F``."""
        return 3 * len(self.frames)

    def _set(self, q: np.ndarray) -> np.ndarray:
        vec = np.asarray(q, dtype=float)
        if vec.shape != (self.n,):
            raise ValueError(f"q: must have shape ({self.n},), got {vec.shape}")
        if not np.all(np.isfinite(vec)):
            raise ValueError("q: contains NaN or inf")
        self._q[self._iq] = vec
        return self._q

    def states(self, Q: np.ndarray) -> np.ndarray:
        """Task-space states of a joint trajectory.

        Parameters
        ----------
        Q : array_like, shape (m, n) or (n,)
            Joint positions (rad or m).

        Returns
        -------
        numpy.ndarray, shape (m, 3F) (or (3F,) for one configuration)
            Stacked frame positions in m, in the root frame.

        Raises
        ------
        ValueError
            If ``Q`` has the wrong shape or is not finite (naming the row).
        """
        arr = np.asarray(Q, dtype=float)
        single = arr.ndim == 1
        rows = arr[None] if single else arr
        if rows.ndim != 2 or rows.shape[1] != self.n:
            raise ValueError(f"Q: must have shape (m, {self.n}), got {arr.shape}")
        out = np.empty((rows.shape[0], len(self._fids), 3))
        for i, q in enumerate(rows):
            if not np.all(np.isfinite(q)):
                raise ValueError(f"Q: row {i} contains NaN or inf")
            pin.forwardKinematics(self._model, self._data, self._set(q))
            pin.updateFramePlacements(self._model, self._data)
            for f, fid in enumerate(self._fids):
                out[i, f] = self._data.oMf[fid].translation
        out = (out - self._origin) @ self._rot.T
        flat = out.reshape(rows.shape[0], -1)
        return flat[0] if single else flat

    __call__ = states

    def kinematics(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State ``x`` (3F,) in m and Jacobian ``J`` (3F, n) in m/rad at ``q`` (n,)."""
        qq = self._set(q)
        pin.computeJointJacobians(self._model, self._data, qq)
        pin.updateFramePlacements(self._model, self._data)
        x = np.empty((len(self._fids), 3))
        jac = np.empty((len(self._fids), 3, self.n))
        for f, fid in enumerate(self._fids):
            x[f] = self._data.oMf[fid].translation
            full = pin.getFrameJacobian(self._model, self._data, fid,
                                        pin.LOCAL_WORLD_ALIGNED)
            jac[f] = self._rot @ full[:3, self._iv]
        x = (x - self._origin) @ self._rot.T
        return x.reshape(-1), jac.reshape(-1, self.n)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """Stacked translational Jacobian ``J`` (3F, n) at ``q`` (n,), m/rad."""
        return self.kinematics(q)[1]


def damped_pinv(B: np.ndarray, threshold: float = 0.05, damping: float = 0.05,
                rcond: float = DEFAULT_RCOND) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-inverse of ``B`` damped on its small singular values, and its row basis.

    Each singular value ``s < threshold`` is inverted as ``s / (s^2 + l^2)`` with
    ``l^2 = damping^2 (1 - (s / threshold)^2)``; larger ones are inverted exactly. So the
    inverse is exact away from singularities and its gain is bounded by about
    ``1 / damping`` (for ``damping <= threshold``) at them.

    Parameters
    ----------
    B : array_like, shape (r, n)
    threshold : float
        Singular value (units of ``B``) below which damping starts (>= 0).
    damping : float
        Damping at a zero singular value (units of ``B``, >= 0).
    rcond : float
        Relative cut-off below which a singular direction counts as absent.

    Returns
    -------
    pinv : numpy.ndarray, shape (n, r)
    row_basis : numpy.ndarray, shape (n, rank)
        Orthonormal basis of the row space of ``B`` (right singular vectors kept), so
        ``row_basis @ row_basis.T`` is the exact ``B^+ B``.
    """
    mat = np.asarray(B, dtype=float)
    r, n = mat.shape
    if r == 0:
        return np.zeros((n, 0)), np.zeros((n, 0))
    u, s, vt = np.linalg.svd(mat, full_matrices=False)
    keep = s > rcond * max(float(s[0]), np.finfo(float).tiny)
    lam2 = np.zeros_like(s)
    small = s < threshold
    lam2[small] = damping**2 * (1.0 - (s[small] / threshold) ** 2)
    inv = np.where(keep, s / np.where(keep, s**2 + lam2, 1.0), 0.0)
    return (vt.T * inv) @ u.T, vt[keep].T


def secondary_velocity(q: np.ndarray, rest: np.ndarray, lower: np.ndarray,
                       upper: np.ndarray, *, rest_gain: float = 0.5,
                       limit_gain: float = 1.0, limit_margin: float = 0.1,
                       max_speed: float = 0.5) -> np.ndarray:
    """Secondary joint velocity ``z`` (n,): toward ``rest``, away from joint limits.

    ``z = clamp(rest_gain (rest - q) + limit_gain * push)``, where ``push_i`` in [-1, 1]
    grows linearly from 0 to 1 across the last ``limit_margin`` fraction of joint ``i``'s
    range, pointing away from the nearer limit; the clamp scales ``z`` to a norm of at most
    ``max_speed`` (rad/s), so the self-motion never outruns the task.

    Parameters
    ----------
    q, rest, lower, upper : numpy.ndarray, shape (n,)
        Joint positions, rest posture and limits (rad or m; infinite limits allowed).
    rest_gain : float
        1/s.
    limit_gain : float
        rad/s at a limit.
    limit_margin : float
        Fraction of the range near each limit where the push acts, in (0, 0.5].
    max_speed : float
        Largest ``||z||``, rad/s.

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    q = np.asarray(q, dtype=float)
    z = rest_gain * (np.asarray(rest, dtype=float) - q)
    span = upper - lower
    finite = np.isfinite(span) & (span > 0)
    if np.any(finite):
        width = limit_margin * span[finite]
        near_lo = np.clip((width - (q[finite] - lower[finite])) / width, 0.0, 1.0)
        near_hi = np.clip((width - (upper[finite] - q[finite])) / width, 0.0, 1.0)
        z[finite] += limit_gain * (near_lo - near_hi)
    norm = float(np.linalg.norm(z))
    if norm > max_speed > 0.0:
        z *= max_speed / norm
    elif max_speed <= 0.0:
        z[:] = 0.0
    return z


def task_to_joint_velocity(J: np.ndarray, xdot: np.ndarray, A: np.ndarray,
                           z: np.ndarray | None = None, *, threshold: float = 0.05,
                           damping: float = 0.05, rcond: float = DEFAULT_RCOND
                           ) -> np.ndarray:
    """Joint velocity minimising ``||J qdot - xdot||`` subject to ``A qdot = 0``.

    ``qdot = (J N_A)^+ xdot + (N_A - (J N_A)^+ (J N_A)) z`` with the damped inverse of
    :func:`damped_pinv`. Both terms lie in the range of ``N_A``, so ``A qdot = 0`` holds
    to round-off whatever the damping; the second is the exact projector onto the
    self-motion space (null space of ``J`` within that of ``A``).

    Parameters
    ----------
    J : array_like, shape (r, n)
        Task Jacobian (m/rad).
    xdot : array_like, shape (r,)
        Wanted task velocity (m/s).
    A : array_like, shape (k, n)
        Constraint rows (k >= 0), including one unit row per locked joint.
    z : array_like, shape (n,), optional
        Secondary joint velocity (rad/s).
    threshold, damping, rcond : float
        See :func:`damped_pinv`.

    Returns
    -------
    numpy.ndarray, shape (n,)
        rad/s.
    """
    J = np.asarray(J, dtype=float)
    n = J.shape[1]
    N_A = nullspace_projector(np.asarray(A, dtype=float).reshape(-1, n), n, rcond)
    B = J @ N_A
    pinv, basis = damped_pinv(B, threshold, damping, rcond)
    # N_A pinv keeps round-off of B's right singular vectors out of A's row space.
    qdot = N_A @ (pinv @ np.asarray(xdot, dtype=float))
    if z is not None:
        zz = np.asarray(z, dtype=float)
        qdot += N_A @ zz - basis @ (basis.T @ zz)
    return qdot


def joint_velocity_within_limits(q: np.ndarray, J: np.ndarray, xdot: np.ndarray,
                                 A: np.ndarray, z: np.ndarray | None, lower: np.ndarray,
                                 upper: np.ndarray, *, max_velocity: np.ndarray | float |
                                 None = None, dt: float | None = None,
                                 bounds: tuple[np.ndarray, np.ndarray] | None = None,
                                 threshold: float = 0.05, damping: float = 0.05
                                 ) -> np.ndarray:
    """:func:`task_to_joint_velocity` with joints held to their limits in the null space.

    Saturation in the null space (Flacco, De Luca and Khatib, 2012): a joint whose
    velocity leaves its bounds (:func:`joint_velocity_bounds`) is fixed at the bound it
    crossed, as an equality ``e_j^T qdot = b_j`` beside ``A qdot = 0``, and the problem is
    solved again, so the task is redistributed over the joints that can still move
    instead of being slowed down as a whole. A joint pushed against a position limit is
    fixed at 0, which is the same unit row in ``A`` as a locked joint (zeroing the
    component afterwards would break both the task and ``A qdot = 0``).

    Without ``max_velocity``, ``dt`` or ``bounds`` only joints at a limit are fixed. With
    them, joints are held at their bounds only where the others realise the task as
    well as without them (up to round-off); otherwise the result is that of joints at a
    limit only, and callers that must respect the bounds scale it as a whole (for example
    ``control.velocity_scale``), which keeps its direction.

    Parameters
    ----------
    q : numpy.ndarray, shape (n,)
        Joint positions (rad or m).
    J, xdot, A, z
        As in :func:`task_to_joint_velocity`.
    lower, upper : numpy.ndarray, shape (n,)
        Joint limits.
    max_velocity : float or numpy.ndarray (n,), optional
        Speed limits, rad/s.
    dt : float, optional
        Period over which no joint may cross a position limit, s.
    bounds : (lo, hi), optional
        Per-joint bounds (n,) in rad/s used instead of those from ``lower``, ``upper``,
        ``max_velocity`` and ``dt`` (see :func:`joint_velocity_bounds`).
    threshold, damping : float
        See :func:`damped_pinv`.

    Returns
    -------
    numpy.ndarray, shape (n,)
        rad/s.
    """
    n = q.shape[0]
    A = np.asarray(A, dtype=float).reshape(-1, n)
    J = np.asarray(J, dtype=float)
    xdot = np.asarray(xdot, dtype=float)
    solve = {"threshold": threshold, "damping": damping}
    at_limit = joint_velocity_bounds(q, lower, upper)
    qdot = _held_at_bounds(J, xdot, A, z, at_limit, solve)
    if bounds is None and max_velocity is None and dt is None:
        return qdot
    lo, hi = (joint_velocity_bounds(q, lower, upper, max_velocity, dt) if bounds is None
              else bounds)
    if np.all((qdot >= lo) & (qdot <= hi)):
        return qdot
    held = _held_at_bounds(J, xdot, A, z, (lo, hi), solve)
    # Only where the free joints make up for the held ones: a task they cannot realise
    # would come out bent, and the caller's scaling of the whole command keeps its
    # direction instead.
    slack = 1e-6 * float(np.linalg.norm(xdot)) + 1e-12
    if np.linalg.norm(J @ held - xdot) <= np.linalg.norm(J @ qdot - xdot) + slack:
        return held
    return qdot


def _held_at_bounds(J: np.ndarray, xdot: np.ndarray, A: np.ndarray, z: np.ndarray | None,
                    bounds: tuple[np.ndarray, np.ndarray], solve: dict[str, float]
                    ) -> np.ndarray:
    """:func:`task_to_joint_velocity` with joints leaving ``bounds`` held at them."""
    lo, hi = bounds
    n = J.shape[1]
    qdot = task_to_joint_velocity(J, xdot, A, z, **solve)
    fixed = np.zeros(n, dtype=bool)
    value = np.zeros(n)
    N_A = None  # A's null-space projector, the same on every pass
    # Each pass fixes at least one more joint, so this ends after at most n passes.
    for _ in range(n):
        new = ((qdot > hi) | (qdot < lo)) & ~fixed
        if not np.any(new):
            break
        fixed |= new
        value[new] = np.clip(qdot[new], lo[new], hi[new])
        # The fixed joints' share: the least-norm motion within A's null space that
        # gives them their values (as near as A allows, so A qdot = 0 stays exact); the
        # task's remainder goes to the joints left free.
        base = np.zeros(n)
        if np.any(value[fixed]):
            if N_A is None:
                N_A = nullspace_projector(A, n) if A.shape[0] else np.eye(n)
            base = N_A @ (np.linalg.pinv(N_A[fixed]) @ value[fixed])
        C = np.vstack([A, np.eye(n)[fixed]])
        qdot = base + task_to_joint_velocity(J, xdot - J @ base, C, z, **solve)
    return qdot


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
        Damping of ``(J N_A)^+``, m/rad, see :func:`damped_pinv`.
    bounds : callable ``q (n,) -> (lo, hi)``, optional
        Per-joint velocity bounds (rad/s) the command must respect, for example the
        executor's speed, position and braking limits (:func:`joint_velocity_bounds`).
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

    def task_policy(self, x: np.ndarray) -> np.ndarray:
        """``pi_x(x)`` (3F,) in m/s at the state ``x`` (3F,)."""
        return np.asarray(self._policy(np.asarray(x, dtype=float)[None]),
                          dtype=float).reshape(-1)

    def command(self, q: np.ndarray) -> np.ndarray:
        """Joint velocity (n,) in rad/s at ``q`` (n,); NaN if the task-space policy or the
        constraint matrix is not finite, so that a controller stops and reports a fault
        (:class:`~policy_align_ros.kinematics.control.ControlStep` does) rather than take
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
        z = secondary_velocity(q, self.rest, self.lower, self.upper, **self.gains)
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


class LearningStateMap:
    """Joint trajectories -> frame-state trajectories, for a learning pipeline.

    A callable: a joint trajectory (a :class:`Trajectory` or an (m, n) array, joints in
    ``robot.joint_names`` order) in, the same in task space out (positions (m, 3F) in m;
    joint velocities, when given, mapped through ``J(q)``). :meth:`definition` gives the
    JSON-able state definition for the model header, with ``rest``: the mean final posture
    (joint -> rad) of the trajectories mapped so far, the executor's default rest posture
    for the redundant joints.

    Parameters
    ----------
    robot : Robot
    frames : sequence of str
    root_frame : str
    """

    def __init__(self, robot: Robot, frames: Sequence[str], root_frame: str = WORLD
                 ) -> None:
        self.map = TaskSpaceMap(robot, frames, root_frame)
        self._finals: list[np.ndarray] = []

    @property
    def joint_names(self) -> list[str]:
        """Joint order the map expects."""
        return list(self.map.robot.joint_names)

    def __call__(self, traj: Trajectory | np.ndarray) -> Trajectory | np.ndarray:
        """Map one joint trajectory; see the class docstring. Raises ValueError."""
        if not isinstance(traj, Trajectory):
            X = self.map.states(traj)
            self._finals.append(np.asarray(traj, dtype=float).reshape(-1, self.map.n)[-1])
            return X
        Q = traj.positions
        if Q.shape[1] != self.map.n:
            raise ValueError(f"trajectory {traj.name}: has {Q.shape[1]} joints, the state "
                             f"map expects {self.map.n} ({', '.join(self.joint_names)})")
        X = self.map.states(Q)
        V = None
        if traj.velocities is not None:
            V = np.array([self.map.jacobian(q) @ v for q, v in zip(Q, traj.velocities,
                                                                  strict=True)])
        self._finals.append(Q[-1].copy())
        return Trajectory(X, traj.times, V, name=traj.name)

    def definition(self) -> dict[str, Any]:
        """JSON-able state definition (``{"type": "frames", ..., "rest": {...}}``)."""
        out = self.map.definition.to_dict()
        if self._finals:
            mean = np.mean(self._finals, axis=0)
            out["rest"] = {j: float(v) for j, v in zip(self.joint_names, mean, strict=True)}
        return out
