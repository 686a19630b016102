"""Expert demonstrators: a known potential-based policy run under changing constraints.

Notation (paper, section II and eq. 5): state ``x`` (n,) (joint positions in rad, or
task-space positions in m), true potential ``phi(x)``, true policy ``pi(x) = -grad phi(x)``
in state units per second, constraint ``A(x, t, pi)`` (k, n), projector
``N = I - pinv(A) A`` (n, n). One step of length ``dt`` (s) is the explicit Euler step of
the constrained motion, ``x_{i+1} = x_i + dt N_i pi_i``; the recorded velocity is
``xdot_i = N_i pi_i``. With ``dt = 1`` this is the paper's convention exactly.

A constraint generator is any callable ``constraint(x, t, pi) -> A``: it sees the state,
the time (s, from the demonstration start) and the intended policy (needed by unilateral
barriers that only block approaching motion). :func:`demo_step` runs one step, so a ROS
node can drive the same expert one control period at a time.

Hand-space demonstrations (:class:`TaskSpaceExpert`, :func:`task_space_rollout`): the
state is ``x`` (3F,), the stacked positions (m) of ``F`` frames, the expert's potential
``phi_x`` is a quadratic in ``x`` and its motion is ``xdot = N_x pi_x(x)`` with
``pi_x = -grad phi_x`` and ``N_x`` the projector of hand-space constraint rows
``A_x`` (k, 3F), realised on the robot through the frames' Jacobian ``J`` (3F, n) by the
joint velocity of :func:`policy_align_ros.control.resolved_rate.task_to_joint_velocity`.
A joint-space expert seen in hand space is not a gradient field there, so it cannot
stand in for a hand-space one.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from policy_align_ros.control import (
    joint_velocity_within_limits,
    secondary_velocity,
    velocity_scale,
)
from policy_align_ros.kinematics import Constraint, Robot, TaskSpaceMap, nullspace_projector
from policy_align_ros.learning import Trajectory

__all__ = [
    "ConstraintFn",
    "Demonstration",
    "QuadraticPotential",
    "TaskSpacePotential",
    "TaskSpaceExpert",
    "TaskSpaceDemonstration",
    "task_space_rollout",
    "StepResult",
    "demo_step",
    "rollout",
    "generate_demonstrations",
    "sample_start_states",
    "no_constraint",
    "from_constraint",
    "held_out_masks",
    "stack_ground_truth",
]

#: ``constraint(x (n,), t [s], pi (n,)) -> A (k, n)``.
ConstraintFn = Callable[[np.ndarray, float, np.ndarray], np.ndarray]


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


def no_constraint(n: int) -> ConstraintFn:
    """The unconstrained case: ``A`` of shape (0, n) always."""
    empty = np.zeros((0, n))
    return lambda x, t, pi: empty


def from_constraint(constraint: Constraint) -> ConstraintFn:
    """Wrap a joint-space :class:`Constraint` (its ``matrix(q, qdot)``) as a generator."""
    return lambda x, t, pi: constraint.matrix(x, pi)


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


def demo_step(x: np.ndarray, t: float, potential, constraint: ConstraintFn, dt: float
              ) -> StepResult:
    """Advance the constrained expert by one Euler step of ``dt`` seconds.

    Parameters
    ----------
    x : numpy.ndarray, shape (n,)
    t : float
        Time since the demonstration started, s.
    potential : object with ``policy(X (m, n)) -> (m, n)``
    constraint : ConstraintFn
    dt : float
        Step, s (> 0).

    Returns
    -------
    StepResult
    """
    x = np.asarray(x, dtype=float)
    pi = potential.policy(x[None])[0]
    A = np.asarray(constraint(x, t, pi), dtype=float).reshape(-1, x.size)
    N = nullspace_projector(A, n=x.size)
    v = N @ pi
    return StepResult(x + dt * v, v, N, pi, A)


@dataclass
class Demonstration:
    """A demonstration with its ground truth at every sample.

    Attributes
    ----------
    trajectory : Trajectory
        Positions (N, n), times (N,) in s and velocities ``N_i pi_i`` (N, n).
    policy : numpy.ndarray, shape (N, n)
        True unconstrained policy ``pi_i``.
    projectors : numpy.ndarray, shape (N, n, n)
        ``N_i`` of the constraint in force at each sample.
    potential : numpy.ndarray, shape (N,)
        True potential ``phi(x_i)``.
    n_active : numpy.ndarray of int, shape (N,)
        Number of constraint rows ``k_i`` in force at each sample.
    """

    trajectory: Trajectory
    policy: np.ndarray
    projectors: np.ndarray
    potential: np.ndarray
    n_active: np.ndarray


def rollout(x0: np.ndarray, potential, constraint: ConstraintFn, n_samples: int,
            dt: float = 1.0, *, name: str | None = None) -> Demonstration:
    """Record ``n_samples`` states of the constrained expert from ``x0``.

    Parameters
    ----------
    x0 : numpy.ndarray, shape (n,)
    potential : QuadraticPotential or TaskSpacePotential (``value`` and ``policy``)
    constraint : ConstraintFn
    n_samples : int
        ``N`` >= 2.
    dt : float
        Sample period, s.
    name : str, optional
        Trajectory label.

    Returns
    -------
    Demonstration
    """
    if n_samples < 2:
        raise ValueError(f"n_samples: must be >= 2, got {n_samples}")
    if not dt > 0:
        raise ValueError(f"dt: must be > 0 s, got {dt}")
    x = np.asarray(x0, dtype=float).copy()
    n = x.size
    X = np.empty((n_samples, n))
    V = np.empty((n_samples, n))
    P = np.empty((n_samples, n))
    Ns = np.empty((n_samples, n, n))
    k = np.empty(n_samples, dtype=int)
    for i in range(n_samples):
        step = demo_step(x, i * dt, potential, constraint, dt)
        X[i], V[i], P[i], Ns[i] = x, step.velocity, step.policy, step.projector
        k[i] = step.A.shape[0]
        x = step.x_next
    times = dt * np.arange(n_samples)
    traj = Trajectory(X, times, V, name=name)
    return Demonstration(traj, P, Ns, potential.value(X), k)


def sample_start_states(rng: np.random.Generator, center: np.ndarray, n: int,
                        variance: float = 0.1, lower: np.ndarray | None = None,
                        upper: np.ndarray | None = None) -> np.ndarray:
    """Random start states ``x ~ N(center, variance I)`` clipped to limits.

    Parameters
    ----------
    rng : numpy.random.Generator
    center : array_like, shape (d,)
        For example the robot's reference posture ``q_0``.
    n : int
        Number of states.
    variance : float
        Per-coordinate variance (the paper's ``0.1 I``), squared state units.
    lower, upper : array_like (d,), optional
        Limits to clip to (joint limits).

    Returns
    -------
    numpy.ndarray, shape (n, d)
    """
    mean = np.asarray(center, dtype=float)
    if variance < 0:
        raise ValueError(f"variance: must be >= 0, got {variance}")
    X = mean + np.sqrt(variance) * rng.standard_normal((n, mean.size))
    lo = -np.inf if lower is None else np.asarray(lower, dtype=float)
    hi = np.inf if upper is None else np.asarray(upper, dtype=float)
    return np.clip(X, lo, hi)


def generate_demonstrations(potential, starts: np.ndarray,
                            constraint_factory: Callable[[int, np.random.Generator],
                                                         ConstraintFn],
                            n_samples: int, dt: float, rng: np.random.Generator
                            ) -> list[Demonstration]:
    """One demonstration per start state, each with its own constraint generator.

    Parameters
    ----------
    potential : expert potential
    starts : numpy.ndarray, shape (K, n)
    constraint_factory : callable ``(k, rng) -> ConstraintFn``
        Draws the constraint context of demonstration ``k`` (for example a gap width or
        a plane orientation).
    n_samples : int
    dt : float
    rng : numpy.random.Generator

    Returns
    -------
    list of Demonstration
    """
    return [
        rollout(x0, potential, constraint_factory(k, rng), n_samples, dt, name=str(k))
        for k, x0 in enumerate(np.asarray(starts, dtype=float))
    ]


def held_out_masks(demos: Sequence[Demonstration], fraction: float,
                   rng: np.random.Generator) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Random train/test split of the samples of each demonstration.

    Returns
    -------
    train, test : list of bool arrays (N_k,)
        ``test`` holds a random ``fraction`` of the samples of each demonstration.
    """
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction: must be in (0, 1), got {fraction}")
    train, test = [], []
    for d in demos:
        m = d.trajectory.n_samples
        held = np.zeros(m, dtype=bool)
        held[rng.choice(m, size=max(1, round(fraction * m)), replace=False)] = True
        train.append(~held)
        test.append(held)
    return train, test


def stack_ground_truth(demos: Sequence[Demonstration], masks: Sequence[np.ndarray],
                       keep: Sequence[int] | None = None) -> dict[str, np.ndarray]:
    """Concatenate states and ground truth of selected samples of selected demos.

    Returns
    -------
    dict with ``X`` (m, n), ``pi`` (m, n), ``N`` (m, n, n), ``phi`` (m,), ``demo`` (m,)
    """
    idx = range(len(demos)) if keep is None else keep
    parts: dict[str, list[np.ndarray]] = {"X": [], "pi": [], "N": [], "phi": [], "demo": []}
    for k in idx:
        d, m = demos[k], np.asarray(masks[k], dtype=bool)
        parts["X"].append(d.trajectory.positions[m])
        parts["pi"].append(d.policy[m])
        parts["N"].append(d.projectors[m])
        parts["phi"].append(d.potential[m])
        parts["demo"].append(np.full(int(m.sum()), k))
    return {key: np.concatenate(val) for key, val in parts.items()}


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
        z = secondary_velocity(q, self.rest, robot.lower, robot.upper, **self.secondary)
        qdot = joint_velocity_within_limits(q, J, xdot, np.vstack(rows), z, robot.lower,
                                            robot.upper, max_velocity=max_velocity, dt=dt,
                                            **self.solve)
        return qdot, StepResult(x + xdot, xdot, N_x, pi_x, A_x)


@dataclass
class TaskSpaceDemonstration(Demonstration):
    """A hand-space demonstration: the :class:`Demonstration` fields are in hand space.

    ``trajectory`` holds the hand states ``x_i = x(q_i)`` (N, 3F) with the expert's
    velocities ``N_x pi_x`` (N, 3F); ``policy`` is ``pi_x`` (N, 3F), ``projectors`` are
    ``N_x`` (N, 3F, 3F) and ``potential`` is ``phi_x(x_i)``.

    Attributes
    ----------
    joints : Trajectory
        The joint trajectory ``q_i`` (N, n) (what a robot's joint states record) with the
        joint velocities sent (N, n), rad/s.
    """

    joints: Trajectory | None = None


#: ``constraint(x (3F,), t [s], pi_x (3F,)) -> A_x (k, 3F)``, hand-space rows.
TaskConstraintFn = ConstraintFn


def task_space_rollout(q0: np.ndarray, expert: TaskSpaceExpert,
                       constraint: TaskConstraintFn | None, n_samples: int, dt: float,
                       *, name: str | None = None) -> TaskSpaceDemonstration:
    """Record ``n_samples`` states of a hand-space expert driven through the joints.

    Each step sends ``qdot`` from :meth:`TaskSpaceExpert.command` (joints held at their
    speed and position bounds, the hand motion kept) for ``dt`` seconds, scaled down
    (never redirected) only where the other joints cannot make up for them.

    Parameters
    ----------
    q0 : numpy.ndarray, shape (n,)
        Start posture (rad).
    expert : TaskSpaceExpert
    constraint : TaskConstraintFn or None
        Hand-space constraint generator (None: unconstrained).
    n_samples : int
        ``N`` >= 2.
    dt : float
        Sample period, s.
    name : str, optional

    Returns
    -------
    TaskSpaceDemonstration
    """
    if n_samples < 2:
        raise ValueError(f"n_samples: must be >= 2, got {n_samples}")
    if not dt > 0:
        raise ValueError(f"dt: must be > 0 s, got {dt}")
    robot = expert.state_map.robot
    q = robot.clip(np.asarray(q0, dtype=float).copy())
    n, d = expert.n, expert.dim
    Q, Qd = np.empty((n_samples, n)), np.empty((n_samples, n))
    X, V, P = (np.empty((n_samples, d)) for _ in range(3))
    Ns = np.empty((n_samples, d, d))
    k = np.empty(n_samples, dtype=int)
    vmax = np.where(np.isfinite(robot.velocity_limit) & (robot.velocity_limit > 0),
                    robot.velocity_limit, np.inf)
    for i in range(n_samples):
        x = expert.state_map.states(q)
        A_x = None
        if constraint is not None:
            A_x = constraint(x, i * dt, expert.task_policy(x[None])[0])
        qdot, step = expert.command(q, A_x, max_velocity=vmax, dt=dt)
        s = velocity_scale(q, qdot, dt, robot.lower, robot.upper, vmax)
        Q[i], Qd[i] = q, s * qdot
        X[i], V[i], P[i], Ns[i], k[i] = x, s * step.velocity, step.policy, step.projector, \
            step.A.shape[0]
        q = robot.clip(q + dt * s * qdot)
    times = dt * np.arange(n_samples)
    return TaskSpaceDemonstration(Trajectory(X, times, V, name=name), P, Ns,
                                  expert.potential.value(X), k,
                                  joints=Trajectory(Q, times, Qd, name=name))
