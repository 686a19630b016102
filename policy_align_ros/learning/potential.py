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
"""

from __future__ import annotations

import numpy as np

from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["euler_potential", "trapezoid_potential", "estimate_potential", "METHODS"]

METHODS = ("euler", "trapezoid")


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


def estimate_potential(traj: Trajectory, method: str = "euler") -> np.ndarray:
    """Potential along a trajectory by the chosen rule.

    Parameters
    ----------
    traj : Trajectory
        The demonstration; ``method="trapezoid"`` needs its velocities.
    method : {"euler", "trapezoid"}
        Integration rule.

    Returns
    -------
    ndarray, shape (N,)
        Potential estimates with ``phi_1 = 0``.
    """
    if method == "euler":
        return euler_potential(traj.positions, traj.dt)
    if method == "trapezoid":
        if traj.velocities is None:
            raise ValueError(
                f"trajectory {traj.name}: the trapezoid estimate needs velocities"
            )
        return trapezoid_potential(traj.positions, traj.velocities)
    raise ValueError(f"unknown potential estimate {method!r}; expected one of {METHODS}")
