"""Expert potentials and the hand-space expert: known policies ``pi = -grad phi``.

Notation (paper, section II and eq. 20): state ``x`` (n,) (joint positions in rad, or
task-space positions in m), true potential ``phi(x)``, true policy ``pi(x) = -grad phi(x)``
in state units per second.

Hand-space expert (:class:`TaskSpaceExpert`): the state is ``x`` (3F,), the stacked
positions (m) of ``F`` frames, the expert's potential ``phi_x`` is a quadratic in ``x``
and its motion is ``xdot = N_x pi_x(x)`` with ``pi_x = -grad phi_x`` and ``N_x`` the
projector of hand-space constraint rows ``A_x`` (k, 3F), realised on the robot through
the frames' Jacobian ``J`` (3F, n) by the joint velocity of
:func:`policy_align_ros.control.resolved_rate.joint_velocity_within_limits`. A joint-space
expert seen in hand space is not a gradient field there, so it cannot stand in for a
hand-space one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from policy_align_ros.control.resolved_rate import (
    joint_velocity_within_limits,
    secondary_velocity,
)
from policy_align_ros.control.turns import nearest_turn
from policy_align_ros.kinematics import Robot, TaskSpaceMap, nullspace_projector

__all__ = [
    "QuadraticPotential",
    "StepResult",
    "TaskSpaceExpert",
    "TaskSpacePotential",
    "quadratic_gradient",
    "quadratic_value",
]

def quadratic_value(X: np.ndarray, center: np.ndarray, W: np.ndarray) -> np.ndarray:
    """``phi(x) = (x - c)^T W (x - c)`` for rows of ``X`` (m, n); returns (m,)."""
    d = X - center
    return np.einsum("mi,ij,mj->m", d, W, d)


def quadratic_gradient(X: np.ndarray, center: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Gradient ``(W + W^T)(x - c)`` of :func:`quadratic_value`; returns (m, n)."""
    return (X - center) @ (W + W.T)


def _weight_matrix(weight: float | np.ndarray, n: int) -> np.ndarray:
    w = np.asarray(weight, dtype=float)
    if w.ndim == 0:
        mat = float(w) * np.eye(n)
    elif w.shape == (n,):
        mat = np.diag(w)
    elif w.shape == (n, n):
        mat = w.copy()
    else:
        raise ValueError(f"weight: must be a scalar, ({n},) or ({n}, {n}), got {w.shape}")
    if not np.all(np.isfinite(mat)):
        raise ValueError("weight: contains NaN or inf")
    sym = 0.5 * (mat + mat.T)
    if np.linalg.eigvalsh(sym).min() <= 0.0:
        raise ValueError("weight: must be positive definite (a single attractor)")
    return mat


class QuadraticPotential:
    """Quadratic potential in the state itself (paper eq. 20).

    Parameters
    ----------
    center : array_like, shape (n,)
        Attractor ``x_c`` (state units).
    weight : float or array_like (n,) or (n, n)
        ``W`` (positive definite); the paper uses ``0.05 I`` with ``dt = 1``.
    """

    def __init__(self, center: Sequence[float], weight: float | np.ndarray = 0.05) -> None:
        self.center = np.asarray(center, dtype=float)
        if self.center.ndim != 1 or not np.all(np.isfinite(self.center)):
            raise ValueError(f"center: must be a finite (n,) vector, got {self.center.shape}")
        self.W = _weight_matrix(weight, self.center.size)

    @property
    def n(self) -> int:
        """State dimension."""
        return self.center.size

    def value(self, X: np.ndarray) -> np.ndarray:
        """Potential at rows of ``X`` (m, n); returns (m,)."""
        return quadratic_value(_rows(X, self.n), self.center, self.W)

    def gradient(self, X: np.ndarray) -> np.ndarray:
        """Gradient at rows of ``X`` (m, n); returns (m, n)."""
        return quadratic_gradient(_rows(X, self.n), self.center, self.W)

    def policy(self, X: np.ndarray) -> np.ndarray:
        """True policy ``-grad phi`` at rows of ``X`` (m, n); returns (m, n)."""
        return -self.gradient(X)


