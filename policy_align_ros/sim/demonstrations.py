"""Constrained demonstrations of an expert: constraint generators, rollouts, ground truth.

Notation (paper, section II and eq. 5): state ``x`` (n,) (joint positions in rad, or
task-space positions in m), true policy ``pi(x) = -grad phi(x)`` in state units per
second (:mod:`policy_align_ros.sim.experts`), constraint ``A(x, t, pi)`` (k, n), projector
``N = I - pinv(A) A`` (n, n). One step of length ``dt`` (s) is the explicit Euler step of
the constrained motion, ``x_{i+1} = x_i + dt N_i pi_i``; the recorded velocity is
``xdot_i = N_i pi_i``. With ``dt = 1`` this is the paper's convention exactly.

A constraint generator is any callable ``constraint(x, t, pi) -> A``: it sees the state,
the time (s, from the demonstration start) and the intended policy (needed by unilateral
barriers that only block approaching motion). :func:`demo_step` runs one step, so a ROS
node can drive the same expert one control period at a time. Hand-space demonstrations
(:func:`task_space_rollout`) drive a :class:`~policy_align_ros.sim.experts.TaskSpaceExpert`
through the joints.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from policy_align_ros.control import velocity_scale
from policy_align_ros.kinematics import Constraint, nullspace_projector
from policy_align_ros.learning import Trajectory
from policy_align_ros.sim.experts import StepResult, TaskSpaceExpert

__all__ = [
    "ConstraintFn",
    "Demonstration",
    "TaskSpaceDemonstration",
    "task_space_rollout",
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


def no_constraint(n: int) -> ConstraintFn:
    """The unconstrained case: ``A`` of shape (0, n) always."""
    empty = np.zeros((0, n))
    return lambda x, t, pi: empty


def from_constraint(constraint: Constraint) -> ConstraintFn:
    """Wrap a joint-space :class:`Constraint` (its ``matrix(q, qdot)``) as a generator."""
    return lambda x, t, pi: constraint.matrix(x, pi)


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
