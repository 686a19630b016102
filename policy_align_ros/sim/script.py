"""The demonstration script: the expert, its random starts and planes, its commands.

Two experts (``mode``):

* ``joints``: ``pi(q) = -gain (q - attractor)`` (rad/s), the negative gradient of the
  quadratic potential ``phi = gain/2 ||q - attractor||^2`` in joint space (the paper's
  eq. 20 with ``W = gain/2 I``); under constraint rows ``A(q)`` it commands ``N(q) pi(q)``.
  For a continuous joint, ``q - attractor`` is the shortest angle
  ``(q - attractor + pi) mod 2 pi - pi``: a driver reports its angle modulo a turn, and
  the plain difference would drive it the long way round;
* ``hands``: a potential in the stacked positions ``x`` (3F,) of ``hand_frames`` (m),
  ``phi_x = gain/2 ||x - hand_targets||^2``, ``pi_x = -grad phi_x`` (m/s). The hands move
  with ``xdot = N_x pi_x`` (``N_x`` the projector of the hand-space plane rows), realised
  through the frames' Jacobian with a secondary pull of the redundant joints towards
  ``attractor`` (:class:`policy_align_ros.sim.experts.TaskSpaceExpert`).

Each demonstration starts at a random ``q0 ~ N(attractor, start_variance I)`` (clipped to
the joint limits), reached with a proportional controller; every frame of
``constraint_frames`` is restricted to a plane of uniformly random orientation through
its current position, re-drawn ``plane_switches`` times at regular intervals (the paper's
switching constraints: with one plane per demonstration, every demonstration ends at its
own point and the potentials can hardly be aligned).

This module is ROS-free; ``policy_align_ros.nodes.demonstrator`` runs it on a robot.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from policy_align_ros.control import (
    DEFAULT_JOINT_LIMIT_MARGIN,
    constrained_command,
    inner_limits,
    nearest_turn,
    velocity_scale,
    wrap_continuous,
)
from policy_align_ros.kinematics import Robot, TaskSpaceMap, constraint_from_spec
from policy_align_ros.sim.demonstrations import sample_start_states
from policy_align_ros.sim.experts import QuadraticPotential, TaskSpaceExpert

__all__ = ["DEFAULT_FRAMES", "EXPERTS", "DemonstrationScript", "drop_roundoff_at_limits",
           "hand_plane_rows", "hands_command", "make_hand_expert", "plane_segment",
           "random_plane_specs", "reachable_home", "stale_joint_state"]

DEFAULT_FRAMES = ["arm_left_7_link", "arm_right_7_link"]
EXPERTS = ("joints", "hands")
#: Outward joint speeds at a limit below this (rad/s) are round-off of a locked joint.
LIMIT_ROUNDOFF = 1e-9
#: How far inside its limits (rad) :func:`reachable_home` keeps every joint: twice the
#: executor's default braking margin, so that a goal there is one it can reach.
HOME_MARGIN = 2.0 * DEFAULT_JOINT_LIMIT_MARGIN


def reachable_home(robot: Robot, margin: float = HOME_MARGIN) -> np.ndarray:
    """The robot's reference posture (n,) moved ``margin`` (rad) inside its limits.

    A URDF's reference posture often puts joints at a limit (an arm folded against its
    stop, a gripper closed). The executor brakes joints to rest ``joint_limit_margin``
    inside their limits, so an expert whose minimum lies there demonstrates a goal no run
    can reach (:func:`~policy_align_ros.control.limits.inner_limits` shrinks the margin on
    narrow joints)."""
    lower, upper = inner_limits(robot.lower, robot.upper, margin)
    return np.clip(robot.neutral(), lower, upper)


def stale_joint_state(received: float | None, now: float, timeout: float) -> str:
    """Why the last joint state is too old to command from, or ``""`` when it is fresh.

    Parameters
    ----------
    received : float or None
        Arrival time of the last accepted joint state [s, node clock]; None: none yet.
    now : float
        Current time [s, node clock].
    timeout : float
        Largest age that counts as fresh [s].

    A clock that went back since the arrival (a restarted simulator's ``/clock``) makes
    the state stale too: its age is unknown.
    """
    if received is None:
        return "no joint state received"
    age = now - received
    if age < 0.0:
        return f"the clock went back {-age:.3f} s since the last joint state"
    if age > timeout:
        return f"last joint state received {age:.3f} s ago (> state_timeout_s)"
    return ""


def random_plane_specs(frames: Sequence[str], rng: np.random.Generator) -> list[dict]:
    """One plane constraint spec per frame, normals uniform on the unit sphere."""
    specs = []
    for frame in frames:
        normal = rng.standard_normal(3)
        normal /= np.linalg.norm(normal)
        specs.append({"type": "plane", "frame": frame, "normal": normal.tolist()})
    return specs


def drop_roundoff_at_limits(q: np.ndarray, qdot: np.ndarray, lower: np.ndarray,
                            upper: np.ndarray) -> np.ndarray:
    """``qdot`` (n,) with round-off pushes out of a limit set to zero.

    The hands expert locks joints at their limits as constraint rows, which leaves
    outward speeds of order 1e-17 rad/s on them; a whole-vector limit scale would read
    those as pushing out and stop the robot. Larger outward speeds are kept (and stop it).
    """
    out = np.array(qdot, dtype=float)
    outward = ((q <= lower) & (out < 0.0)) | ((q >= upper) & (out > 0.0))
    out[outward & (np.abs(out) < LIMIT_ROUNDOFF)] = 0.0
    return out


def hands_command(hand_expert: TaskSpaceExpert, q: np.ndarray, A_x: np.ndarray | None,
                  A_q: np.ndarray | None, lower: np.ndarray, upper: np.ndarray,
                  vmax: np.ndarray, dt: float) -> np.ndarray:
    """The hands expert's joint velocity (n,) at ``q`` (n,), scaled into the joint limits.

    Parameters
    ----------
    hand_expert : TaskSpaceExpert
    q : ndarray, shape (n,)
        Joint positions [rad].
    A_x : ndarray, shape (k, 3F), or None
        Hand-space constraint rows.
    A_q : ndarray, shape (c, n), or None
        Joint-space constraint rows.
    lower, upper, vmax : ndarray, shape (n,)
        Joint limits [rad] and speed limits [rad/s].
    dt : float
        Control period [s].

    Returns
    -------
    ndarray, shape (n,)
        Joint velocity [rad/s]. The scale applies to the whole vector, and only where no
        joint can make up for a bound, which keeps the hands on their planes.
    """
    qdot, _ = hand_expert.command(q, A_x, A_q, max_velocity=vmax, dt=dt)
    qdot = drop_roundoff_at_limits(q, qdot, lower, upper)
    return velocity_scale(q, qdot, dt, lower, upper, vmax) * qdot


def hand_plane_rows(specs: Sequence[dict], hand_frames: Sequence[str]
                    ) -> tuple[np.ndarray, list[dict]]:
    """Hand-space rows ``A_x`` (k, 3F) of the plane specs on frames of ``hand_frames``.

    A plane with unit normal ``n`` on frame ``F_j`` is the row with ``n`` in the columns
    ``3j:3j+3`` of the stacked hand state; specs on other frames are returned as they are
    (the caller applies them as joint-space rows).
    """
    index = {frame: j for j, frame in enumerate(hand_frames)}
    rows, other = [], []
    for spec in specs:
        j = index.get(spec.get("frame"))
        if spec.get("type") != "plane" or j is None:
            other.append(spec)
            continue
        row = np.zeros(3 * len(hand_frames))
        row[3 * j:3 * j + 3] = np.asarray(spec["normal"], dtype=float)
        rows.append(row)
    return np.array(rows).reshape(-1, 3 * len(hand_frames)), other


def make_hand_expert(robot: Robot, hand_frames: Sequence[str], targets, gain: float,
                     attractor: np.ndarray) -> TaskSpaceExpert:
    """The hands expert ``pi_x = -gain (x - targets)`` on the stacked ``hand_frames``.

    Parameters
    ----------
    robot : Robot
    hand_frames : sequence of str
        Frames whose stacked positions (3F,) are the expert's state.
    targets : array_like, shape (3F,), or None
        Target positions [m]; None: the hands' positions at ``attractor``.
    gain : float
        Expert gain [1/s].
    attractor : numpy.ndarray, shape (n,)
        Rest posture of the redundant joints [rad].
    """
    if not hand_frames:
        raise ValueError("hand_frames: the hands expert needs at least one frame")
    state_map = TaskSpaceMap(robot, list(hand_frames))
    if targets is None:
        targets = state_map.states(attractor)
    targets = np.asarray(targets, dtype=float)
    if targets.shape != (state_map.dim,) or not np.all(np.isfinite(targets)):
        raise ValueError(f"hand_targets: need {state_map.dim} finite values (3 per hand "
                         f"frame), got {targets.size}")
    # phi_x = gain/2 ||x - x_c||^2, so pi_x = -gain (x - x_c).
    return TaskSpaceExpert(state_map, targets, gain / 2.0, rest=attractor)


def plane_segment(elapsed: float, duration: float, switches: int) -> int:
    """Index of the plane draw in force ``elapsed`` s into a ``duration`` s demonstration
    whose planes are re-drawn ``switches`` times at regular intervals."""
    return int(elapsed / duration * (switches + 1))


class DemonstrationScript:
    """The expert of a demonstrator, one control period at a time.

    Parameters
    ----------
    robot : Robot
    attractor : array_like, shape (n,), or None
        Minimum of the expert potential [rad]; None: :func:`reachable_home`.
    gain : float
        Expert gain [1/s].
    mode : {"joints", "hands"}
        Potential in joint space or in the stacked positions of ``hand_frames``.
    constraint_frames : sequence of str
        Frames each restricted to a random plane (empty: unconstrained).
    hand_frames : sequence of str
        The hands expert's frames.
    hand_targets : array_like, shape (3F,), or None
        The hands expert's targets [m]; None: the hands at the attractor.
    max_velocity : numpy.ndarray, shape (n,)
        Joint speed limits [rad/s].
    period : float
        Control period [s].
    rng : numpy.random.Generator
        Draws the starts and the planes.
    """

    def __init__(self, robot: Robot, attractor, gain: float, mode: str,
                 constraint_frames: Sequence[str], hand_frames: Sequence[str], hand_targets,
                 max_velocity: np.ndarray, period: float, rng: np.random.Generator) -> None:
        self.robot = robot
        self.attractor = reachable_home(robot) if attractor is None else np.asarray(attractor)
        if self.attractor.shape != (robot.nq,):
            raise ValueError(f"attractor: need {robot.nq} values, got {self.attractor.size}")
        self.expert = QuadraticPotential(self.attractor, weight=gain / 2.0)
        self.frames = [f for f in constraint_frames if f]
        for frame in self.frames:
            robot.frame_id(frame)  # fail at start on a wrong frame name
        if mode not in EXPERTS:
            raise ValueError(f"expert: must be one of {', '.join(EXPERTS)}, got {mode!r}")
        self.mode = mode
        self.hand_frames = [f for f in hand_frames if f]
        self.hand_expert: TaskSpaceExpert | None = None
        if mode == "hands":
            self.hand_expert = make_hand_expert(robot, self.hand_frames, hand_targets, gain,
                                                self.attractor)
        self.vmax = max_velocity
        self.period = period
        self.rng = rng
        self.A_x = np.zeros((0, 0))
        self.constraints: list = []

    def new_start(self, variance: float) -> np.ndarray:
        """A random start ``q0 ~ N(attractor, variance I)`` (n,) in the joint limits."""
        return sample_start_states(self.rng, self.attractor, 1, variance, self.robot.lower,
                                   self.robot.upper)[0]

    def draw_planes(self) -> None:
        """Restrict every constraint frame to a new plane of random orientation."""
        specs = random_plane_specs(self.frames, self.rng)
        if self.hand_expert is not None:
            # Planes on hands are rows of the hand-space constraint A_x (so the hands move
            # with N_x pi_x); planes on other frames stay joint-space rows.
            self.A_x, specs = hand_plane_rows(specs, self.hand_frames)
        self.constraints = [constraint_from_spec(s, self.robot) for s in specs]

    def nearest_turn(self, q: np.ndarray) -> np.ndarray:
        """``q`` (n,) with each continuous joint moved by whole turns to within half a turn
        of the attractor, where the joint-space expert is evaluated; other joints as given.
        """
        return nearest_turn(q, np.where(self.robot.continuous, self.attractor, np.nan))

    def start_distance(self, q: np.ndarray, q0: np.ndarray) -> float:
        """The largest joint distance ``max |q - q0|`` (rad or m) of ``q`` (n,) from the
        start ``q0`` (n,), continuous joints the short way (a driver wraps them)."""
        return float(np.max(np.abs(wrap_continuous(q - q0, self.robot.continuous))))

    def reach_command(self, q: np.ndarray, q0: np.ndarray, gain: float) -> np.ndarray:
        """Unconstrained ``-gain (q - q0)`` within the limits (n,), rad/s; the shortest
        angle for continuous joints."""
        pi = -gain * wrap_continuous(q - q0, self.robot.continuous)
        return constrained_command(q, pi, np.zeros((0, q.size)), self.robot.lower,
                                   self.robot.upper, self.vmax, self.period)

    def command(self, q: np.ndarray) -> np.ndarray:
        """The expert's joint velocity (n,) at ``q`` under the current planes, rad/s."""
        lower, upper = self.robot.lower, self.robot.upper
        if self.hand_expert is None:
            # The potential's minimum is one angle of a continuous joint: the expert pulls
            # towards its nearest turn, the short way round.
            pi = self.expert.policy(self.nearest_turn(q)[None, :])[0]
            A = (np.vstack([c.matrix(q, pi) for c in self.constraints])
                 if self.constraints else np.zeros((0, q.size)))
            return constrained_command(q, pi, A, lower, upper, self.vmax, self.period)
        A_q = (np.vstack([c.matrix(q) for c in self.constraints]) if self.constraints
               else None)
        return hands_command(self.hand_expert, q, self.A_x, A_q, lower, upper, self.vmax,
                             self.period)
