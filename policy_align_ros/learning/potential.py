"""Potential estimates along single trajectories (paper section III-A).

Notation: a trajectory ``x_1 ... x_N`` in ``R^n`` with time steps ``dt_i = t_{i+1} - t_i``
(seconds; ``dt = 1`` in the paper's units). For a potential-based policy ``pi = -grad phi``
observed through a projection ``xdot = N pi``, a step satisfies
``x_{i+1} - x_i ~= dt_i N_i pi_i`` and, because ``N`` is a symmetric idempotent projection,

    phi_{i+1} - phi_i ~= -(x_{i+1} - x_i)^T pi_i = -||x_{i+1} - x_i||^2 / dt_i   (Euler, eq. 7)

or, with measured velocities ``v_i = N_i pi_i``, the trapezoid rule

    phi_{i+1} - phi_i ~= -(v_i + v_{i+1})^T (x_{i+1} - x_i) / 2.

Both return potentials with ``phi_1 = 0``; the unknown offset is found by alignment. With
times in seconds, the learnt policy ``-grad phi`` is in state units per second.

Which rule: the Euler drop ``||x_{i+1} - x_i||^2 / dt_i`` is ``-grad phi(x_i)`` times the
step exactly when the state moves at ``v_i`` for the whole step (a velocity command held
over a control period, or simulated data), and then misses the step's second-order term
``1/2 dx^T H dx``: a bias of relative order ``dt`` that no global model can remove. The
trapezoid rule averages the gradient at both ends of the step, which is exact for a
quadratic potential under held commands and second order for smooth motion; measured
velocities enter it linearly, so their noise does not bias it. ``"auto"`` therefore uses
the trapezoid where velocities were recorded and agree with the positions
(:func:`velocity_disagreement`), and the Euler rule otherwise (no velocities, or
velocity fields a driver leaves at zero or fills with something else).
"""

from __future__ import annotations

import math

import numpy as np

from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["euler_potential", "trapezoid_potential", "estimate_potential", "METHODS",
           "velocity_disagreement", "choose_method", "VELOCITY_AGREEMENT"]

METHODS = ("auto", "euler", "trapezoid")
#: Largest :func:`velocity_disagreement` at which ``"auto"`` trusts recorded velocities.
VELOCITY_AGREEMENT = 0.5


def euler_potential(positions: np.ndarray, dt: np.ndarray | float = 1.0) -> np.ndarray:
    """Euler estimate of the potential along one trajectory (paper eq. 7).

    Parameters
    ----------
    positions : ndarray, shape (N, n)
        States along the trajectory.
    dt : float or ndarray, shape (N-1,)
        Time steps in seconds (1 in the paper's units).

    Returns
    -------
    ndarray, shape (N,)
        ``phi_1 = 0`` and ``phi_{i+1} = phi_i - ||x_{i+1} - x_i||^2 / dt_i``.
    """
    steps = np.diff(positions, axis=0)
    drops = np.einsum("ij,ij->i", steps, steps) / dt
    return np.concatenate(([0.0], -np.cumsum(drops)))


def trapezoid_potential(positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
    """Trapezoid estimate of the potential from positions and measured velocities.

    Parameters
    ----------
    positions : ndarray, shape (N, n)
        States along the trajectory.
    velocities : ndarray, shape (N, n)
        Observed ``xdot_i = N_i pi_i`` in state units per second.

    Returns
    -------
    ndarray, shape (N,)
        ``phi_1 = 0`` and ``phi_{i+1} = phi_i - (v_i + v_{i+1})^T (x_{i+1} - x_i) / 2``.
    """
    steps = np.diff(positions, axis=0)
    mean_v = 0.5 * (velocities[:-1] + velocities[1:])
    drops = np.einsum("ij,ij->i", mean_v, steps)
    return np.concatenate(([0.0], -np.cumsum(drops)))


def velocity_disagreement(positions: np.ndarray, velocities: np.ndarray,
                          dt: np.ndarray | float) -> float:
    """How far recorded velocities are from explaining the recorded steps.

    Parameters
    ----------
    positions, velocities : ndarray, shape (N, n)
        States and their recorded time derivatives (state units per second).
    dt : float or ndarray, shape (N-1,)
        Time steps in seconds.

    Returns
    -------
    float
        ``sqrt(sum ||dx_i - dt_i (v_i + v_{i+1}) / 2||^2 / sum ||dx_i||^2)``: near 0 when the
        velocities are those of the motion (a constraint switch adds one bad step), 1 for
        velocities left at zero, 2 for the opposite sign; ``inf`` if nothing moves.
    """
    steps = np.diff(positions, axis=0)
    dt = np.reshape(dt, (-1, 1)) if np.ndim(dt) else dt
    miss = steps - dt * 0.5 * (velocities[:-1] + velocities[1:])
    moved = float(np.sum(steps**2))
    return math.sqrt(float(np.sum(miss**2)) / moved) if moved > 0 else math.inf


def choose_method(trajs: list[Trajectory]) -> str:
    """``"trapezoid"`` if every trajectory has velocities that agree with its positions
    (:data:`VELOCITY_AGREEMENT`), else ``"euler"``: one rule for a whole data set, so that
    every trajectory's potential carries the same kind of error."""
    for traj in trajs:
        if traj.velocities is None or traj.n_samples < 2 or not velocity_disagreement(
                traj.positions, traj.velocities, traj.dt) <= VELOCITY_AGREEMENT:
            return "euler"
    return "trapezoid"


def estimate_potential(traj: Trajectory, method: str = "euler") -> np.ndarray:
    """Potential along a trajectory by the chosen rule.

    Parameters
    ----------
    traj : Trajectory
        The demonstration; ``method="trapezoid"`` needs its velocities.
    method : {"auto", "euler", "trapezoid"}
        Integration rule; ``"auto"`` is :func:`choose_method` for this trajectory alone.

    Returns
    -------
    ndarray, shape (N,)
        Potential estimates with ``phi_1 = 0``.
    """
    if method == "auto":
        method = choose_method([traj])
    if method == "euler":
        return euler_potential(traj.positions, traj.dt)
    if method == "trapezoid":
        if traj.velocities is None:
            raise ValueError(
                f"trajectory {traj.name}: the trapezoid estimate needs velocities"
            )
        return trapezoid_potential(traj.positions, traj.velocities)
    raise ValueError(f"unknown potential estimate {method!r}; expected one of {METHODS}")
