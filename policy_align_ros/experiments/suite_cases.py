"""The suite's cases: expert potentials, constraint generators and one problem per seed.

Each case is an expert potential ``phi`` (state units^2 per second) with a start
distribution, a generator of the constraints re-drawn within every training
demonstration, and one constraint never demonstrated (for the closed-loop test of
:mod:`policy_align_ros.experiments.suite`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from policy_align_ros.sim.demonstrations import ConstraintFn
from policy_align_ros.sim.experts import QuadraticPotential, TaskSpacePotential

__all__ = ["CASES", "Case", "Problem", "ArmPotential", "SinusoidPotential",
           "TwoMinimaPotential", "hand_planes", "hold_hand", "locked_coordinates",
           "numerical_minimum", "random_rows"]

# -- expert potentials ------------------------------------------------------------------

class SinusoidPotential:
    """The paper's sinusoidal potential ``phi = 0.1 sin(x1) cos(x2)`` (dt = 1 units)."""

    n = 2

    def value(self, X: np.ndarray) -> np.ndarray:
        return 0.1 * np.sin(X[:, 0]) * np.cos(X[:, 1])

    def policy(self, X: np.ndarray) -> np.ndarray:
        return -0.1 * np.stack([np.cos(X[:, 0]) * np.cos(X[:, 1]),
                                -np.sin(X[:, 0]) * np.sin(X[:, 1])], axis=1)


class TwoMinimaPotential:
    """``phi = w ||x||^2 - sum_i d_i exp(-||x - m_i||^2 / (2 s^2))``: two minima, depths d."""

    def __init__(self, minima: np.ndarray, depths: np.ndarray, width: float, bowl: float):
        self.minima, self.depths, self.width, self.bowl = minima, depths, width, bowl
        self.n = minima.shape[1]

    def _bumps(self, X):
        d = X[:, None, :] - self.minima[None]
        return self.depths * np.exp(-0.5 * np.sum(d**2, axis=2) / self.width**2), d

    def value(self, X: np.ndarray) -> np.ndarray:
        b, _ = self._bumps(X)
        return self.bowl * np.sum(X**2, axis=1) - b.sum(axis=1)

    def policy(self, X: np.ndarray) -> np.ndarray:
        b, d = self._bumps(X)
        grad = 2.0 * self.bowl * X + np.einsum("mk,mkn->mn", b, d) / self.width**2
        return -grad


class ArmPotential:
    """``phi(q) = a ||p(q) - p_c||^2 + b ||q - q_c||^2`` for a hand frame ``p`` of an arm."""

    def __init__(self, task: TaskSpacePotential, joint_weight: float, q_c: np.ndarray):
        self.task, self.b, self.q_c = task, joint_weight, q_c
        self.n = task.n

    def value(self, X: np.ndarray) -> np.ndarray:
        return self.task.value(X) + self.b * np.sum((X - self.q_c) ** 2, axis=1)

    def policy(self, X: np.ndarray) -> np.ndarray:
        return self.task.policy(X) - 2.0 * self.b * (X - self.q_c)

    def hand(self, q: np.ndarray) -> np.ndarray:
        return self.task.robot.frame_position(q, self.task.frames[0])


def numerical_minimum(potential, x0: np.ndarray, bounds=None) -> np.ndarray:
    """The local minimum of ``potential`` (``value``, ``policy = -grad``) reached from ``x0``.

    Parameters
    ----------
    potential : object with ``value(X (m, n)) -> (m,)`` and ``policy(X) -> (m, n)``
    x0 : numpy.ndarray, shape (n,)
    bounds : sequence of (low, high), optional

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    res = minimize(lambda x: float(potential.value(x[None])[0]), np.asarray(x0, float),
                   jac=lambda x: -potential.policy(x[None])[0], method="L-BFGS-B",
                   bounds=bounds, options={"gtol": 1e-10, "ftol": 1e-14, "maxiter": 2000})
    return res.x


# -- constraints ------------------------------------------------------------------------

def random_rows(n: int, duration: float, rng: np.random.Generator, switches: int = 2
                ) -> ConstraintFn:
    """Random Gaussian rows (1 to max(1, n/2) of them), re-drawn ``switches`` times."""
    segments = [rng.standard_normal((int(rng.integers(1, max(1, n // 2) + 1)), n))
                for _ in range(switches + 1)]

    def constraint(x, t, pi):
        return segments[min(int(t / duration * len(segments)), len(segments) - 1)]

    return constraint


def locked_coordinates(n: int, k: int) -> ConstraintFn:
    """Hold the first ``k`` coordinates (``A`` = the first ``k`` rows of ``I``)."""
    A = np.eye(n)[:k]
    return lambda x, t, pi: A


def hand_planes(robot, frame: str, duration: float, rng: np.random.Generator,
                switches: int = 2) -> ConstraintFn:
    """A plane through the moving hand with a random normal, re-drawn within the demo."""
    normals = rng.standard_normal((switches + 1, 3))

    def constraint(q, t, pi):
        normal = normals[min(int(t / duration * len(normals)), len(normals) - 1)]
        return (normal / np.linalg.norm(normal)) @ robot.frame_jacobian(q, frame)

    return constraint


def hold_hand(robot, frame: str, axes: tuple[int, ...] = (0, 1)) -> ConstraintFn:
    """Hold the hand in place along ``axes`` (rows of its translational Jacobian)."""
    return lambda q, t, pi: robot.frame_jacobian(q, frame)[list(axes)]


# -- cases ------------------------------------------------------------------------------

@dataclass
class Problem:
    """One data set's expert: potential, sampling, starts and constraints."""

    potential: object
    dt: float
    n_samples: int
    n_train: int
    sample_starts: Callable[[np.random.Generator, int], np.ndarray]
    training_constraint: Callable[[np.random.Generator], ConstraintFn]
    unseen_constraint: ConstraintFn
    minima: np.ndarray | None = None
    sigma: str = "medium"
    extras: dict = field(default_factory=dict)
    #: ``record(x0, constraint, rng, name) -> Demonstration``: how a demonstration is
    #: recorded (None: the exact constrained expert, ``sim.demonstrations.rollout``).
    record: Callable | None = None
    #: The expert's true minimum (n,), for the learnt-minimum column (None: not reported).
    minimum: np.ndarray | None = None


