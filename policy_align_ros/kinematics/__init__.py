"""Robot kinematics (Pinocchio), constraint models ``A(q)`` and projections ``N(q)``.

Units: joint positions in rad (revolute) or m (prismatic), frame positions in m in the
world frame, Jacobians LOCAL_WORLD_ALIGNED. See :mod:`.robot`, :mod:`.constraints` and
:mod:`.projection`.
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

__all__ = [
    "ROBOTS",
    "BarrierConstraint",
    "Constraint",
    "JointLockConstraint",
    "PlaneConstraint",
    "PositionConstraint",
    "Robot",
    "StackedConstraint",
    "constraint_from_spec",
    "nullspace_projector",
    "nullspace_projectors",
]
