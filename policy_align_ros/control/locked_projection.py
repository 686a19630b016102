"""Null-space projection with limit locks, ROS-free: ``v = N' pi``.

Notation and units: ``q`` joint positions (rad), ``pi`` a velocity (rad/s), ``A`` the
stacked constraint matrix (k, n), ``N = I - pinv(A) A`` its null-space projector.

A joint sitting on a position limit and pushed outwards by the projected velocity is
*locked*: a unit row is appended to ``A`` and ``pi`` is projected again onto the null
space ``N'`` of the grown matrix, so the remaining joints still follow ``pi`` within the
constraints instead of the whole robot stalling. :func:`project_with_locks` does this
for :class:`~policy_align_ros.control.step.ControlStep`; :func:`constrained_command`
adds the speed and position-limit scale of
:func:`~policy_align_ros.control.limits.velocity_scale` (the command of a step without
guard, barriers or drift correction, as the simulated demonstrators use it).
"""

from __future__ import annotations

import numpy as np

from policy_align_ros.control.limits import limit_locks, velocity_scale
from policy_align_ros.kinematics.projection import nullspace_projector

__all__ = ["constrained_command", "project_with_locks"]


def constrained_command(
    q: np.ndarray,
    pi: np.ndarray,
    A: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    max_velocity: np.ndarray,
    dt: float,
    max_acceleration: float | None = None,
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
    max_acceleration : float, optional
        Braking limit near joint limits (see :func:`velocity_scale`).

    Returns
    -------
    ndarray, shape (n,)
        ``s N' pi`` with ``N'`` the projector of ``A`` stacked with unit rows of the locked
        joints, so ``A qdot = 0`` up to round-off, no speed limit is exceeded and no joint
        crosses a limit within ``dt``.
    """
    v, _ = project_with_locks(q, pi, A, lower, upper)
    return velocity_scale(q, v, dt, lower, upper, max_velocity, max_acceleration) * v


def project_with_locks(
    q: np.ndarray,
    pi: np.ndarray,
    A: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    projector: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``N' pi`` and ``N'``: the projector of ``A`` plus unit rows of the locked joints.

    Parameters
    ----------
    q, pi : ndarray, shape (n,)
        Positions and the velocity to project (units of ``q`` per second).
    A : ndarray, shape (k, n)
        Constraint matrix at ``q`` (k >= 0).
    lower, upper : ndarray, shape (n,)
        Joint limits.
    projector : ndarray, shape (n, n), optional
        ``nullspace_projector(A)`` when the caller has it already (saves an SVD).

    Returns
    -------
    v : ndarray, shape (n,)
        The projected velocity, exactly 0 on locked joints.
    projector : ndarray, shape (n, n)
        ``N'``, so that a later command can be projected onto the same space.
    """
    n = q.shape[0]
    P = nullspace_projector(A, n) if projector is None else projector
    v = P @ pi
    locked = np.zeros(n, dtype=bool)
    # Each pass locks at least one more joint, so this ends after at most n passes.
    for _ in range(n):
        new = limit_locks(q, v, lower, upper) & ~locked
        if not np.any(new):
            break
        locked |= new
        P = nullspace_projector(np.vstack([A, np.eye(n)[locked]]))
        v = P @ pi
    v[locked] = 0.0  # exact zeros where the projection leaves round-off
    return v, P
