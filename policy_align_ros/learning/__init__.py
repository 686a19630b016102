"""ROS-free learning core of policy_align_ros (PolicyAlign, paper Algorithm 1).

Public API (``docs/design.md`` section 3)::

    from policy_align_ros.learning import PolicyAlign, Trajectory
    model = PolicyAlign(sigma="medium").fit([Trajectory(Q, times=t), ...])
    model.potential(X); model.policy(X); model.save(path); PolicyAlign.load(path)
"""

from policy_align_ros.learning import metrics
from policy_align_ros.learning.base import NotFittedError
from policy_align_ros.learning.baselines import NaivePolicy
from policy_align_ros.learning.policy_align import PolicyAlign
from policy_align_ros.learning.regressors import LocalLinearRegression
from policy_align_ros.learning.trajectory import Trajectory, as_trajectories

__all__ = [
    "LocalLinearRegression",
    "NaivePolicy",
    "NotFittedError",
    "PolicyAlign",
    "Trajectory",
    "as_trajectories",
    "metrics",
]
