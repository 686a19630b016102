"""The regressors a model file may name, by class name.

A model file names its regressor's class; :func:`regressor_class` finds it here, so a
PolicyAlign fitted with any registered regressor saves and loads, wherever the class is
defined.
"""

from __future__ import annotations

import inspect

__all__ = ["REGISTRY", "register", "regressor_class", "takes_free_groups", "takes_goal",
           "takes_drops", "takes_final", "takes_min_curvature", "takes_motion",
           "takes_scored"]

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
    return _takes(regressor, "free_groups")


def takes_goal(regressor) -> bool:
    """Whether ``regressor.fit`` accepts ``goal`` (a point where the model is stationary)."""
    return _takes(regressor, "goal")


def takes_motion(regressor) -> bool:
    """Whether ``regressor.fit`` accepts ``motion`` (each sample's step, state units)."""
    return _takes(regressor, "motion")


def takes_drops(regressor) -> bool:
    """Whether ``regressor.fit`` accepts ``drops`` (each sample's potential change over
    its ``motion`` step)."""
    return _takes(regressor, "drops")


def takes_min_curvature(regressor) -> bool:
    """Whether ``regressor.fit`` accepts ``min_curvature`` (the smallest curvature of the
    bowl of a model stationary at a goal)."""
    return _takes(regressor, "min_curvature")


def takes_scored(regressor) -> bool:
    """Whether ``regressor.fit`` accepts ``scored`` (False: skip a CV score nobody reads)."""
    return _takes(regressor, "scored")


def takes_final(regressor) -> bool:
    """Whether ``regressor.fit`` accepts ``final`` (False: the CV's scores without the
    model fitted on all data)."""
    return _takes(regressor, "final")


def _takes(regressor, argument: str) -> bool:
    try:
        return argument in inspect.signature(regressor.fit).parameters
    except (TypeError, ValueError):
        return False
