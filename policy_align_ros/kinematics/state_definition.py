"""Task-space state definition: which robot, joints and frames a frame state is made of.

A model file records it so that a model learnt in task space is only used on the robot
whose kinematics produced its data.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from policy_align_ros.kinematics.robot import Robot, closest_names

__all__ = ["WORLD", "FrameStateDefinition"]

#: Default root frame: Pinocchio's world frame of a fixed-base model.
WORLD = "universe"


@dataclass(frozen=True)
class FrameStateDefinition:
    """What a task-space state is: which robot, joints and frames, and how it was built.

    Attributes
    ----------
    robot : str
        example-robot-data name or URDF path, as given to :meth:`Robot.load`.
    joints : tuple of str
        The ``n`` joints of the joint states, in state-map order.
    frames : tuple of str
        The ``F`` frames whose positions are stacked; the state has ``3F`` coordinates.
    root_frame : str
        Frame the positions are expressed in; must be fixed to the world.
    locked_posture : dict str -> list of float
        Configuration of every joint outside ``joints`` (rad or m).
    urdf_sha256 : str
        Hex SHA-256 of the URDF file.
    """

    robot: str
    joints: tuple[str, ...]
    frames: tuple[str, ...]
    root_frame: str
    locked_posture: dict[str, list[float]] = field(hash=False)
    urdf_sha256: str

    #: Tolerance (rad or m) when comparing locked postures.
    POSTURE_TOL = 1e-9

    @property
    def dim(self) -> int:
        """Task-space dimension ``3F``."""
        return 3 * len(self.frames)

    @classmethod
    def from_robot(cls, robot: Robot, frames: Sequence[str], root_frame: str = WORLD
                   ) -> FrameStateDefinition:
        """Definition of the stacked positions of ``frames`` of ``robot``.

        Raises
        ------
        ValueError
            For an unknown, repeated or empty frame list, or a root frame that moves
            with the robot's joints.
        """
        frames = _frame_list(frames)
        for f in frames:
            robot.frame_id(f)
        _check_root(robot, root_frame)
        return cls(robot=str(robot.name), joints=tuple(robot.joint_names),
                   frames=tuple(frames), root_frame=str(root_frame),
                   locked_posture={k: list(v) for k, v in robot.locked_posture.items()},
                   urdf_sha256=robot.urdf_sha256())

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict for a model header (``{"type": "frames", ...}``)."""
        return {"type": "frames", "robot": self.robot, "joints": list(self.joints),
                "frames": list(self.frames), "root_frame": self.root_frame,
                "locked_posture": {k: list(v) for k, v in self.locked_posture.items()},
                "urdf_sha256": self.urdf_sha256}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FrameStateDefinition:
        """Inverse of :meth:`to_dict`; raises ValueError naming a missing or bad field."""
        if not isinstance(data, Mapping):
            raise ValueError(f"state definition: expected a dict, got {type(data).__name__}")
        if data.get("type") != "frames":
            raise ValueError(f"state definition: field 'type' must be 'frames', got "
                             f"{data.get('type')!r}")
        for key in ("robot", "joints", "frames", "root_frame", "locked_posture",
                    "urdf_sha256"):
            if key not in data:
                raise ValueError(f"state definition: field {key!r} is missing")
        for key in ("robot", "root_frame", "urdf_sha256"):
            if not isinstance(data[key], str) or not data[key]:
                raise ValueError(f"state definition: field {key!r} must be a non-empty "
                                 f"string, got {data[key]!r}")
        for key in ("joints", "frames"):
            val = data[key]
            if (isinstance(val, str) or not isinstance(val, Sequence) or not val
                    or not all(isinstance(v, str) for v in val)):
                raise ValueError(f"state definition: field {key!r} must be a non-empty "
                                 f"list of names, got {val!r}")
        posture = data["locked_posture"]
        if not isinstance(posture, Mapping):
            raise ValueError("state definition: field 'locked_posture' must be a dict")
        clean: dict[str, list[float]] = {}
        for joint, values in posture.items():
            try:
                vec = [float(v) for v in values]
            except (TypeError, ValueError):
                raise ValueError(f"state definition: locked_posture[{joint!r}] must be a "
                                 f"list of numbers, got {values!r}") from None
            if not all(math.isfinite(v) for v in vec):
                raise ValueError(f"state definition: locked_posture[{joint!r}] is not "
                                 "finite")
            clean[str(joint)] = vec
        return cls(robot=data["robot"], joints=tuple(data["joints"]),
                   frames=tuple(_frame_list(data["frames"])), root_frame=data["root_frame"],
                   locked_posture=clean, urdf_sha256=data["urdf_sha256"])

    def check(self, robot: Robot, *, same_order: bool = True) -> None:
        """Raise ValueError naming what differs between this definition and ``robot``.

        Compared: the URDF's hash, the joints (and their order unless ``same_order`` is
        False: frame positions do not depend on it), the frames and root frame (they must
        exist) and the posture of the locked joints. A robot loaded by name and one
        loaded from the same URDF file match.
        """
        problems = []
        sha = robot.urdf_sha256()
        if sha != self.urdf_sha256:
            problems.append(f"URDF differs (model: robot {self.robot!r} sha256 "
                            f"{self.urdf_sha256[:12]}..., here: robot {robot.name!r} sha256 "
                            f"{sha[:12]}...)")
        if (list(robot.joint_names) != list(self.joints) if same_order
                else sorted(robot.joint_names) != sorted(self.joints)):
            missing = [j for j in self.joints if j not in robot.joint_names]
            extra = [j for j in robot.joint_names if j not in self.joints]
            what = (f"missing {missing}, extra {extra}" if missing or extra
                    else "same joints in another order")
            problems.append(f"joints differ ({what})")
        for f in (*self.frames, self.root_frame):
            if f not in robot.frame_names:
                problems.append(f"frame {f!r} does not exist on robot {robot.name!r}")
        mine, theirs = self.locked_posture, robot.locked_posture
        if set(mine) != set(theirs):
            problems.append(
                f"locked joints differ (model only: {sorted(set(mine) - set(theirs))}, "
                f"robot only: {sorted(set(theirs) - set(mine))})")
        else:
            moved = [j for j in mine
                     if len(mine[j]) != len(theirs[j])
                     or not np.allclose(mine[j], theirs[j], atol=self.POSTURE_TOL, rtol=0)]
            if moved:
                problems.append(f"locked posture differs at {moved[:5]}"
                                + (f" and {len(moved) - 5} more" if len(moved) > 5 else ""))
        if not problems:
            try:
                _check_root(robot, self.root_frame)
            except ValueError as err:
                problems.append(str(err))
        if problems:
            raise ValueError("state definition does not match the robot: "
                             + "; ".join(problems))

    def load_robot(self) -> Robot:
        """Load the robot this definition describes and :meth:`check` it.

        Raises
        ------
        ValueError
            If the robot cannot be loaded or no longer matches (for example its URDF
            file changed).
        """
        reference = {j: v[0] for j, v in self.locked_posture.items() if len(v) == 1}
        robot = Robot.load(self.robot, list(self.joints), reference=reference)
        self.check(robot)
        return robot


def _frame_list(frames: Sequence[str]) -> list[str]:
    if isinstance(frames, (str, bytes)) or not isinstance(frames, Sequence) or not frames:
        raise ValueError(f"frames: must be a non-empty list of frame names, got {frames!r}")
    out = [str(f) for f in frames]
    if len(set(out)) != len(out):
        raise ValueError(f"frames: a frame is listed twice in {out}")
    return out


def _check_root(robot: Robot, root_frame: str) -> None:
    if root_frame not in robot.frame_names:
        raise ValueError(f"root_frame: unknown frame {root_frame!r}; closest valid names: "
                         f"{closest_names(str(root_frame), robot.frame_names)}")
    fid = robot.frame_id(root_frame)
    # Positions in a moving root would need the root's Jacobian too; a frame attached to
    # the universe joint (0) of the reduced model does not move with any selected joint.
    if robot.model.frames[fid].parentJoint != 0:
        raise ValueError(f"root_frame: {root_frame!r} moves with the selected joints; "
                         "choose a frame fixed to the world (for example 'universe')")
