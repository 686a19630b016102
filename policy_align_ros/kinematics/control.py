"""The executor's control law, ROS-free: ``qdot = s * N(q) pi_hat(q)``.

Notation and units: ``q`` joint positions (rad), ``pi_hat(q)`` the learnt unconstrained
policy (rad/s), ``A(q)`` the stacked constraint matrix (k, n) of the configured constraints,
``N = I - pinv(A) A`` its null-space projector, ``dt`` the control period (s).

Two safety rules shape the command:

* a joint sitting on a position limit and pushed outwards is *locked*, i.e. a unit row is
  appended to ``A`` and the policy is projected again, so the remaining joints still follow
  the policy within the constraints instead of the whole robot stalling;
* the projected velocity is scaled by one factor ``s in [0, 1]`` so that no joint exceeds
  its maximum speed and no joint crosses a limit within one period. One factor for the
  whole vector keeps the direction, hence ``A(q) qdot = 0``; clipping joints one by one
  would not.

Anything that prevents a safe command (non-finite state, no policy, a policy returning
non-finite values) gives zeros and a reason.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from policy_align_ros.kinematics.projection import nullspace_projector

__all__ = [
    "ControlStep",
    "constrained_command",
    "limit_locks",
    "model_permutation",
    "velocity_scale",
]

PolicyFn = Callable[[np.ndarray], np.ndarray]


class ConstraintModel(Protocol):
    """Anything giving ``A(q)`` of shape (k, n), k >= 0, given an intended ``qdot``."""

    def matrix(self, q: np.ndarray, qdot: np.ndarray | None = None) -> np.ndarray: ...


def limit_locks(
    q: np.ndarray,
    v: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    tol: float = 1e-9,
) -> np.ndarray:
    """Joints at (or beyond) a position limit whose velocity points outwards.

    Parameters
    ----------
    q, v : ndarray, shape (n,)
        Positions and candidate velocities.
    lower, upper : ndarray, shape (n,)
        Joint limits.
    tol : float
        Distance to a limit (units of ``q``) counted as touching it.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    return ((q >= upper - tol) & (v > 0.0)) | ((q <= lower + tol) & (v < 0.0))


def velocity_scale(
    q: np.ndarray,
    v: np.ndarray,
    dt: float,
    lower: np.ndarray,
    upper: np.ndarray,
    max_velocity: np.ndarray,
) -> float:
    """Largest ``s in [0, 1]`` such that ``s v`` respects speed and position limits.

    Parameters
    ----------
    q, v : ndarray, shape (n,)
        Positions and the velocity direction (units of ``q`` per second).
    dt : float
        Period (s) over which ``q + s v dt`` must stay within ``[lower, upper]``.
    lower, upper : ndarray, shape (n,)
        Joint limits.
    max_velocity : ndarray, shape (n,)
        Per-joint speed limits (> 0, may be inf).

    Returns
    -------
    float
        The scale; 0 when a joint at a limit is pushed outwards.
    """
    speed = np.abs(v)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_speed = np.where(speed > 0.0, max_velocity / speed, np.inf)
        room = np.where(v > 0.0, upper - q, np.where(v < 0.0, q - lower, np.inf))
        s_pos = np.where(speed > 0.0, np.maximum(room, 0.0) / (speed * dt), np.inf)
    return float(np.clip(min(np.min(s_speed, initial=np.inf), np.min(s_pos, initial=np.inf)),
                         0.0, 1.0))


def constrained_command(
    q: np.ndarray,
    pi: np.ndarray,
    A: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    max_velocity: np.ndarray,
    dt: float,
) -> np.ndarray:
    """Project ``pi`` onto the constraints' null space, lock limit joints, then scale.

    Parameters
    ----------
    q : ndarray, shape (n,)
        Current joint positions.
    pi : ndarray, shape (n,)
        Unconstrained policy at ``q`` (units of ``q`` per second).
    A : ndarray, shape (k, n)
        Constraint matrix at ``q`` (k >= 0).
    lower, upper, max_velocity : ndarray, shape (n,)
        Joint limits and speed limits.
    dt : float
        Control period (s).

    Returns
    -------
    ndarray, shape (n,)
        ``s N' pi`` with ``N'`` the projector of ``A`` stacked with unit rows of the locked
        joints, so ``A qdot = 0`` up to round-off, no speed limit is exceeded and no joint
        crosses a limit within ``dt``.
    """
    n = q.shape[0]
    rows = A
    v = nullspace_projector(rows) @ pi
    locked = np.zeros(n, dtype=bool)
    # Each pass locks at least one more joint, so this ends after at most n passes.
    for _ in range(n):
        new = limit_locks(q, v, lower, upper) & ~locked
        if not np.any(new):
            break
        locked |= new
        rows = np.vstack([A, np.eye(n)[locked]])
        v = nullspace_projector(rows) @ pi
    v[locked] = 0.0  # exact zeros where the projection leaves round-off
    return velocity_scale(q, v, dt, lower, upper, max_velocity) * v


