"""Global models of the potential, one module per family, and their registry.

Every regressor follows :class:`~.protocol.Regressor` (``docs/design.md`` section 3):
``fit(X, y, groups)`` returning itself, ``predict(X)`` (m,), ``gradient(X)`` (m, n),
``get_state()`` -> ``(arrays, meta)`` and the classmethod ``from_state(arrays, meta)``. A
model file names its regressor's class; :func:`~.registry.regressor_class` finds it, so a
PolicyAlign fitted with any registered regressor saves and loads.

- :class:`TrendKernelRegression` (default): a quadratic trend shrunk toward an isotropic
  bowl plus a Gaussian-kernel residual, hyperparameters chosen by CV over whole
  held-out demonstrations, the single-index trend (:mod:`.trend_kernel.single_index`)
  among the families it chooses from.
- :class:`LocalLinearRegression`: receptive fields with local linear models (the LWPR
  family the paper uses); purely local.

A regressor may also take ``fit(..., free_groups=ids)``: demonstrations whose offsets it
re-fits freely (:func:`~.registry.takes_free_groups`); PolicyAlign then gives it the
trajectories the alignment could not level.
"""

from policy_align_ros.learning.base import NotFittedError
from policy_align_ros.learning.baselines.local_linear import LocalLinearRegression
from policy_align_ros.learning.regressors.protocol import Regressor
from policy_align_ros.learning.regressors.registry import (
    REGISTRY,
    register,
    regressor_class,
    takes_drops,
    takes_final,
    takes_free_groups,
    takes_goal,
    takes_min_curvature,
    takes_motion,
    takes_scored,
)
from policy_align_ros.learning.regressors.trend_kernel import TrendKernelRegression

__all__ = [
    "REGISTRY",
    "LocalLinearRegression",
    "NotFittedError",
    "Regressor",
    "TrendKernelRegression",
    "register",
    "regressor_class",
    "takes_drops",
    "takes_free_groups",
    "takes_goal",
    "takes_min_curvature",
    "takes_motion",
    "takes_final",
    "takes_scored",
]

# The baseline lives outside this package (it imports nothing from it), so it is
# registered here rather than by a decorator: old model files name it.
register(LocalLinearRegression)
