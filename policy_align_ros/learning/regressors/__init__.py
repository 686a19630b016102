"""Global models of the potential, one module per family, and their registry.

Every regressor follows the protocol of DESIGN.md section 3: ``fit(X, y, groups)``
returning itself, ``predict(X)`` (m,), ``gradient(X)`` (m, n), ``get_state()`` ->
``(arrays, meta)`` and the classmethod ``from_state(arrays, meta)``. A model file names
its regressor's class; :func:`regressor_class` finds it here, so a PolicyAlign fitted with
any registered regressor saves and loads.

- :class:`TrendKernelRegression` (default): a quadratic trend shrunk toward an isotropic
  bowl plus a Gaussian-kernel residual, hyperparameters chosen by CV over whole
  held-out demonstrations, the single-index trend (:mod:`.single_index`) among the
  families it chooses from.
- :class:`LocalLinearRegression`: receptive fields with local linear models (the LWPR
  family the paper uses); purely local.

A regressor may also take ``fit(..., free_groups=ids)``: demonstrations whose offsets it
re-fits freely (:func:`takes_free_groups`); PolicyAlign then gives it the trajectories the
alignment could not level.
"""

from __future__ import annotations

import inspect

from policy_align_ros.learning.baselines.local_linear import LocalLinearRegression
from policy_align_ros.learning.fitting import NotFittedError
from policy_align_ros.learning.regressors.trend_kernel import TrendKernelRegression

__all__ = [
    "REGISTRY",
    "LocalLinearRegression",
    "NotFittedError",
    "TrendKernelRegression",
    "register",
    "regressor_class",
    "takes_free_groups",
]

REGISTRY: dict[str, type] = {}


def register(cls: type) -> type:
    """Register a regressor class under its name (usable as a decorator)."""
    for method in ("fit", "predict", "gradient", "get_state", "from_state"):
        if not callable(getattr(cls, method, None)):
            raise ValueError(f"register: {cls.__name__} has no method {method!r}")
    REGISTRY[cls.__name__] = cls
    return cls


def regressor_class(name: str) -> type:
    """The registered regressor class called ``name`` (ValueError listing the known ones)."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ValueError(
            f"unknown regressor {name!r}; registered: {sorted(REGISTRY)}"
        ) from None


def takes_free_groups(regressor) -> bool:
    """Whether ``regressor.fit`` accepts ``free_groups`` (offsets it re-fits freely)."""
    try:
        return "free_groups" in inspect.signature(regressor.fit).parameters
    except (TypeError, ValueError):
        return False


register(TrendKernelRegression)
register(LocalLinearRegression)
