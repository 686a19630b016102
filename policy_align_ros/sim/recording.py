"""How real teachers and robots distort the recording of an exact expert.

The demonstrations of :mod:`policy_align_ros.sim.demonstrations` are exact Euler steps of
``xdot = N pi(x)``. A recording of a real robot or a human teacher differs:

* :func:`track_velocity`: a robot follows the expert's velocity command through a
  first-order lag (time constant ``tau``, s) and a speed and acceleration saturation; the
  recorder sees the robot's positions and velocities, not the command;
* :func:`retime_path`: a human follows the expert's *path* with its own timing, at rest at
  both ends (a minimum-jerk profile over the arc length, :func:`minimum_jerk`), at a speed
  that differs between demonstrations;
* :func:`friction_slowdown` and :func:`table_contact_rollout`: a hand slides on a table (a
  unilateral plane it pushes into) and Coulomb friction slows its tangential motion, which
  is then not a projection of the expert's policy;
* :func:`encoder_noise` and :func:`stamp_jitter`: quantised, noisy positions and stamps
  taken off the sampling instants;
* :func:`pad_with_rest`: a recorder started before the motion and stopped after it (the
  recorder node's ``start_demo`` and ``stop_demo``), so the robot stands still at both
  ends.

Every function returns arrays the suite wraps as a
:class:`~policy_align_ros.sim.demonstrations.Demonstration` with the expert's ground
truth at the recorded positions (:func:`with_ground_truth`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from policy_align_ros.kinematics import nullspace_projector
from policy_align_ros.learning import Trajectory
from policy_align_ros.sim.demonstrations import ConstraintFn, Demonstration

__all__ = ["encoder_noise", "friction_slowdown", "hesitate", "minimum_jerk", "pad_with_rest",
           "retime_path", "stamp_jitter", "table_contact_rollout", "track_velocity",
           "with_ground_truth"]

#: Distance above the table top (m) at which the hand counts as touching it.
CONTACT_TOL = 1e-3

#: ``command(x (n,), t [s]) -> u (n,)``: the expert's velocity command at the robot's state.
CommandFn = Callable[[np.ndarray, float], np.ndarray]


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name}: must be a finite number > 0, got {value}")
    return value


def track_velocity(x0: np.ndarray, command: CommandFn, n_samples: int, dt: float, *,
                   tau: float = 0.08, max_speed: float = np.inf, max_accel: float = np.inf,
                   substeps: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A robot tracking a velocity command through a lag and saturations, as recorded.

    The robot's velocity ``v`` obeys ``dv/dt = (sat(u) - v) / tau`` with ``|dv/dt|``
    clipped at ``max_accel`` per coordinate and ``sat`` clipping each coordinate of the
    command ``u = command(x, t)`` at ``max_speed``; ``x`` and ``v`` are integrated with
    ``substeps`` explicit steps per sample period. The robot starts at rest.

    Parameters
    ----------
    x0 : numpy.ndarray, shape (n,)
        Start state (state units).
    command : callable ``(x (n,), t) -> u (n,)``
        The expert's velocity command at the robot's current state, units/s.
    n_samples : int
        Samples recorded (>= 2), one every ``dt``.
    dt : float
        Sample period, s.
    tau : float
        Time constant of the velocity loop, s (real arms: 0.05-0.15 s).
    max_speed, max_accel : float
        Per-coordinate limits, units/s and units/s^2.
    substeps : int
        Integration steps per sample period.

    Returns
    -------
    X : numpy.ndarray, shape (n_samples, n)
        Recorded positions.
    V : numpy.ndarray, shape (n_samples, n)
        The robot's velocities at the samples, units/s.
    times : numpy.ndarray, shape (n_samples,)
        s, from 0.
    """
    if n_samples < 2:
        raise ValueError(f"n_samples: must be >= 2, got {n_samples}")
    dt, tau = _positive("dt", dt), _positive("tau", tau)
    if not (max_speed > 0 and max_accel > 0):
        raise ValueError(f"max_speed, max_accel: must be > 0 (inf: no limit), got "
                         f"{max_speed}, {max_accel}")
    if substeps < 1:
        raise ValueError(f"substeps: must be >= 1, got {substeps}")
    x = np.asarray(x0, dtype=float).copy()
    v = np.zeros_like(x)
    h = dt / substeps
    X, V = np.empty((n_samples, x.size)), np.empty((n_samples, x.size))
    for i in range(n_samples):
        X[i], V[i] = x, v
        for j in range(substeps):
            u = np.clip(command(x, (i + j / substeps) * dt), -max_speed, max_speed)
            a = np.clip((u - v) / tau, -max_accel, max_accel)
            # Semi-implicit Euler; the lag's own step is stable for h < tau.
            v = v + h * a
            x = x + h * v
    return X, V, dt * np.arange(n_samples)


