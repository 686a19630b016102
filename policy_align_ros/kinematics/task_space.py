"""Task-space state: stacked frame positions and their Jacobian, for one robot.

Notation and units:

- ``q`` (n,) joint positions of the robot's selected joints (rad or m), in the order of
  :attr:`Robot.joint_names`; ``Q`` (m, n) a joint trajectory;
- ``x`` (3F,) the task-space state: the positions (m) of ``F`` frames, stacked
  ``[p_1; ...; p_F]``, each expressed in the root frame (``universe``, the world, by
  default); ``X`` (m, 3F);
- ``J(q)`` (3F, n) the stacked translational Jacobian ``dx/dq`` (m/rad), taken with
  ``pin.LOCAL_WORLD_ALIGNED`` (origin at each frame, axes of the world) by
  :meth:`Robot.frames_kinematics` and rotated into the root frame.

The state definition (:mod:`.state_definition`) says which robot, joints and frames a
state is made of; the map back to joint velocities is
:mod:`policy_align_ros.control.task_policy`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from policy_align_ros.kinematics.robot import Robot
from policy_align_ros.kinematics.state_definition import WORLD, FrameStateDefinition
from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["LearningStateMap", "TaskSpaceMap"]


class TaskSpaceMap:
    """Joint positions -> stacked frame positions, and their Jacobian, for one robot.

    Frame kinematics are the robot's (:meth:`Robot.frames_kinematics`, one model and
    data); this adds the root frame's axes and origin.

    Parameters
    ----------
    robot : Robot
    frames : sequence of str
        ``F`` frames.
    root_frame : str
        Frame (fixed to the world) the positions are expressed in.

    Attributes
    ----------
    definition : FrameStateDefinition
    """

    def __init__(self, robot: Robot, frames: Sequence[str], root_frame: str = WORLD
                 ) -> None:
        self.definition = FrameStateDefinition.from_robot(robot, frames, root_frame)
        self.robot = robot
        self.frames = list(self.definition.frames)
        root = robot.fixed_frame_placement(root_frame)
        self._rot = np.array(root.rotation).T  # world -> root axes
        self._origin = np.array(root.translation)

    @property
    def n(self) -> int:
        """Joint dimension."""
        return self.robot.nq

    @property
    def dim(self) -> int:
        """Task-space dimension ``3F``."""
        return 3 * len(self.frames)

    def _checked(self, q: np.ndarray) -> np.ndarray:
        vec = np.asarray(q, dtype=float)
        if vec.shape != (self.n,):
            raise ValueError(f"q: must have shape ({self.n},), got {vec.shape}")
        if not np.all(np.isfinite(vec)):
            raise ValueError("q: contains NaN or inf")
        return vec

    def states(self, Q: np.ndarray) -> np.ndarray:
        """Task-space states of a joint trajectory.

        Parameters
        ----------
        Q : array_like, shape (m, n) or (n,)
            Joint positions (rad or m).

        Returns
        -------
        numpy.ndarray, shape (m, 3F) (or (3F,) for one configuration)
            Stacked frame positions in m, in the root frame.

        Raises
        ------
        ValueError
            If ``Q`` has the wrong shape or is not finite (naming the row).
        """
        arr = np.asarray(Q, dtype=float)
        single = arr.ndim == 1
        rows = arr[None] if single else arr
        if rows.ndim != 2 or rows.shape[1] != self.n:
            raise ValueError(f"Q: must have shape (m, {self.n}), got {arr.shape}")
        out = np.empty((rows.shape[0], len(self.frames), 3))
        for i, q in enumerate(rows):
            if not np.all(np.isfinite(q)):
                raise ValueError(f"Q: row {i} contains NaN or inf")
            out[i] = self.robot.frame_positions(q, self.frames)
        out = (out - self._origin) @ self._rot.T
        flat = out.reshape(rows.shape[0], -1)
        return flat[0] if single else flat

    __call__ = states

    def kinematics(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State ``x`` (3F,) in m and Jacobian ``J`` (3F, n) in m/rad at ``q`` (n,)."""
        pos, jac = self.robot.frames_kinematics(self._checked(q), self.frames)
        x = (pos - self._origin) @ self._rot.T
        J = np.empty_like(jac)
        for f, block in enumerate(jac):
            J[f] = self._rot @ block
        return x.reshape(-1), J.reshape(-1, self.n)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """Stacked translational Jacobian ``J`` (3F, n) at ``q`` (n,), m/rad."""
        return self.kinematics(q)[1]


class LearningStateMap:
    """Joint trajectories -> frame-state trajectories, for a learning pipeline.

    A callable: a joint trajectory (a :class:`Trajectory` or an (m, n) array, joints in
    ``robot.joint_names`` order) in, the same in task space out (positions (m, 3F) in m;
    joint velocities, when given, mapped through ``J(q)``). :meth:`definition` gives the
    JSON-able state definition for the model header, with ``rest``: the mean final posture
    (joint -> rad) of the trajectories mapped so far, the executor's default rest posture
    for the redundant joints.

    Parameters
    ----------
    robot : Robot
    frames : sequence of str
    root_frame : str
    """

    def __init__(self, robot: Robot, frames: Sequence[str], root_frame: str = WORLD
                 ) -> None:
        self.map = TaskSpaceMap(robot, frames, root_frame)
        self._finals: list[np.ndarray] = []

    @property
    def joint_names(self) -> list[str]:
        """Joint order the map expects."""
        return list(self.map.robot.joint_names)

    def __call__(self, traj: Trajectory | np.ndarray) -> Trajectory | np.ndarray:
        """Map one joint trajectory; see the class docstring. Raises ValueError."""
        if not isinstance(traj, Trajectory):
            X = self.map.states(traj)
            self._finals.append(np.asarray(traj, dtype=float).reshape(-1, self.map.n)[-1])
            return X
        Q = traj.positions
        if Q.shape[1] != self.map.n:
            raise ValueError(f"trajectory {traj.name}: has {Q.shape[1]} joints, the state "
                             f"map expects {self.map.n} ({', '.join(self.joint_names)})")
        X = self.map.states(Q)
        V = None
        if traj.velocities is not None:
            V = np.array([self.map.jacobian(q) @ v for q, v in zip(Q, traj.velocities,
                                                                  strict=True)])
        self._finals.append(Q[-1].copy())
        return Trajectory(X, traj.times, V, name=traj.name)

    def definition(self) -> dict[str, Any]:
        """JSON-able state definition (``{"type": "frames", ..., "rest": {...}}``)."""
        out = self.map.definition.to_dict()
        if self._finals:
            mean = np.mean(self._finals, axis=0)
            out["rest"] = {j: float(v) for j, v in zip(self.joint_names, mean, strict=True)}
        return out