class TaskSpacePotential:
    """Quadratic potential of stacked frame positions, as a function of the joints.

    ``phi(q) = (p(q) - p_c)^T W (p(q) - p_c)`` with ``p`` (3f,) the stacked world positions
    (m) of ``frames``; ``grad phi = J^T (W + W^T)(p - p_c)`` with the stacked
    LOCAL_WORLD_ALIGNED translational Jacobian ``J`` (3f, n).

    Parameters
    ----------
    robot : Robot
    frames : sequence of str
        Frames whose positions are stacked (for example both hands).
    center : array_like, shape (3f,)
        Target positions, m.
    weight : float or array_like (3f,) or (3f, 3f)
    """

    def __init__(self, robot: Robot, frames: Sequence[str], center: Sequence[float],
                 weight: float | np.ndarray = 0.05) -> None:
        if isinstance(frames, str) or not frames:
            raise ValueError("frames: must be a non-empty list of frame names")
        for f in frames:
            robot.frame_id(f)
        self.robot = robot
        self.frames = list(frames)
        self.center = np.asarray(center, dtype=float)
        if self.center.shape != (3 * len(self.frames),):
            raise ValueError(
                f"center: must have shape ({3 * len(self.frames)},), got {self.center.shape}"
            )
        self.W = _weight_matrix(weight, self.center.size)

    @property
    def n(self) -> int:
        """State (joint) dimension."""
        return self.robot.nq

    def _task(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos, jac = self.robot.frames_kinematics(q, self.frames)
        return pos.reshape(-1), jac.reshape(-1, self.robot.nq)

    def value(self, X: np.ndarray) -> np.ndarray:
        """Potential at joint rows ``X`` (m, n); returns (m,)."""
        P = np.array([self._task(q)[0] for q in _rows(X, self.n)])
        return quadratic_value(P, self.center, self.W)

    def gradient(self, X: np.ndarray) -> np.ndarray:
        """Gradient at joint rows ``X`` (m, n); returns (m, n)."""
        out = []
        for q in _rows(X, self.n):
            p, jac = self._task(q)
            out.append(jac.T @ ((self.W + self.W.T) @ (p - self.center)))
        return np.array(out)

    def policy(self, X: np.ndarray) -> np.ndarray:
        """True policy ``-grad phi`` at joint rows ``X`` (m, n); returns (m, n)."""
        return -self.gradient(X)


def _rows(X: np.ndarray, n: int) -> np.ndarray:
    arr = np.asarray(X, dtype=float)
    if arr.ndim == 1:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != n:
        raise ValueError(f"X: must have shape (m, {n}), got {np.shape(X)}")
    return arr


@dataclass
class StepResult:
    """One demonstrator step: next state, recorded velocity and the ground truth.

    ``x_next`` (n,), ``velocity = N pi`` (n,), ``projector`` N (n, n), ``policy`` pi (n,),
    ``A`` (k, n).
    """

    x_next: np.ndarray
    velocity: np.ndarray
    projector: np.ndarray
    policy: np.ndarray
    A: np.ndarray


class TaskSpaceExpert:
    """An expert whose potential lives in hand space, driven through the joints.

    ``phi_x(x) = (x - x_c)^T W (x - x_c)`` over the stacked frame positions ``x`` (3F,),
    ``pi_x = -grad phi_x`` (m/s); under hand-space constraint rows ``A_x`` (k, 3F) the
    frames move with ``xdot = N_x pi_x``. The joint velocity realising it solves
    ``min ||J qdot - N_x pi_x||`` subject to ``A_x J qdot = 0`` and any joint-space rows
    ``A_q`` (k', n), with a secondary term toward ``rest`` and away from joint limits in the
    self-motion space.

    Parameters
    ----------
    state_map : TaskSpaceMap
        Joints -> stacked frame positions (and the Jacobian).
    center : array_like, shape (3F,)
        Targets of the frames, m.
    weight : float or array_like (3F,) or (3F, 3F)
        ``W`` (positive definite), 1/s when ``dt`` is in s.
    rest : array_like, shape (n,), optional
        Rest posture of the redundant joints (default the robot's reference posture).
    rest_gain, limit_gain, limit_margin, max_secondary, threshold, damping : float
        As for :class:`~policy_align_ros.control.task_policy.TaskSpacePolicy`.
    """

    def __init__(self, state_map: TaskSpaceMap, center: Sequence[float],
                 weight: float | np.ndarray = 0.5, *, rest: np.ndarray | None = None,
                 rest_gain: float = 0.5, limit_gain: float = 1.0, limit_margin: float = 0.1,
                 max_secondary: float = 0.5, threshold: float = 0.05,
                 damping: float = 0.05) -> None:
        self.state_map = state_map
        self.potential = QuadraticPotential(center, weight)
        if self.potential.n != state_map.dim:
            raise ValueError(f"center: must have shape ({state_map.dim},) for "
                             f"{len(state_map.frames)} frames, got ({self.potential.n},)")
        robot = state_map.robot
        self.rest = robot.neutral() if rest is None else np.asarray(rest, dtype=float)
        if self.rest.shape != (robot.nq,):
            raise ValueError(f"rest: must have shape ({robot.nq},), got {self.rest.shape}")
        self.secondary = {"rest_gain": rest_gain, "limit_gain": limit_gain,
                          "limit_margin": limit_margin, "max_speed": max_secondary}
        self.solve = {"threshold": threshold, "damping": damping}

    @property
    def n(self) -> int:
        """Joint dimension."""
        return self.state_map.n

    @property
    def dim(self) -> int:
        """Hand-space dimension ``3F``."""
        return self.state_map.dim

    def value(self, Q: np.ndarray) -> np.ndarray:
        """``phi_x`` at the hand states of joint rows ``Q`` (m, n); returns (m,)."""
        return self.potential.value(self.state_map.states(_rows(Q, self.n)))

    def task_policy(self, X: np.ndarray) -> np.ndarray:
        """``pi_x = -grad phi_x`` at hand-state rows ``X`` (m, 3F); returns (m, 3F), m/s."""
        return self.potential.policy(X)

    def command(self, q: np.ndarray, A_x: np.ndarray | None = None,
                A_q: np.ndarray | None = None, *,
                max_velocity: np.ndarray | float | None = None,
                dt: float | None = None) -> tuple[np.ndarray, StepResult]:
        """Joint velocity realising ``xdot = N_x pi_x`` at ``q`` (n,).

        With ``max_velocity`` and ``dt``, joints that would exceed their speed or cross a
        position limit within ``dt`` are held at that bound and the hand motion is
        redistributed over the other joints
        (:func:`~policy_align_ros.control.resolved_rate.joint_velocity_within_limits`).
        Scaling the whole command instead would record ``xdot = s N_x pi_x`` with
        ``s < 1``: not a projection of ``pi_x``, so the potential estimated from the
        recording would be wrong there.

        Parameters
        ----------
        q : numpy.ndarray, shape (n,)
        A_x : numpy.ndarray, shape (k, 3F), optional
            Hand-space constraint rows (none: ``N_x = I``).
        A_q : numpy.ndarray, shape (k', n), optional
            Further joint-space rows (for example locked joints).
        max_velocity : float or numpy.ndarray (n,), optional
            Joint speed limits, rad/s.
        dt : float, optional
            Control period, s.

        Returns
        -------
        qdot : numpy.ndarray, shape (n,)
            rad/s; zero on joints pushed against a limit.
        step : StepResult
            In hand space: ``x_next`` is ``x + xdot`` for a unit step (callers scale),
            ``velocity = N_x pi_x``, ``projector = N_x``, ``policy = pi_x``, ``A = A_x``.
        """
        q = np.asarray(q, dtype=float)
        x, J = self.state_map.kinematics(q)
        pi_x = self.task_policy(x[None])[0]
        A_x = np.zeros((0, self.dim)) if A_x is None else np.asarray(A_x, float)
        A_x = A_x.reshape(-1, self.dim)
        N_x = nullspace_projector(A_x, n=self.dim)
        xdot = N_x @ pi_x
        rows = [A_x @ J]
        if A_q is not None:
            rows.append(np.asarray(A_q, dtype=float).reshape(-1, self.n))
        robot = self.state_map.robot
        # A continuous joint turns to its rest posture the short way: the rest on q's turn.
        rest = nearest_turn(self.rest, np.where(robot.continuous, q, np.nan))
        z = secondary_velocity(q, rest, robot.lower, robot.upper, **self.secondary)
        qdot = joint_velocity_within_limits(q, J, xdot, np.vstack(rows), z, robot.lower,
                                            robot.upper, max_velocity=max_velocity, dt=dt,
                                            **self.solve)
        return qdot, StepResult(x + xdot, xdot, N_x, pi_x, A_x)
