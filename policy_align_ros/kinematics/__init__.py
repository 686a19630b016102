"""Robot kinematics (Pinocchio), constraint models ``A(q)`` and projections ``N(q)``.

Units: joint positions in rad (revolute) or m (prismatic), frame positions in m in the
world frame, Jacobians LOCAL_WORLD_ALIGNED. See :mod:`.robot` (the one frame-kinematics
path), :mod:`.constraints` and :mod:`.projection`; task-space states (stacked frame
positions) in :mod:`.task_space` and their definition in :mod:`.state_definition`.
"""

from policy_align_ros.kinematics.constraints import (
    BarrierConstraint,
    Constraint,
    ConstraintModel,
    JointLockConstraint,
    PlaneConstraint,
    PositionConstraint,
    StackedConstraint,
    constraint_from_spec,
)
from policy_align_ros.kinematics.projection import nullspace_projector, nullspace_projectors
from policy_align_ros.kinematics.robot import ROBOTS, Robot
from policy_align_ros.kinematics.robot_config import (
    RobotConfig,
    RobotSetup,
    load_robot_config,
    resolve_robot_setup,
)
from policy_align_ros.kinematics.state_definition import FrameStateDefinition
from policy_align_ros.kinematics.task_space import LearningStateMap, TaskSpaceMap
from policy_align_ros.learning.state_spec import parse_state_spec

__all__ = [
    "ROBOTS",
    "BarrierConstraint",
    "Constraint",
    "ConstraintModel",
    "FrameStateDefinition",
    "JointLockConstraint",
    "LearningStateMap",
    "PlaneConstraint",
    "PositionConstraint",
    "Robot",
    "RobotConfig",
    "RobotSetup",
    "StackedConstraint",
    "TaskSpaceMap",
    "constraint_from_spec",
    "load_robot_config",
    "nullspace_projector",
    "nullspace_projectors",
    "resolve_robot_setup",
    "parse_state_spec",
]