def minimum_jerk(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The minimum-jerk profile ``10 s^3 - 15 s^4 + 6 s^5`` on ``[0, 1]`` and its slope.

    Parameters
    ----------
    s : numpy.ndarray
        Normalised time in ``[0, 1]`` (clipped to it).

    Returns
    -------
    value, slope : numpy.ndarray, same shape
        Share of the path covered (0 to 1) and its derivative in ``s``.
    """
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s**2), 30 * s**2 * (1 - s) ** 2


def retime_path(path: np.ndarray, duration: float, dt: float, *, rest_before: float = 0.3,
                rest_after: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                  np.ndarray]:
    """The geometry of ``path`` travelled with a human's timing, at rest at both ends.

    The arc length covered is ``L minimum_jerk((t - rest_before) / duration)``: the speed
    is zero at both ends of the motion and peaks at ``1.875 L / duration`` half-way; the
    recording holds the first point for ``rest_before`` s and the last for ``rest_after`` s.

    Parameters
    ----------
    path : numpy.ndarray, shape (M, n)
        Consecutive points of the expert's path (state units), M >= 2, not all equal.
    duration : float
        Time of the motion itself, s.
    dt : float
        Sample period of the recording, s.
    rest_before, rest_after : float
        Rests at the start and at the end, s (>= 0).

    Returns
    -------
    X : numpy.ndarray, shape (N, n)
        Recorded positions on the path.
    V : numpy.ndarray, shape (N, n)
        Velocities along the path, units/s (zero at rest).
    times : numpy.ndarray, shape (N,)
        s, from 0, every ``dt``.
    index : numpy.ndarray, shape (N,)
        Fractional index into ``path`` of each sample (for the ground truth of the
        sample the path point came from).
    """
    path = np.asarray(path, dtype=float)
    if path.ndim != 2 or len(path) < 2:
        raise ValueError(f"path: must have shape (M >= 2, n), got {path.shape}")
    duration, dt = _positive("duration", duration), _positive("dt", dt)
    if rest_before < 0 or rest_after < 0:
        raise ValueError(f"rest_before, rest_after: must be >= 0 s, got {rest_before}, "
                         f"{rest_after}")
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    if arc[-1] <= 0:
        raise ValueError("path: all its points are equal (no motion to re-time)")
    times = dt * np.arange(int(np.ceil((rest_before + duration + rest_after) / dt)) + 1)
    share, slope = minimum_jerk((times - rest_before) / duration)
    s = share * arc[-1]
    index = np.interp(s, arc, np.arange(len(path)))
    X = np.stack([np.interp(s, arc, path[:, d]) for d in range(path.shape[1])], axis=1)
    # Tangent of the segment each sample lies on (a unit vector in state units).
    seg = np.clip(np.floor(index).astype(int), 0, len(path) - 2)
    tangent = path[seg + 1] - path[seg]
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
    V = tangent * (slope * arc[-1] / duration)[:, None]
    return X, V, times, index


def friction_slowdown(v_tangent: np.ndarray, normal_push: float, mu: float) -> np.ndarray:
    """Coulomb-like friction on a tangential velocity: slowed, never reversed.

    A contact pushed into at the normal speed ``normal_push`` (units/s, >= 0; an
    admittance turns the blocked speed into the normal force) takes ``mu normal_push`` off
    the tangential speed, down to sticking at zero.

    Parameters
    ----------
    v_tangent : numpy.ndarray, shape (d,)
        Tangential velocity the expert asks for, units/s.
    normal_push : float
        Speed of the motion the contact blocks, units/s (>= 0).
    mu : float
        Friction coefficient (>= 0; real contacts 0.2-0.6).

    Returns
    -------
    numpy.ndarray, shape (d,)
        ``v_tangent max(0, 1 - mu normal_push / |v_tangent|)``.
    """
    if mu < 0 or normal_push < 0:
        raise ValueError(f"mu, normal_push: must be >= 0, got {mu}, {normal_push}")
    v = np.asarray(v_tangent, dtype=float)
    speed = float(np.linalg.norm(v))
    if speed == 0.0:
        return v.copy()
    return v * max(0.0, 1.0 - mu * normal_push / speed)


def table_contact_rollout(q0: np.ndarray, policy: Callable[[np.ndarray], np.ndarray],
                          robot, frame: str, height: float, mu: float, n_samples: int,
                          dt: float, other: ConstraintFn | None = None
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Joint-space expert whose hand slides on a table ``z >= height`` with friction.

    Each step the expert's joint velocity ``pi(q)`` is projected onto the rows of
    ``other`` (if any); when the hand is on the table and that motion pushes it down, the
    hand's normal motion is removed (the row ``e_z^T J``) and the tangential hand motion
    is slowed by :func:`friction_slowdown` through the least-norm joint velocity
    ``J^+ dv``. Above the table the expert moves freely (up to ``other``).

    Parameters
    ----------
    q0 : numpy.ndarray, shape (n,)
        Start posture (rad), hand above the table.
    policy : callable ``(Q (m, n)) -> (m, n)``
        The expert's policy, rad/s.
    robot : Robot
        Gives ``frame_position`` and the translational ``frame_jacobian`` (3, n).
    frame : str
        The hand frame.
    height : float
        Table top, m (world z).
    mu : float
        Friction coefficient.
    n_samples : int
    dt : float
        Sample period, s.
    other : ConstraintFn, optional
        Further constraint rows ``A(q, t, pi)`` (k, n) the expert obeys.

    Returns
    -------
    Q : numpy.ndarray, shape (n_samples, n)
    Qdot : numpy.ndarray, shape (n_samples, n)
        Joint velocities, rad/s.
    projectors : numpy.ndarray, shape (n_samples, n, n)
        ``N`` of the rows in force (the clean projection friction departs from).
    n_active : numpy.ndarray of int, shape (n_samples,)
    """
    q = robot.clip(np.asarray(q0, dtype=float).copy())
    n = q.size
    Q, Qd = np.empty((n_samples, n)), np.empty((n_samples, n))
    Ns, k = np.empty((n_samples, n, n)), np.zeros(n_samples, dtype=int)
    for i in range(n_samples):
        pi = policy(q[None])[0]
        A = np.zeros((0, n)) if other is None else np.atleast_2d(other(q, i * dt, pi))
        J = robot.frame_jacobian(q, frame)
        qdot = nullspace_projector(A, n=n) @ pi
        push = -float(J[2] @ qdot)
        on_table = robot.frame_position(q, frame)[2] <= height + CONTACT_TOL
        if on_table and push > 0:
            A = np.vstack([A, J[2:3]])
            qdot = nullspace_projector(A, n=n) @ pi
            hand = J @ qdot
            slowed = friction_slowdown(hand[:2], push, mu)
            dv = np.concatenate([hand[:2] - slowed, [0.0]])
            qdot = qdot - np.linalg.pinv(J) @ dv
        Q[i], Qd[i], Ns[i], k[i] = q, qdot, nullspace_projector(A, n=n), A.shape[0]
        # The table stops a falling hand at its top (no penetration within a step).
        z0 = robot.frame_position(q, frame)[2]
        z1 = robot.frame_position(robot.clip(q + dt * qdot), frame)[2]
        share = 1.0 if z1 >= height or z0 <= height else (z0 - height) / (z0 - z1)
        q_next = robot.clip(q + dt * share * qdot)
        q = q_next
    return Q, Qd, Ns, k


def encoder_noise(X: np.ndarray, resolution: float, sd: float, rng: np.random.Generator
                  ) -> np.ndarray:
    """Positions read through an encoder: quantised to ``resolution``, plus white noise.

    The added error has RMS ``sqrt(resolution^2 / 12 + sd^2)`` per coordinate.

    Parameters
    ----------
    X : numpy.ndarray, shape (N, n)
        True positions (state units).
    resolution : float
        Quantisation step (> 0), state units.
    sd : float
        Standard deviation of the white noise (>= 0), state units.
    rng : numpy.random.Generator

    Returns
    -------
    numpy.ndarray, shape (N, n)
    """
    resolution = _positive("resolution", resolution)
    if not sd >= 0:
        raise ValueError(f"sd: must be >= 0, got {sd}")
    X = np.asarray(X, dtype=float)
    return resolution * np.round(X / resolution) + sd * rng.standard_normal(X.shape)


def pad_with_rest(X: np.ndarray, times: np.ndarray, rest_before: float, rest_after: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """A recording that starts ``rest_before`` s before the motion and ends ``rest_after``
    s after it: the first and last positions held, at the median sample period.

    Parameters
    ----------
    X : numpy.ndarray, shape (N, n)
        Positions of the motion (state units), N >= 2.
    times : numpy.ndarray, shape (N,)
        Increasing stamps, s.
    rest_before, rest_after : float
        Rests added at the start and at the end, s (>= 0; rounded to whole periods).

    Returns
    -------
    X : numpy.ndarray, shape (N + a + b, n)
    times : numpy.ndarray, shape (N + a + b,)
        Still increasing, with the motion's stamps unchanged.
    """
    X, times = np.asarray(X, dtype=float), np.asarray(times, dtype=float)
    if X.ndim != 2 or len(X) < 2 or times.shape != (len(X),):
        raise ValueError(f"X, times: must have shapes (N >= 2, n) and (N,), got {X.shape} "
                         f"and {times.shape}")
    if not (rest_before >= 0 and rest_after >= 0):
        raise ValueError(f"rest_before, rest_after: must be >= 0 s, got {rest_before}, "
                         f"{rest_after}")
    dt = float(np.median(np.diff(times)))
    before, after = int(round(rest_before / dt)), int(round(rest_after / dt))
    X = np.vstack([np.repeat(X[:1], before, axis=0), X, np.repeat(X[-1:], after, axis=0)])
    times = np.concatenate([times[0] - dt * np.arange(before, 0, -1), times,
                            times[-1] + dt * np.arange(1, after + 1)])
    return X, times


def hesitate(X: np.ndarray, times: np.ndarray, at: float, pause: float, ramp: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """The recording of a teacher who stops once on the way and sets off again.

    The motion ``X(t)`` is replayed on a clock that runs at the recording's pace but,
    around ``at`` of its duration, slows to a halt over ``ramp`` s (a raised cosine),
    stands still for ``pause`` s and speeds up again over ``ramp`` s: the path is the
    same, its speed along it is scaled by that clock's rate, and the recording lasts
    ``pause + ramp`` s longer, sampled at its median period.

    Parameters
    ----------
    X : numpy.ndarray, shape (N, n)
        Positions of the motion (state units), N >= 2.
    times : numpy.ndarray, shape (N,)
        Increasing stamps, s.
    at : float
        Where the halt is reached, as a fraction of the duration, in ``(0, 1)``.
    pause, ramp : float
        The halt's length and each of its two ramps' length, s (``pause >= 0``,
        ``ramp > 0``).

    Returns
    -------
    X : numpy.ndarray, shape (M, n)
        Positions on the motion's path (linear interpolation between its samples).
    times : numpy.ndarray, shape (M,)
        From ``times[0]``, every median period.
    """
    X, times = np.asarray(X, dtype=float), np.asarray(times, dtype=float)
    if X.ndim != 2 or len(X) < 2 or times.shape != (len(X),) or np.any(np.diff(times) <= 0):
        raise ValueError(f"X, times: must have shapes (N >= 2, n) and (N,) with increasing "
                         f"stamps, got {X.shape} and {times.shape}")
    if not 0.0 < at < 1.0:
        raise ValueError(f"at: must be in (0, 1), got {at}")
    if pause < 0:
        raise ValueError(f"pause: must be >= 0 s, got {pause}")
    ramp = _positive("ramp", ramp)
    dt = float(np.median(np.diff(times)))
    halt = times[0] + at * (times[-1] - times[0])  # on the new clock, the halt starts here
    # The motion's clock tau(t) is the integral of the rate; the ramps end where the
    # unmodified clock would have covered ramp / 2 each (a raised cosine's mean is 1/2).
    fine = np.linspace(times[0], times[-1] + pause + ramp, 64 * len(times))
    rate = np.ones_like(fine)
    down = (fine > halt - ramp) & (fine < halt)
    rate[down] = 0.5 * (1.0 + np.cos(np.pi * (fine[down] - halt + ramp) / ramp))
    rate[(fine >= halt) & (fine <= halt + pause)] = 0.0
    up = (fine > halt + pause) & (fine < halt + pause + ramp)
    rate[up] = 0.5 * (1.0 - np.cos(np.pi * (fine[up] - halt - pause) / ramp))
    tau = times[0] + np.concatenate(
        [[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(fine))])
    new_times = times[0] + dt * np.arange(int(np.ceil((fine[-1] - times[0]) / dt - 1e-9)) + 1)
    clock = np.minimum(np.interp(new_times, fine, tau), times[-1])
    out = np.stack([np.interp(clock, times, X[:, d]) for d in range(X.shape[1])], axis=1)
    return out, new_times


def stamp_jitter(times: np.ndarray, sd: float, rng: np.random.Generator) -> np.ndarray:
    """Stamps taken off the sampling instants by white jitter, still increasing.

    Parameters
    ----------
    times : numpy.ndarray, shape (N,)
        True sampling instants, s, increasing.
    sd : float
        Standard deviation of the jitter, s; each offset is clipped to 0.4 of the
        smallest step so the stamps stay in order.
    rng : numpy.random.Generator

    Returns
    -------
    numpy.ndarray, shape (N,)
    """
    t = np.asarray(times, dtype=float)
    steps = np.diff(t)
    if t.ndim != 1 or len(t) < 2 or np.any(steps <= 0):
        raise ValueError("times: must be an increasing (N >= 2,) array")
    if not sd >= 0:
        raise ValueError(f"sd: must be >= 0, got {sd}")
    bound = 0.4 * float(steps.min())
    return t + np.clip(sd * rng.standard_normal(t.shape), -bound, bound)


def with_ground_truth(X: np.ndarray, V: np.ndarray | None, times: np.ndarray, potential,
                      projectors: np.ndarray, n_active: np.ndarray, *,
                      name: str | None = None, truth_at: np.ndarray | None = None
                      ) -> Demonstration:
    """A recording as a :class:`Demonstration` with the expert's truth at its positions.

    Parameters
    ----------
    X : numpy.ndarray, shape (N, n)
        Recorded positions.
    V : numpy.ndarray (N, n) or None
        Recorded velocities.
    times : numpy.ndarray, shape (N,)
        Recorded stamps, s.
    potential : object with ``value`` and ``policy``
    projectors : numpy.ndarray, shape (N, n, n)
        ``N`` in force at each sample.
    n_active : numpy.ndarray of int, shape (N,)
    name : str, optional
    truth_at : numpy.ndarray (N, n), optional
        Where the truth is evaluated (default ``X``; the true positions when ``X`` is noisy).
    """
    at = X if truth_at is None else truth_at
    return Demonstration(Trajectory(X, times, V, name=name), potential.policy(at),
                         projectors, potential.value(at), np.asarray(n_active, dtype=int))
