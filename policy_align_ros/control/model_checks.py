"""What the executor checks about a model when it loads it, ROS-free.

Two things a model file can record that make its runs go wrong although it loads:

* *a forced model*: ``policy-align learn --force`` (the learner's ``force:=true``) writes
  a fit that ``learn`` refused (no better than a zero policy, no minimum, ...) and records
  that in the header's ``training.pipeline`` block (``forced``, ``refusals``;
  :mod:`policy_align_ros.data.pipeline`). Such a model drove a UR10 away from its goal
  until the extrapolation guard stopped it. The executor refuses to arm it
  (:meth:`~policy_align_ros.control.step.ControlStep.model_check`,
  :data:`~policy_align_ros.control.causes.ZeroCause.FORCED_MODEL`) unless
  ``allow_forced_model`` is set, and warns whenever one is loaded (:func:`model_refusals`,
  :func:`forced_model_refusal`, :func:`forced_model_warning`);
* *a learnt goal beyond the guard's reach*: the extrapolation guard stops commands
  leading out of the data at ``max_extrapolation`` spacings, or ``max_extrapolation_rad``
  rad, from it (:mod:`policy_align_ros.control.guard`). A learnt goal farther out (short
  demonstrations that stop before the goal) is never reached: every run stops at the
  edge. It is not refused (the user may want it), but said at load and on
  ``/diagnostics`` (:class:`GoalReach`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from policy_align_ros.control.guard import ExtrapolationGuard

__all__ = ["GoalReach", "forced_model_refusal", "forced_model_warning", "model_refusals"]

#: Stands for the refusals of a model whose file says it was forced but names none.
UNNAMED_REFUSAL = "(the model file names no refusal)"


def model_refusals(model) -> tuple[str, ...]:
    """Why ``learn`` refused ``model``, when its file records that it was written anyway.

    Parameters
    ----------
    model : PolicyAlign
        As loaded; its ``fit_summary_["pipeline"]`` is the learn pipeline's summary
        (``forced``, ``refusals``).

    Returns
    -------
    tuple of str
        The refusals of a model recorded as forced (``forced`` true, or refusals recorded:
        a refused fit is only written when forced); empty for a model that passed every
        gate, and for one written without the learn pipeline (``PolicyAlign.save``).
    """
    pipeline = (getattr(model, "fit_summary_", None) or {}).get("pipeline")
    if not isinstance(pipeline, Mapping):
        return ()
    recorded = pipeline.get("refusals")
    refusals = (tuple(str(r) for r in recorded if str(r))
                if isinstance(recorded, list) else ())
    if pipeline.get("forced") is True or refusals:
        return refusals or (UNNAMED_REFUSAL,)
    return ()


def forced_model_refusal(refusals: Sequence[str]) -> str:
    """The ~/enable refusal (and ``zero_reason``) for a forced model whose ``refusals``
    :func:`model_refusals` gives: what learn said and the two ways on."""
    return (f"the model was refused by learn and written only because it was forced "
            f"(--force, or the learner's force:=true): {'; '.join(refusals)}. Learn a "
            f"model that passes (more or better demonstrations, without force), or, to run "
            f"this one anyway, set allow_forced_model (-p allow_forced_model:=true, or "
            f"policy-align param set /executor allow_forced_model true)")


def forced_model_warning(path: str, refusals: Sequence[str], allowed: bool) -> str:
    """The warning logged when a forced model (``refusals``) is loaded from ``path``;
    ``allowed``: ``allow_forced_model``."""
    then = ("allow_forced_model is set: ~/enable arms it" if allowed else
            "~/enable is refused until allow_forced_model is set or a model that passes "
            "is loaded")
    return (f"model {path} was refused by learn and written only because it was forced: "
            f"{'; '.join(refusals)}; {then}")


@dataclass(frozen=True)
class GoalReach:
    """The learnt goal's distance to the model's data, as the extrapolation guard
    measures it (:class:`~policy_align_ros.control.guard.ExtrapolationGuard`'s
    ``distance`` at the goal's posture).

    Attributes
    ----------
    distance : float
        ``d`` at the goal (spacings of the training data, >= 0).
    grad_norm : float
        ``|grad d|`` there (spacings per rad; NaN on a support state, where ``d`` is 0).
    """

    distance: float
    grad_norm: float

    @property
    def distance_rad(self) -> float:
        """The distance in rad (joint-space 2-norm to the nearest support state)."""
        return 0.0 if self.distance == 0.0 else self.distance / self.grad_norm

    def reach_rad(self, guard: ExtrapolationGuard, max_velocity: np.ndarray,
                  max_acceleration: float | None) -> tuple[float, str]:
        """How far from the data (rad), in the goal's direction, the guard stops a command
        leading out, and the parameter that sets it (:meth:`ExtrapolationGuard.edge`);
        ``(inf, "")`` for a goal on the data."""
        if not self.grad_norm > 0.0:
            return math.inf, ""
        edge, limit = guard.edge(self.grad_norm, max_velocity, max_acceleration)
        return edge / self.grad_norm, limit

    def beyond(self, guard: ExtrapolationGuard, max_velocity: np.ndarray,
               max_acceleration: float | None) -> bool:
        """Whether the goal lies beyond the guard's reach: no run gets there."""
        return self.distance_rad > self.reach_rad(guard, max_velocity, max_acceleration)[0]

    def fixes(self, guard: ExtrapolationGuard, max_velocity: np.ndarray,
              max_acceleration: float | None) -> dict[str, float]:
        """The parameters to raise so that the guard leaves the way to the goal unscaled
        (``d_max >= d``), with the least value that does it, rounded up to 0.01:
        ``max_extrapolation`` (spacings) when it is below ``d``, ``max_extrapolation_rad``
        (rad) when its cap ``R |grad d| - b`` is; empty when neither is."""
        g, d = self.grad_norm, self.distance
        if not g > 0.0:
            return {}
        out = {}
        if d > guard.max_extrapolation:
            out["max_extrapolation"] = _up(d)
        rad = guard.max_extrapolation_rad
        if rad is not None:
            band = guard.bounds(g, max_velocity, max_acceleration)[1]
            if rad * g - band < d:
                # Raised, the cap's band is the uncapped one (R g >= d + b >= min_band).
                out["max_extrapolation_rad"] = _up(
                    (d + guard.band(g, max_velocity, max_acceleration)) / g)
        return out

    def problem(self, guard: ExtrapolationGuard, max_velocity: np.ndarray,
                max_acceleration: float | None) -> str:
        """The goal beyond the guard's reach in words: both distances, the limit that
        binds and the fixes (:meth:`fixes`); "" when the guard lets runs get there."""
        limits = (guard, max_velocity, max_acceleration)
        if not self.beyond(*limits):
            return ""
        reach, limit = self.reach_rad(*limits)
        rad = limit == "max_extrapolation_rad"
        value = guard.max_extrapolation_rad if rad else guard.max_extrapolation
        raise_ = " and ".join(f"{name} to at least {v:.2f}{' rad' if name.endswith('rad') else ''}"
                              for name, v in self.fixes(*limits).items())
        return (f"the learnt goal lies {self.distance_rad:.2f} rad ({self.distance:.2f} "
                f"spacings of the training data) from the nearest training state, beyond "
                f"the extrapolation guard's reach of {reach:.2f} rad "
                f"({reach * self.grad_norm:.2f} spacings; {limit} {value:g}"
                f"{' rad' if rad else ' spacings'}): every run stops at the data's edge short "
                f"of it. Record demonstrations that end at the goal, or raise "
                f"{raise_ or limit}")


def _up(value: float) -> float:
    """``value`` rounded up to two decimals, as a parameter value to suggest."""
    return math.ceil(value * 100.0 - 1e-9) / 100.0
