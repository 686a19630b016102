"""Kinematic robot simulation: integrate joint velocity commands, clamp to joint limits.

Notation and units: ``q`` joint positions (rad, or m for prismatic joints), ``qdot`` joint
velocities (rad/s), ``t`` and ``dt`` in seconds. The simulated robot behaves like a
ros2_control JointGroupVelocityController on a perfect plant, except that it stops when
the last command is older than ``command_timeout_s`` (a real controller would hold it).

This module is ROS-free; ``policy_align_ros.nodes.sim_robot`` is its ROS adapter.
"""

from __future__ import annotations

import numpy as np

from policy_align_ros.control.turns import wrap_continuous

__all__ = ["KinematicSim", "integrate_clamped", "wrap_continuous"]


def integrate_clamped(
    q: np.ndarray,
    qdot: np.ndarray,
    dt: float,
    lower: np.ndarray,
    upper: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One explicit Euler step with the result clamped to the joint limits.

    Parameters
    ----------
    q : ndarray, shape (n,)
        Joint positions before the step.
    qdot : ndarray, shape (n,)
        Commanded joint velocities (units of ``q`` per second).
    dt : float
        Step length in seconds (>= 0).
    lower, upper : ndarray, shape (n,)
        Joint position limits.

    Returns
    -------
    q_next : ndarray, shape (n,)
        ``clip(q + dt * qdot, lower, upper)``.
    qdot_actual : ndarray, shape (n,)
        The velocity really achieved, ``(q_next - q) / dt`` (the command when ``dt == 0``).
    """
    q_next = np.clip(q + dt * qdot, lower, upper)
    if dt <= 0.0:
        return q_next, np.array(qdot, dtype=float)
    return q_next, (q_next - q) / dt


class KinematicSim:
    """A velocity-controlled kinematic robot with joint limits and a command timeout.

    Parameters
    ----------
    lower, upper : array_like, shape (n,)
        Joint position limits; ``lower <= upper``, infinite values allowed.
    q0 : array_like, shape (n,)
        Initial positions; clamped into the limits.
    command_timeout_s : float
        Commands older than this are ignored and the robot holds still (> 0).
    velocity_limit : array_like, shape (n,), optional
        Per-joint speed limits (> 0) applied joint by joint, as a motor driver would.
    """

    def __init__(
        self,
        lower: np.ndarray,
        upper: np.ndarray,
        q0: np.ndarray,
        *,
        command_timeout_s: float = 0.2,
        velocity_limit: np.ndarray | None = None,
    ) -> None:
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        n = self.lower.shape[0]
        if self.lower.shape != (n,) or self.upper.shape != (n,):
            raise ValueError(
                f"lower/upper: must be 1-D arrays of one length, got {self.lower.shape} and "
                f"{self.upper.shape}"
            )
        if np.any(np.isnan(self.lower)) or np.any(np.isnan(self.upper)):
            raise ValueError("lower/upper: contain NaN")
        if np.any(self.lower > self.upper):
            bad = int(np.argmax(self.lower > self.upper))
            raise ValueError(f"lower/upper: lower > upper for joint {bad}")
        if not command_timeout_s > 0.0:
            raise ValueError(f"command_timeout_s: must be > 0, got {command_timeout_s}")
        self.command_timeout_s = float(command_timeout_s)
        if velocity_limit is None:
            self.velocity_limit = np.full(n, np.inf)
        else:
            self.velocity_limit = np.asarray(velocity_limit, dtype=float)
            if self.velocity_limit.shape != (n,) or np.any(~(self.velocity_limit > 0.0)):
                raise ValueError(f"velocity_limit: must be {n} positive values")
        self.reset(q0)

    @property
    def n_joints(self) -> int:
        """Number of simulated joints ``n``."""
        return self.lower.shape[0]

    def reset(self, q0: np.ndarray) -> np.ndarray:
        """Teleport to ``q0`` (clamped into the limits), drop the command; return ``q``."""
        q = self._checked(q0, "q0")
        self.q = np.clip(q, self.lower, self.upper)
        self.qdot = np.zeros(self.n_joints)
        self._command = np.zeros(self.n_joints)
        self._command_time: float | None = None
        return self.q.copy()

    def set_command(self, qdot: np.ndarray, t: float) -> None:
        """Store a velocity command received at time ``t`` (seconds).

        Raises
        ------
        ValueError
            If ``qdot`` has the wrong length or holds NaN/inf; the previous command is kept.
        """
        self._command = np.clip(
            self._checked(qdot, "command"), -self.velocity_limit, self.velocity_limit
        )
        self._command_time = float(t)

    def command_is_fresh(self, t: float) -> bool:
        """Whether the last command, at time ``t``, is younger than the timeout.

        A command stamped after ``t`` (the clock went back: a restarted ``/clock``) is
        not: its age is unknown, and holding it could keep the robot moving for as long
        as the clock takes to catch up.
        """
        return self._command_time is not None and (
            0.0 <= t - self._command_time <= self.command_timeout_s
        )

    def step(self, dt: float, t: float) -> np.ndarray:
        """Advance by ``dt`` seconds at time ``t``; return the new positions, shape (n,)."""
        if not dt >= 0.0:
            raise ValueError(f"dt: must be >= 0, got {dt}")
        command = self._command if self.command_is_fresh(t) else np.zeros(self.n_joints)
        self.q, self.qdot = integrate_clamped(self.q, command, dt, self.lower, self.upper)
        return self.q.copy()

    def _checked(self, values: np.ndarray, what: str) -> np.ndarray:
        arr = np.asarray(values, dtype=float)
        if arr.shape != (self.n_joints,):
            raise ValueError(f"{what}: expected {self.n_joints} values, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{what}: contains NaN or inf")
        return arr
