"""Resolved-rate control in task space: the joint velocity realising a task velocity.

Notation and units: ``J`` (r, n) a task Jacobian (m/rad), ``xdot`` (r,) the wanted task
velocity (m/s), ``A`` (k, n) joint-space constraints ``A qdot = 0``, ``N_A = I - A^+ A``
(n, n), ``z`` (n,) a secondary joint velocity (rad/s). The joint velocity minimising
``||J qdot - xdot||`` subject to ``A qdot = 0`` is::

    qdot = (J N_A)^+ xdot + (N_A - (J N_A)^+ (J N_A)) z

where ``z`` only acts in the self-motion space (null space of both ``J`` and ``A``). The
pseudo-inverse of ``B = J N_A`` is damped on its small singular values only (numerical
filtering): a constraint creates singularities of ``B`` where neither ``J`` nor ``A`` is
singular, and an undamped inverse turns them into unbounded joint speeds.
"""

from __future__ import annotations

import numpy as np

from policy_align_ros.control.limits import joint_velocity_bounds
from policy_align_ros.kinematics.projection import DEFAULT_RCOND, nullspace_projector

__all__ = [
    "damped_pinv",
    "joint_velocity_within_limits",
    "secondary_velocity",
    "task_to_joint_velocity",
]


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
