"""A rigid-body arm under a joint-velocity servo, touching planes: a physical recording.

:func:`policy_align_ros.sim.recording.track_velocity` lags every joint alike and
:func:`~policy_align_ros.sim.recording.table_contact_rollout` slides the hand on a table
kinematically. A physical robot, or a physics simulator driving one, does neither:

* each joint's servo pushes a torque ``K_v (u - v)`` through the arm's configuration-
  dependent, coupled mass matrix (a heavy shoulder lags more than a light wrist, and one
  joint's acceleration drags the others), on top of gravity compensation, the two within
  the joint's effort limit;
* a plane the hand touches (a table, a wall) pushes back with a stiff spring-damper, and
  Coulomb friction opposes the hand's sliding: the servo keeps pushing into the plane, so
  the contact force, and with it the friction, grows with the speed the plane blocks.

:class:`ServoArm` integrates Pinocchio's forward dynamics (``pinocchio.aba``) with
semi-implicit Euler steps; a recorder reads the joint positions and velocities.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from policy_align_ros.kinematics import Robot

__all__ = ["ContactPlane", "ServoArm", "contact_force", "servo_gains"]

#: ``command(q (n,), t [s]) -> u (n,)``: the joint velocity asked of the servo, rad/s.
CommandFn = Callable[[np.ndarray, float], np.ndarray]


@dataclass(frozen=True)
class ContactPlane:
    """A plane the hand frame cannot pass: ``normal . p >= offset`` (world frame, m).

    ``stiffness`` (N/m) and ``damping`` (N s/m) make the normal force; ``mu`` is the
    Coulomb friction coefficient (real contacts 0.2-0.6) and ``slip`` (m/s) the sliding
    speed below which friction is viscous, ``mu f_n |v_t| / slip``: an explicit step stays
    stable, and a hand pushed along the plane below the Coulomb force creeps slowly
    rather than sticks (no event-driven solver).
    """

    normal: tuple[float, float, float]
    offset: float
    mu: float = 0.4
    stiffness: float = 2.0e4
    damping: float = 300.0
    slip: float = 0.05

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, dtype=float)
        if n.shape != (3,) or not np.isfinite(n).all() or np.linalg.norm(n) == 0:
            raise ValueError(f"normal: must be a finite non-zero 3-vector, got {self.normal}")
        object.__setattr__(self, "normal", tuple(n / np.linalg.norm(n)))
        for name in ("mu", "stiffness", "damping", "slip"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0) or (name == "slip" and value == 0):
                raise ValueError(f"{name}: must be a finite number >= 0 (slip > 0), got "
                                 f"{value}")


def contact_force(p: np.ndarray, pdot: np.ndarray, plane: ContactPlane) -> np.ndarray:
    """Force (3,) in N the plane puts on a point at ``p`` (m) moving at ``pdot`` (m/s).

    Zero off the plane. On it, the normal force is ``max(0, k d - c n . pdot)`` for a
    penetration ``d`` (never pulling), and friction ``-mu f_n v_t / max(|v_t|, slip)``
    opposes the tangential velocity ``v_t``.

    Parameters
    ----------
    p, pdot : numpy.ndarray, shape (3,)
    plane : ContactPlane

    Returns
    -------
    numpy.ndarray, shape (3,)
    """
    n = np.asarray(plane.normal)
    depth = plane.offset - float(n @ p)
    if depth <= 0.0:
        return np.zeros(3)
    normal_speed = float(n @ pdot)
    f_n = max(0.0, plane.stiffness * depth - plane.damping * normal_speed)
    v_t = pdot - normal_speed * n
    friction = -plane.mu * f_n * v_t / max(float(np.linalg.norm(v_t)), plane.slip)
    return f_n * n + friction


def servo_gains(model: pin.Model, q_ref: np.ndarray, tau: float) -> np.ndarray:
    """Per-joint velocity gains ``K_v = M_ii(q_ref) / tau``, shape (nv,), N m s/rad.

    Constant gains, as a physics simulator's velocity actuators or a robot's joint
    servos have: each joint tracks with time constant ``tau`` at ``q_ref`` when the
    others stand still, and with another one, coupled to the others, elsewhere.

    Parameters
    ----------
    model : pinocchio.Model
        The arm, with its inertias (and armature, which ``crba`` includes).
    q_ref : numpy.ndarray, shape (nq,)
        Reference posture, rad.
    tau : float
        Time constant at ``q_ref``, s (> 0).

    Returns
    -------
    numpy.ndarray, shape (nv,)
    """
    if not (np.isfinite(tau) and tau > 0):
        raise ValueError(f"tau: must be a finite number > 0, got {tau}")
    return np.diag(pin.crba(model, model.createData(), np.asarray(q_ref, dtype=float))) / tau


class ServoArm:
    """A rigid arm (Pinocchio model) whose joints track velocity commands, touching planes.

    Parameters
    ----------
    robot : policy_align_ros.kinematics.Robot
        Its model's joints, in tree order and without continuous joints, are the state.
    frame : str
        The frame that touches the planes (the hand).
    planes : sequence of ContactPlane
    tau : float
        Servo time constant at ``robot.neutral()``, s (:func:`servo_gains`).
    step : float
        Physics step, s (semi-implicit Euler).
    control_period : float
        How often the command is read, s (a multiple of ``step``).
    """

    def __init__(self, robot: Robot, frame: str, planes: Sequence[ContactPlane] = (), *,
                 tau: float = 0.05, step: float = 5e-4, control_period: float = 1e-3) -> None:
        model = robot.model
        tree = [model.names[i] for i in range(1, model.njoints)]
        if tree != list(robot.joint_names) or robot.continuous.any() or model.nq != model.nv:
            raise ValueError("robot: ServoArm needs its joints in tree order and no "
                             "continuous joints (load it with joints=None or in tree order)")
        robot.frame_id(frame)  # an unknown frame is named now, not at the first step
        self.robot, self.model, self.data, self.frame = robot, model, model.createData(), frame
        self.planes = tuple(planes)
        self.gains = servo_gains(model, robot.neutral(), tau)
        self.effort = np.asarray(model.effortLimit, dtype=float)
        self.damping = np.asarray(model.damping, dtype=float)
        if not (0 < step <= control_period):
            raise ValueError(f"step, control_period: need 0 < step <= control_period, got "
                             f"{step}, {control_period}")
        self.step = float(step)
        self.substeps = max(1, int(round(control_period / step)))

    def on_plane(self, q: np.ndarray) -> bool:
        """Whether the hand at ``q`` is pressed into one of the planes."""
        return self._pressed(self.robot.frame_position(q, self.frame))

    def _pressed(self, p: np.ndarray) -> bool:
        return any(np.dot(plane.normal, p) < plane.offset for plane in self.planes)

    def _contact_torque(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        p = self.robot.frame_position(q, self.frame)
        if not self._pressed(p):
            return np.zeros(self.model.nv)
        J = self.robot.frame_jacobian(q, self.frame)  # LOCAL_WORLD_ALIGNED, (3, n)
        pdot = J @ v
        force = sum(contact_force(p, pdot, plane) for plane in self.planes)
        return J.T @ force

    def _accelerate(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        # The motors saturate on what they deliver: gravity compensation and servo.
        motor = np.clip(pin.computeGeneralizedGravity(self.model, self.data, q)
                        + self.gains * (u - v), -self.effort, self.effort)
        torque = motor - self.damping * v + self._contact_torque(q, v)
        return pin.aba(self.model, self.data, q, v, torque)

    def run(self, q0: np.ndarray, command: CommandFn, n_samples: int, dt: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Run from rest at ``q0`` and record every ``dt``.

        Parameters
        ----------
        q0 : numpy.ndarray, shape (n,)
            Start posture, rad (clipped to the limits).
        command : callable ``(q (n,), t) -> u (n,)``
            Joint velocity asked of the servo at the measured posture, rad/s; read every
            control period.
        n_samples : int
            Samples recorded (>= 2).
        dt : float
            Sample period, s (a multiple of the control period).

        Returns
        -------
        Q, V : numpy.ndarray, shape (n_samples, n)
            Joint positions (rad) and velocities (rad/s) at the samples.
        times : numpy.ndarray, shape (n_samples,)
            s, from 0.
        touching : numpy.ndarray of bool, shape (n_samples,)
            Whether the hand is on a plane (pressed into it) at each sample.
        """
        period = self.step * self.substeps
        controls = int(round(dt / period)) if np.isfinite(dt) and dt > 0 else 0
        if n_samples < 2 or controls < 1 or abs(controls * period - dt) > 1e-9 * dt:
            raise ValueError(f"n_samples, dt: need n_samples >= 2 and dt a multiple of the "
                             f"control period {period} s, got {n_samples}, {dt}")
        q = self.robot.clip(np.asarray(q0, dtype=float).copy())
        v = np.zeros_like(q)
        n = q.size
        Q, V = np.empty((n_samples, n)), np.empty((n_samples, n))
        touching = np.zeros(n_samples, dtype=bool)
        lo, hi = self.robot.lower, self.robot.upper
        for i in range(n_samples):
            Q[i], V[i] = q, v
            touching[i] = self.on_plane(q)
            for c in range(controls):
                u = np.asarray(command(q, (i * controls + c) * period), dtype=float)
                for _ in range(self.substeps):
                    a = self._accelerate(q, v, u)
                    v = v + self.step * a
                    q = q + self.step * v
                    # A joint at its limit stops there (a hard end stop).
                    stop = ((q <= lo) & (v < 0)) | ((q >= hi) & (v > 0))
                    q, v = np.clip(q, lo, hi), np.where(stop, 0.0, v)
        return Q, V, dt * np.arange(n_samples), touching
