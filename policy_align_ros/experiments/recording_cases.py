"""Suite cases that look like recordings of real teachers and robots.

Each case is an exact expert of the suite (:mod:`policy_align_ros.experiments.suite_cases`)
recorded through one distortion of :mod:`policy_align_ros.sim.recording`; the closed-loop
test and the held-out errors compare with the exact expert, and ``Problem.minimum`` is the
expert's true minimum (computed numerically where it has no closed form):

- ``lag_joint_7``: a 7-joint quadratic expert (gain 0.5-2 /s) tracked by a robot with an
  80 ms velocity lag, 1 rad/s and 5 rad/s^2 per joint, at 50 Hz;
- ``lag_slow_7``: the same through a 250 ms lag (a compliant arm's slow velocity loop):
  gain times lag up to 0.5, past critical damping (0.25), so the arm passes its goal along
  its stiffest directions (by about 1 % of the start distance) and comes back;
- ``human_timing_2``: the expert's 2-D path travelled with a minimum-jerk timing, at rest
  for 0.2-0.5 s before and 0.3-0.8 s after, 0.6-1.6 times the expert's duration;
- ``contact_arm_7``: the suite's arm expert pushing its hand into a table (friction
  coefficient 0.4) beside the random hand planes, at 25 Hz;
- ``bumps_2`` and ``bumps_noisy_6``: a quadratic-plus-conic attractor with two small
  Gaussian bumps that shift its minimum; the 6-D one at 100 Hz through a 14-bit encoder
  with white noise and 1 ms stamp jitter;
- ``kinesthetic_7``: a person guiding the suite's arm expert freely to its goal: the
  expert's converged path with a minimum-jerk timing of 2-5 s, at rest before and after,
  read at 50 Hz through the same encoder, velocities differenced;
- ``dynamics_arm_7``: the joint-space expert ``qdot = -(q - q_c)``, at most 1 rad/s per
  joint, driving a rigid-body Panda (:mod:`policy_align_ros.sim.dynamics`) through joint-
  velocity servos of 50 ms (coupled through the arm's mass matrix, within its effort
  limits), its hand pressing into and sliding on a surface (friction coefficient 0.4),
  recorded at 50 Hz.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from policy_align_ros.experiments.suite_cases import (
    CASES,
    ArmPotential,
    Case,
    Problem,
    hand_planes,
    hold_hand,
    locked_coordinates,
    numerical_minimum,
    random_rows,
)
from policy_align_ros.kinematics import nullspace_projector
from policy_align_ros.sim.demonstrations import (
    ConstraintFn,
    Demonstration,
    no_constraint,
    rollout,
)
from policy_align_ros.sim.dynamics import ContactPlane, ServoArm
from policy_align_ros.sim.experts import QuadraticPotential, TaskSpacePotential
from policy_align_ros.sim.recording import (
    encoder_noise,
    retime_path,
    stamp_jitter,
    table_contact_rollout,
    track_velocity,
    with_ground_truth,
)

__all__ = ["RECORDING_CASES", "BumpsPotential", "CappedQuadratic", "contact_arm", "dynamics_arm",
           "numerical_minimum"]


class BumpsPotential:
    """``phi = (x-c)^T W (x-c) + a sqrt(|x-c|^2 + e^2) + sum_i h_i exp(-|x-b_i|^2 / 2s^2)``.

    A quadratic-plus-conic attractor at ``c`` with Gaussian bumps of heights ``h`` (>0:
    repulsive) at ``b`` (k, n) and width ``s``: no single trend family holds it.
    """

    def __init__(self, centre: np.ndarray, W: np.ndarray, cone: float, bumps: np.ndarray,
                 heights: np.ndarray, width: float, eps: float = 0.05):
        self.centre, self.W, self.cone = centre, W, cone
        self.bumps, self.heights, self.width, self.eps = bumps, heights, width, eps
        self.n = centre.size

    def _parts(self, X):
        d = X - self.centre
        r = np.sqrt(np.sum(d**2, axis=1) + self.eps**2)
        db = X[:, None, :] - self.bumps[None]
        g = self.heights * np.exp(-0.5 * np.sum(db**2, axis=2) / self.width**2)
        return d, r, db, g

    def value(self, X: np.ndarray) -> np.ndarray:
        d, r, _, g = self._parts(np.atleast_2d(X))
        return np.einsum("mi,ij,mj->m", d, self.W, d) + self.cone * r + g.sum(axis=1)

    def policy(self, X: np.ndarray) -> np.ndarray:
        d, r, db, g = self._parts(np.atleast_2d(X))
        grad = (d @ (self.W + self.W.T) + self.cone * d / r[:, None]
                - np.einsum("mk,mkn->mn", g, db) / self.width**2)
        return -grad


def _rotation(n: int, rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((n, n)))
    return q * np.sign(np.diag(r))


def _anisotropic(n: int, rng: np.random.Generator, low: float, high: float) -> np.ndarray:
    R = _rotation(n, rng)
    return R @ np.diag(np.exp(rng.uniform(np.log(low), np.log(high), n))) @ R.T


def _starts_around(centre: np.ndarray, rng: np.random.Generator, spread: float = 0.35
                   ) -> Callable[[np.random.Generator, int], np.ndarray]:
    direction = rng.standard_normal(centre.size)
    home = centre + direction / np.linalg.norm(direction)
    return lambda r, m: home + spread * r.standard_normal((m, centre.size))


def _truth_projectors(potential, constraint: ConstraintFn, X: np.ndarray, times: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    n = X.shape[1]
    Ns, k = np.empty((len(X), n, n)), np.empty(len(X), dtype=int)
    for i, (x, t) in enumerate(zip(X, times, strict=True)):
        A = np.atleast_2d(constraint(x, t, potential.policy(x[None])[0])).reshape(-1, n)
        Ns[i], k[i] = nullspace_projector(A, n=n), A.shape[0]
    return Ns, k


# -- 1. velocity tracking with lag and saturation -----------------------------------------

def _lag_joint(rng: np.random.Generator, tau: float = 0.08) -> Problem:
    n, hz, duration = 7, 50.0, 5.0
    centre = rng.normal(scale=0.5, size=n)
    potential = QuadraticPotential(centre, _anisotropic(n, rng, 0.25, 1.0))
    dt = 1.0 / hz

    def record(x0, constraint, r, name) -> Demonstration:
        def command(x, t):
            pi = potential.policy(x[None])[0]
            A = np.atleast_2d(constraint(x, t, pi)).reshape(-1, n)
            return nullspace_projector(A, n=n) @ pi

        X, V, times = track_velocity(x0, command, int(hz * duration), dt, tau=tau,
                                     max_speed=1.0, max_accel=5.0)
        Ns, k = _truth_projectors(potential, constraint, X, times)
        return with_ground_truth(X, V, times, potential, Ns, k, name=name)

    return Problem(potential, dt, int(hz * duration), 40, _starts_around(centre, rng),
                   lambda r: random_rows(n, duration, r), locked_coordinates(n, 2),
                   record=record, minimum=centre)


# -- 2. human-like timing along the expert's path ----------------------------------------

def _human_timing(rng: np.random.Generator) -> Problem:
    n, hz, duration = 2, 50.0, 3.0
    centre = rng.normal(scale=0.5, size=n)
    potential = QuadraticPotential(centre, _anisotropic(n, rng, 0.25, 2.5))
    dt = 1.0 / hz
    steps = int(hz * duration)

    def record(x0, constraint, r, name) -> Demonstration:
        path = rollout(x0, potential, constraint, steps, dt)
        X, V, times, index = retime_path(
            path.trajectory.positions, duration * r.uniform(0.6, 1.6), dt,
            rest_before=r.uniform(0.2, 0.5), rest_after=r.uniform(0.3, 0.8))
        near = np.clip(np.rint(index).astype(int), 0, steps - 1)
        return with_ground_truth(X, V, times, potential, path.projectors[near],
                                 path.n_active[near], name=name)

    return Problem(potential, dt, steps, 30, _starts_around(centre, rng),
                   lambda r: random_rows(n, duration, r), locked_coordinates(n, 1),
                   record=record, minimum=centre)


# -- 3. a hand sliding on a table with friction -------------------------------------------

_ARM: dict = {}
#: Height of the table top over the hand at the true minimum, m.
TABLE_ABOVE_MINIMUM = -0.02


def _arm_robot():
    if "robot" not in _ARM:
        from policy_align_ros.kinematics import Robot

        _ARM["robot"] = Robot.load("panda", joints=[f"panda_joint{i}" for i in range(1, 8)])
    return _ARM["robot"]


def contact_arm(rng: np.random.Generator, *, mu: float = 0.4, table: bool = True) -> Problem:
    """The ``contact_arm_7`` problem of one seed (``rng``); ``mu`` the friction coefficient,
    ``table=False`` no table under the same starts and planes (an exact recording): what
    the contact alone costs (``tools/contact_ablation.py``)."""
    robot, frame = _arm_robot(), "panda_hand_tcp"
    q_c = np.clip(robot.neutral() + rng.normal(scale=0.2, size=robot.nq), robot.lower,
                  robot.upper)
    # The hand target lies 0.15 m below the posture's hand: the expert pushes it down.
    target = robot.frame_position(q_c, frame) + np.concatenate(
        [rng.normal(scale=0.05, size=2), [-0.15]])
    potential = ArmPotential(TaskSpacePotential(robot, [frame], target, weight=4.0), 0.3, q_c)
    bounds = list(zip(robot.lower, robot.upper, strict=True))
    minimum = numerical_minimum(potential, q_c, bounds)
    height = float(robot.frame_position(minimum, frame)[2]) + TABLE_ABOVE_MINIMUM
    home = np.clip(q_c + rng.normal(scale=0.5, size=robot.nq), robot.lower, robot.upper)
    hz, duration = 25.0, 4.0

    def starts(r, m):
        out = []
        while len(out) < m:  # starts with the hand at least 3 cm above the table
            q = np.clip(home + 0.2 * r.standard_normal(robot.nq), robot.lower, robot.upper)
            if robot.frame_position(q, frame)[2] >= height + 0.03:
                out.append(q)
        return np.array(out)

    def record(q0, constraint, r, name) -> Demonstration:
        Q, Qd, Ns, k = table_contact_rollout(q0, potential.policy, robot, frame,
                                             height if table else -np.inf, mu,
                                             int(hz * duration), 1.0 / hz, constraint)
        return with_ground_truth(Q, Qd, np.arange(len(Q)) / hz, potential, Ns, k, name=name)

    return Problem(potential, 1.0 / hz, int(hz * duration), 40, starts,
                   lambda r: hand_planes(robot, frame, duration, r),
                   hold_hand(robot, frame), record=record, minimum=minimum,
                   extras={"hand": potential.hand, "table": height if table else None})


# -- 4 and 5. local features; encoder noise and stamp jitter ------------------------------

def _bumps_case(n: int, hz: float, duration: float, k: int, noisy: bool
                ) -> Callable[[np.random.Generator], Problem]:
    def make(rng: np.random.Generator) -> Problem:
        centre = rng.normal(scale=0.5, size=n)
        dirs = rng.standard_normal((2, n))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        bumps = centre + 0.15 * dirs
        potential = BumpsPotential(centre, _anisotropic(n, rng, 0.25, 1.0), 0.15, bumps,
                                   np.array([0.04, 0.03]), 0.15)
        minimum = numerical_minimum(potential, centre)
        dt, steps = 1.0 / hz, int(hz * duration)

        def record(x0, constraint, r, name) -> Demonstration:
            demo = rollout(x0, potential, constraint, steps, dt, name=name)
            if not noisy:
                return demo
            X = demo.trajectory.positions
            # A 14-bit encoder per turn, white noise of a fifth of a count, 1 ms jitter.
            read = encoder_noise(X, 2 * np.pi / 2**14, 0.2 * 2 * np.pi / 2**14, r)
            times = stamp_jitter(demo.trajectory.times, 1e-3, r)
            # Drivers report velocities differenced from the encoder at the true rate.
            V = np.gradient(read, demo.trajectory.times, axis=0)
            return with_ground_truth(read, V, times, potential, demo.projectors,
                                     demo.n_active, name=name, truth_at=X)

        return Problem(potential, dt, steps, k, _starts_around(centre, rng),
                       lambda r: random_rows(n, duration, r),
                       locked_coordinates(n, max(1, n // 4)), record=record, minimum=minimum)

    return make


# -- 6. kinesthetic teaching: free paths to one goal, a person's timing, encoders --------

#: The expert's path runs this long (s, at 100 Hz) before it is re-timed: about 6 of the
#: posture term's time constants, so every demonstration ends at the goal it means.
KINESTHETIC_PATH = 10.0


def _kinesthetic(rng: np.random.Generator) -> Problem:
    # arm_task_7's expert, starts and unseen constraint, drawn alike from the seed.
    arm = CASES["arm_task_7"].make(rng)
    n, hz, duration = arm.potential.n, 50.0, 3.0

    def record(q0, constraint, r, name) -> Demonstration:
        path = rollout(q0, arm.potential, constraint, int(100 * KINESTHETIC_PATH), 0.01)
        X, _, times, _ = retime_path(path.trajectory.positions, duration * r.uniform(0.6, 1.6),
                                     1.0 / hz, rest_before=r.uniform(0.2, 0.5),
                                     rest_after=r.uniform(0.3, 0.8))
        # The same 14-bit encoders and 1 ms jitter as bumps_noisy_6; velocities differenced.
        read = encoder_noise(X, 2 * np.pi / 2**14, 0.2 * 2 * np.pi / 2**14, r)
        V = np.gradient(read, times, axis=0)
        eye = np.broadcast_to(np.eye(n), (len(X), n, n))
        return with_ground_truth(read, V, stamp_jitter(times, 1e-3, r), arm.potential, eye,
                                 np.zeros(len(X), dtype=int), name=name, truth_at=X)

    free = no_constraint(n)
    return replace(arm, dt=1.0 / hz, n_samples=int(hz * duration), n_train=8,
                   training_constraint=lambda r: free, record=record)


# -- 7. a physical arm: rigid-body dynamics, joint-velocity servos, a surface with friction

#: Time constant of ``dynamics_arm_7``'s joint-velocity servos at the reference posture, s.
SERVO_TAU = 0.05
#: The surface lies this far (m) from the hand at the goal, across the free paths' bulge.
SURFACE_CLEARANCE = 0.02


class CappedQuadratic:
    """``phi = sum_i h(x_i - c_i)``, ``h`` quadratic (``d^2 / 2``) up to ``|d| = cap`` and
    linear beyond: the policy ``-clip(x - c, -cap, cap)``, a joint-space servo to ``c``
    at gain 1 /s whose speed is capped at ``cap`` per joint (state units, units/s)."""

    def __init__(self, centre: np.ndarray, cap: float = 1.0) -> None:
        self.centre, self.cap, self.n = np.asarray(centre, dtype=float), float(cap), len(centre)

    def value(self, X: np.ndarray) -> np.ndarray:
        """Potential at rows of ``X`` (m, n); returns (m,)."""
        a = np.abs(np.atleast_2d(X) - self.centre)
        return np.sum(np.where(a <= self.cap, 0.5 * a**2, self.cap * (a - 0.5 * self.cap)),
                      axis=1)

    def policy(self, X: np.ndarray) -> np.ndarray:
        """``-grad phi`` at rows of ``X`` (m, n); returns (m, n), units/s."""
        return -np.clip(np.atleast_2d(X) - self.centre, -self.cap, self.cap)


def _path_bulge(P: np.ndarray) -> np.ndarray:
    """The hand path's (m, 3) largest deviation from its chord, as a vector (3,), m."""
    chord = (P[-1] - P[0]) / max(float(np.linalg.norm(P[-1] - P[0])), 1e-12)
    off = (P - P[0]) - np.outer((P - P[0]) @ chord, chord)
    return off[np.argmax(np.linalg.norm(off, axis=1))]


