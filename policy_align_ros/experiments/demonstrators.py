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
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from policy_align_ros.kinematics import Constraint, Robot, nullspace_projector
from policy_align_ros.learning import Trajectory

__all__ = [
    "ConstraintFn",
    "Demonstration",
    "QuadraticPotential",
    "TaskSpacePotential",
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