def model_permutation(model_joints: Sequence[str] | None, joints: Sequence[str]) -> np.ndarray:
    """Indices ``p`` such that ``q[p]`` is ``q`` (ordered as ``joints``) in model order.

    Parameters
    ----------
    model_joints : sequence of str or None
        The joint names the model was trained on (None: trust the order of ``joints``).
    joints : sequence of str
        The controller's joint order.

    Returns
    -------
    ndarray of int, shape (n,)

    Raises
    ------
    ValueError
        If the two sets of names differ; the message lists the missing and extra names.
    """
    joints = list(joints)
    if model_joints is None:
        return np.arange(len(joints))
    model_joints = list(model_joints)
    missing = [j for j in model_joints if j not in joints]
    extra = [j for j in joints if j not in model_joints]
    if missing or extra or len(model_joints) != len(joints):
        raise ValueError(
            "model joints do not match the configured joints: "
            f"model needs {missing or 'nothing more'}, configured but not in the model "
            f"{extra or 'none'}"
        )
    index = {name: i for i, name in enumerate(joints)}
    return np.array([index[name] for name in model_joints], dtype=int)


class ControlStep:
    """One executor control step: joint positions in, joint velocity command out.

    Parameters
    ----------
    lower, upper : array_like, shape (n,)
        Joint position limits.
    max_velocity : array_like, shape (n,)
        Per-joint speed limits (> 0).
    dt : float
        Control period (s), used to stop joints before their limits.
    constraints : sequence of objects with ``matrix(q) -> (k, n)``
        Constraints in force; none means unconstrained.
    policy : callable, optional
        ``policy(X)`` with X of shape (1, n) in model joint order, returning (1, n) in rad/s
        (for example ``PolicyAlign.policy``). None means no model: commands are zeros.
    permutation : array_like of int, shape (n,), optional
        From :func:`model_permutation`; identity when omitted.
    """

    def __init__(
        self,
        lower: np.ndarray,
        upper: np.ndarray,
        max_velocity: np.ndarray,
        dt: float,
        constraints: Sequence[ConstraintModel] = (),
        policy: PolicyFn | None = None,
        permutation: np.ndarray | None = None,
    ) -> None:
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        n = self.lower.shape[0]
        self.max_velocity = np.broadcast_to(np.asarray(max_velocity, dtype=float), (n,)).copy()
        if np.any(~(self.max_velocity > 0.0)):
            raise ValueError("max_velocity: must be > 0 for every joint")
        if not dt > 0.0:
            raise ValueError(f"dt: must be > 0, got {dt}")
        self.dt = float(dt)
        self.constraints = list(constraints)
        self.policy = policy
        self.permutation = (
            np.arange(n) if permutation is None else np.asarray(permutation, dtype=int)
        )
        self._zeros = np.zeros(n)

    @property
    def n_joints(self) -> int:
        """Number of controlled joints ``n``."""
        return self.lower.shape[0]

    def constraint_matrix(self, q: np.ndarray, pi: np.ndarray | None = None) -> np.ndarray:
        """All constraint rows at ``q`` stacked, shape (k, n).

        ``pi`` (n,) is the intended velocity, which unilateral constraints (barriers) use
        to act only against motion towards them.
        """
        if not self.constraints:
            return np.zeros((0, self.n_joints))
        return np.vstack([np.asarray(c.matrix(q, pi), dtype=float) for c in self.constraints])

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, str]:
        """Command for positions ``q`` (n,) in controller order.

        Returns
        -------
        qdot : ndarray, shape (n,)
            Velocity command in rad/s; zeros when no safe command exists.
        reason : str
            Empty on a normal command, else why the command is zero.
        """
        if self.policy is None:
            return self._zeros.copy(), "no model loaded"
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_joints,) or not np.all(np.isfinite(q)):
            return self._zeros.copy(), "joint positions missing or not finite"
        p = self.permutation
        pi_model = np.asarray(self.policy(q[p][None, :]), dtype=float).reshape(-1)
        if pi_model.shape != (self.n_joints,) or not np.all(np.isfinite(pi_model)):
            return self._zeros.copy(), "policy output not finite"
        pi = np.empty(self.n_joints)
        pi[p] = pi_model
        A = self.constraint_matrix(q, pi)
        if not np.all(np.isfinite(A)):
            return self._zeros.copy(), "constraint matrix not finite"
        qdot = constrained_command(
            q, pi, A, self.lower, self.upper, self.max_velocity, self.dt
        )
        return qdot, ""