def _surface_and_home(robot, frame: str, potential: CappedQuadratic, q_c: np.ndarray,
                      rng: np.random.Generator) -> tuple[ContactPlane, np.ndarray]:
    """A home posture and a plane its free paths press into on their way to the goal.

    Of 20 candidate homes whose free hand path bulges off its chord by more than twice
    ``SURFACE_CLEARANCE`` (else few paths would reach the plane), the one whose path sags
    most (its bulge's downward component; the first candidate when none bulges enough);
    the plane lies ``SURFACE_CLEARANCE`` from the goal's hand against the bulge, so the
    goal stays free and paths from around the home slide on the plane: a table when the
    sag is straight down, a tilted desk or a wall otherwise, a ceiling when no path sags.
    """
    best = None
    for _ in range(20):
        home = np.clip(q_c + rng.normal(scale=0.5, size=robot.nq), robot.lower, robot.upper)
        q, hand = home.copy(), []
        for _ in range(200):
            hand.append(robot.frame_position(q, frame))
            q = robot.clip(q + 0.02 * potential.policy(q[None])[0])
        bulge = _path_bulge(np.array(hand))
        enough = float(np.linalg.norm(bulge)) > 2 * SURFACE_CLEARANCE
        if best is None or (enough, -bulge[2]) > (best[2], -best[1][2]):
            best = (home, bulge, enough)
    home, bulge, _ = best
    normal = -bulge / np.linalg.norm(bulge)
    offset = float(normal @ robot.frame_position(q_c, frame)) - SURFACE_CLEARANCE
    return ContactPlane(tuple(normal), offset), home


