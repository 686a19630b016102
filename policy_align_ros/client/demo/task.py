"""The demo's learning state and expert without ROS, and the runs' new start states.

Notation: ``q`` joint positions (rad), ``x`` the learning state: ``x = q`` for
``--state joints``, or the stacked positions (m) of both hands for ``--state hands``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from policy_align_ros.client.demo.settings import MIN_START_SEPARATION, DemoSettings, StageError
from policy_align_ros.control import ControlStep, speed_limits
from policy_align_ros.kinematics import Robot, TaskSpaceMap, constraint_from_spec
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.metrics import ncpe
from policy_align_ros.sim.demonstrations import rollout, sample_start_states, task_space_rollout
from policy_align_ros.sim.experts import QuadraticPotential, TaskSpaceExpert
from policy_align_ros.sim.script import (
    hand_plane_rows,
    hands_command,
    random_plane_specs,
    reachable_home,
)

__all__ = ["Task", "new_starts"]


class Task:
    """The demo's state space, its goal and its expert, without ROS.

    Parameters
    ----------
    robot : Robot
    s : DemoSettings
    """

    def __init__(self, robot: Robot, s: DemoSettings) -> None:
        self.robot = robot
        self.s = s
        self.dt = 1.0 / s.rate_hz
        self.attractor = (np.asarray(s.home, dtype=float) if len(s.home)
                          else reachable_home(robot))
        self.vmax = speed_limits(robot.velocity_limit, s.max_velocity)
        self.hands = TaskSpaceMap(robot, s.frames) if s.frames else None
        self.joint_expert = QuadraticPotential(self.attractor, weight=s.gain / 2.0)
        self.hand_expert: TaskSpaceExpert | None = None
        if s.state == "hands":
            targets = self.hands.states(self.attractor) + np.asarray(s.hand_offset, float)
            self.hand_expert = TaskSpaceExpert(self.hands, targets, s.gain / 2.0,
                                               rest=self.attractor)
            self.goal = targets
        else:
            self.goal = self.attractor

    @property
    def state_spec(self) -> str:
        """What the learner's ``state`` parameter says."""
        return "joints" if self.s.state == "joints" else "frames:" + ",".join(self.s.frames)

    def states(self, Q: np.ndarray) -> np.ndarray:
        """Learning states (m, d) of joint rows ``Q`` (m, n)."""
        Q = np.atleast_2d(Q)
        return Q.copy() if self.hand_expert is None else self.hands.states(Q)

    def distances(self, Q: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """``||x(q) - goal||`` (m,) in state units for joint rows ``Q`` (m, n)."""
        return np.linalg.norm(self.states(Q) - goal, axis=1)

    def frame_distances(self, q: np.ndarray, goal: np.ndarray) -> dict[str, float] | None:
        """Per-hand distance (m) of the hands at ``q`` (n,) to ``goal`` (hands only)."""
        if self.hand_expert is None:
            return None
        diff = (self.states(q)[0] - goal).reshape(-1, 3)
        return {f: float(d) for f, d in zip(self.s.frames, np.linalg.norm(diff, axis=1),
                                            strict=True)}

    def expert_run(self, q0: np.ndarray, specs: list[dict], duration_s: float
                   ) -> np.ndarray:
        """The expert from ``q0`` under joint-space constraint ``specs``, as executed.

        Joint space: the executor's own control step (:class:`ControlStep`) with the true
        policy. Hand space: the task-space expert's joint velocity, scaled into the limits.

        Returns
        -------
        ndarray, shape (T + 1, n)
            Joint positions every control period (rad), ``T = duration_s * rate_hz``.
        """
        robot = self.robot
        constraints = [constraint_from_spec(spec, robot) for spec in specs]
        steps = int(round(duration_s / self.dt))
        q = robot.clip(np.asarray(q0, dtype=float).copy())
        out = [q.copy()]
        if self.hand_expert is None:
            step = ControlStep(robot.lower, robot.upper, self.vmax, self.dt, constraints,
                               policy=self.joint_expert.policy)
            for _ in range(steps):
                q = robot.clip(q + self.dt * step(q)[0])
                out.append(q.copy())
            return np.array(out)
        for _ in range(steps):
            A_q = np.vstack([c.matrix(q) for c in constraints]) if constraints else None
            qdot = hands_command(self.hand_expert, q, None, A_q, robot.lower, robot.upper,
                                 self.vmax, self.dt)
            q = robot.clip(q + self.dt * qdot)
            out.append(q.copy())
        return np.array(out)

    def fresh_ncpe(self, model: PolicyAlign, rng: np.random.Generator) -> float:
        """The paper's nCPE of ``model`` on new demonstrations with known projectors."""
        s, robot = self.s, self.robot
        starts = sample_start_states(rng, self.attractor, s.fresh_demos, s.start_variance,
                                     robot.lower, robot.upper)
        n_samples = int(round(s.demo_duration_s * s.rate_hz))
        X, P, Ns = [], [], []
        for x0 in starts:
            planes = [random_plane_specs(s.frames, rng) for _ in range(3)]
            if self.hand_expert is None:
                segments = [[constraint_from_spec(p, robot) for p in specs]
                            for specs in planes]
                demo = rollout(x0, self.joint_expert, _switching(segments, s.demo_duration_s),
                               n_samples, self.dt)
            else:
                rows = [hand_plane_rows(specs, s.frames)[0] for specs in planes]
                # The projectors and pi_x are exact whether or not a step is blocked
                # at a joint limit, which is all the nCPE uses.
                demo = task_space_rollout(x0, self.hand_expert,
                                          _switching_rows(rows, s.demo_duration_s),
                                          n_samples, self.dt)
            X.append(demo.trajectory.positions)
            P.append(demo.policy)
            Ns.append(demo.projectors)
        X = np.concatenate(X)
        return float(ncpe(np.concatenate(P), model.policy(X), np.concatenate(Ns)))


def _switching(segments: list[list], duration_s: float) -> Callable:
    """Constraint generator with the planes of ``segments`` in equal thirds of the demo."""
    parts = len(segments)

    def gen(x: np.ndarray, t: float, pi: np.ndarray) -> np.ndarray:
        seg = segments[min(int(t / duration_s * parts), parts - 1)]
        if not seg:
            return np.zeros((0, x.size))
        return np.vstack([c.matrix(x, pi) for c in seg])
    return gen


def _switching_rows(rows: list[np.ndarray], duration_s: float) -> Callable:
    """Hand-space generator returning ``rows[k]`` in the k-th equal part of the demo."""
    def gen(x: np.ndarray, t: float, pi: np.ndarray) -> np.ndarray:
        return rows[min(int(t / duration_s * len(rows)), len(rows) - 1)]
    return gen


def new_starts(task: Task, rng: np.random.Generator, count: int,
               recorded: np.ndarray) -> np.ndarray:
    """``count`` start postures (count, n) from the demonstrations' start distribution.

    Draws are rejected while closer than :data:`MIN_START_SEPARATION` (rad) to a recorded
    demonstration's first posture ``recorded`` (K, n), so none began a demonstration.
    """
    s, robot = task.s, task.robot
    out: list[np.ndarray] = []
    for _ in range(100 * count):
        if len(out) == count:
            break
        q = sample_start_states(rng, task.attractor, 1, s.start_variance, robot.lower,
                                robot.upper)[0]
        if recorded.size == 0 or np.min(np.linalg.norm(recorded - q, axis=1)) \
                >= MIN_START_SEPARATION:
            out.append(q)
    if len(out) < count:
        raise StageError("could not draw new start states away from the recorded ones")
    return np.array(out)

