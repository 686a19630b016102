"""Baselines PolicyAlign is compared with: the paper's naive policy and its regressor.

- :class:`LocalLinearRegression` (:mod:`.local_linear`): receptive fields with local linear
  models, the LWPR family the paper uses (still a registered regressor of PolicyAlign);
- :class:`NaivePolicy` (:mod:`.naive`): the observed velocities regressed directly on the
  states (paper section IV-C).

Nothing here imports :mod:`policy_align_ros.learning.regressors` at import time, which
imports :class:`LocalLinearRegression` from here to register it.
"""

from policy_align_ros.learning.baselines.local_linear import LocalLinearRegression
from policy_align_ros.learning.baselines.naive import NaivePolicy, velocity_samples

__all__ = ["LocalLinearRegression", "NaivePolicy", "velocity_samples"]