@dataclass
class Case:
    """A named family of problems, one per seed."""

    name: str
    n: int
    rate: str
    make: Callable[[np.random.Generator], Problem]


def _rotation(n: int, rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((n, n)))
    return q * np.sign(np.diag(r))


def _quadratic_case(n: int, anisotropic: bool, hz: float, duration: float, k: int,
                    sigma: str = "medium") -> Callable[[np.random.Generator], Problem]:
    def make(rng: np.random.Generator) -> Problem:
        centre = rng.normal(scale=0.5, size=n)
        if anisotropic:
            R = _rotation(n, rng)
            W = R @ np.diag(np.exp(rng.uniform(np.log(0.25), np.log(2.5), n))) @ R.T
        else:
            W = 0.8 * np.eye(n)
        direction = rng.standard_normal(n)
        home = centre + direction / np.linalg.norm(direction)

        def starts(r, m):
            return home + 0.35 * r.standard_normal((m, n))

        dt = 1.0 / hz
        return Problem(
            QuadraticPotential(centre, W), dt, int(round(duration * hz)), k, starts,
            lambda r: random_rows(n, duration, r), locked_coordinates(n, max(1, n // 4)),
            sigma=sigma,
        )

    return make


def _sinusoid(rng: np.random.Generator) -> Problem:
    def starts(r, m):
        return r.uniform(-2.0, 2.0, size=(m, 2))

    return Problem(SinusoidPotential(), 1.0, 40, 40, starts,
                   lambda r: random_rows(2, 40.0, r), locked_coordinates(2, 1))


def _two_minima(rng: np.random.Generator) -> Problem:
    minima = np.array([[-0.8, 0.0], [0.8, 0.1]]) + rng.normal(scale=0.05, size=(2, 2))
    potential = TwoMinimaPotential(minima, np.array([1.0, 0.6]), 0.5, 0.25)

    def starts(r, m):
        return r.uniform([-1.8, -1.2], [1.8, 1.2], size=(m, 2))

    hz, duration = 50.0, 4.0
    return Problem(potential, 1.0 / hz, int(hz * duration), 40, starts,
                   lambda r: random_rows(2, duration, r), locked_coordinates(2, 1),
                   minima=minima)


_ARM = {}


def _arm_robot():
    if "robot" not in _ARM:
        from policy_align_ros.kinematics import Robot

        _ARM["robot"] = Robot.load("panda", joints=[f"panda_joint{i}" for i in range(1, 8)])
    return _ARM["robot"]


def _arm(rng: np.random.Generator) -> Problem:
    robot = _arm_robot()
    frame = "panda_hand_tcp"
    q_ref = robot.neutral()
    q_c = np.clip(q_ref + rng.normal(scale=0.2, size=robot.nq), robot.lower, robot.upper)
    target = robot.frame_position(q_c, frame) + rng.normal(scale=0.05, size=3)
    task = TaskSpacePotential(robot, [frame], target, weight=4.0)
    potential = ArmPotential(task, 0.3, q_c)
    minimum = numerical_minimum(potential, q_c, list(zip(robot.lower, robot.upper, strict=True)))
    home = np.clip(q_c + rng.normal(scale=0.5, size=robot.nq), robot.lower, robot.upper)

    def starts(r, m):
        return np.clip(home + 0.2 * r.standard_normal((m, robot.nq)), robot.lower, robot.upper)

    hz, duration = 25.0, 4.0
    return Problem(potential, 1.0 / hz, int(hz * duration), 40, starts,
                   lambda r: hand_planes(robot, frame, duration, r),
                   hold_hand(robot, frame), minimum=minimum, extras={"hand": potential.hand})


CASES = {
    "quad_iso_2": Case("quad_iso_2", 2, "50 Hz", _quadratic_case(2, False, 50.0, 3.0, 30)),
    "quad_aniso_3": Case("quad_aniso_3", 3, "50 Hz", _quadratic_case(3, True, 50.0, 4.0, 40)),
    "quad_aniso_4": Case("quad_aniso_4", 4, "100 Hz",
                         _quadratic_case(4, True, 100.0, 4.0, 40)),
    "quad_iso_7": Case("quad_iso_7", 7, "20 Hz", _quadratic_case(7, False, 20.0, 6.0, 60)),
    "quad_aniso_7": Case("quad_aniso_7", 7, "20 Hz", _quadratic_case(7, True, 20.0, 6.0, 60)),
    "quad_aniso_22": Case("quad_aniso_22", 22, "10 Hz",
                          _quadratic_case(22, True, 10.0, 8.0, 100, sigma="narrow")),
    "sinusoid": Case("sinusoid", 2, "dt = 1", _sinusoid),
    "two_minima": Case("two_minima", 2, "50 Hz", _two_minima),
    "arm_task_7": Case("arm_task_7", 7, "25 Hz", _arm),
}