def dynamics_arm(rng: np.random.Generator, *, mu: float = 0.4, surface: bool = True
                 ) -> Problem:
    """The ``dynamics_arm_7`` problem of one seed (``rng``): ``mu`` the surface's friction
    coefficient, ``surface=False`` the same arm, starts and servos without the surface."""
    robot, frame = _arm_robot(), "panda_hand_tcp"
    q_c = np.clip(robot.neutral() + rng.normal(scale=0.2, size=robot.nq), robot.lower,
                  robot.upper)
    potential = CappedQuadratic(q_c)  # qdot = -(q - q_c), at most 1 rad/s per joint
    plane, home = _surface_and_home(robot, frame, potential, q_c, rng)
    plane = replace(plane, mu=mu)
    normal = np.asarray(plane.normal)
    arm = ServoArm(robot, frame, [plane] if surface else [], tau=SERVO_TAU)
    hz, duration = 50.0, 5.0

    def starts(r, m):
        out = []
        while len(out) < m:  # starts with the hand at least 3 cm off the surface
            q = np.clip(home + 0.2 * r.standard_normal(robot.nq), robot.lower, robot.upper)
            if normal @ robot.frame_position(q, frame) >= plane.offset + 0.03:
                out.append(q)
        return np.array(out)

    def record(q0, constraint, r, name) -> Demonstration:
        def command(q, t):
            pi = potential.policy(q[None])[0]
            A = np.atleast_2d(constraint(q, t, pi)).reshape(-1, robot.nq)
            return nullspace_projector(A, n=robot.nq) @ pi

        Q, V, times, touching = arm.run(q0, command, int(hz * duration), 1.0 / hz)
        Ns, k = _truth_projectors(potential, constraint, Q, times)
        for i in np.flatnonzero(touching):  # the clean projection friction departs from
            row = normal @ robot.frame_jacobian(Q[i], frame)
            Ns[i] = nullspace_projector(np.vstack([np.eye(robot.nq) - Ns[i], row[None]]),
                                        n=robot.nq)
            k[i] = robot.nq - int(round(np.trace(Ns[i])))
        return with_ground_truth(Q, V, times, potential, Ns, k, name=name)

    return Problem(potential, 1.0 / hz, int(hz * duration), 40, starts,
                   lambda r: no_constraint(robot.nq), hold_hand(robot, frame),
                   record=record, minimum=q_c,
                   extras={"hand": lambda q: robot.frame_position(q, frame),
                           "surface": plane if surface else None})


RECORDING_CASES = {
    "lag_joint_7": Case("lag_joint_7", 7, "50 Hz", _lag_joint),
    "lag_slow_7": Case("lag_slow_7", 7, "50 Hz", lambda rng: _lag_joint(rng, tau=0.25)),
    "human_timing_2": Case("human_timing_2", 2, "50 Hz", _human_timing),
    "contact_arm_7": Case("contact_arm_7", 7, "25 Hz", contact_arm),
    "bumps_2": Case("bumps_2", 2, "50 Hz", _bumps_case(2, 50.0, 4.0, 30, False)),
    "bumps_noisy_6": Case("bumps_noisy_6", 6, "100 Hz", _bumps_case(6, 100.0, 4.0, 40, True)),
    "kinesthetic_7": Case("kinesthetic_7", 7, "50 Hz", _kinesthetic),
    "dynamics_arm_7": Case("dynamics_arm_7", 7, "50 Hz", dynamics_arm),
}
