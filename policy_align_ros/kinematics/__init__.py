"""Robot kinematics (Pinocchio), constraint models ``A(q)`` and projections ``N(q)``.

Units: joint positions in rad (revolute) or m (prismatic), frame positions in m in the
world frame, Jacobians LOCAL_WORLD_ALIGNED. See :mod:`.robot`, :mod:`.constraints` and
:mod:`.projection`;
task-space states (stacked frame positions) and their map back to joint velocities in
:mod:`.task_space`.
"""

from policy_align_ros.kinematics.constraints import (
    BarrierConstraint,
    Constraint,
    JointLockConstraint,
    PlaneConstraint,
    PositionConstraint,
    StackedConstraint,
    constraint_from_spec,
)
from policy_align_ros.kinematics.projection import nullspace_projector, nullspace_projectors
from policy_align_ros.kinematics.robot import ROBOTS, Robot
from policy_align_ros.kinematics.task_space import (
    FrameStateDefinition,
    TaskSpaceMap,
    TaskSpacePolicy,
    parse_state_spec,
)

__all__ = [
    "ROBOTS",
    "BarrierConstraint",
    "Constraint",
    "FrameStateDefinition",
    "JointLockConstraint",
    "PlaneConstraint",
    "PositionConstraint",
    "Robot",
    "StackedConstraint",
    "TaskSpaceMap",
    "TaskSpacePolicy",
    "constraint_from_spec",
    "nullspace_projector",
    "nullspace_projectors",
    "parse_state_spec",
]
