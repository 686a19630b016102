"""The global model's training set and the cross-validation scores read from it.

Helpers of stage 4 of :class:`~policy_align_ros.learning.PolicyAlign`: the samples and
aligned potentials the regressor is fitted on, its CV score of the hyperparameters it
chose, a copy with those hyperparameters fixed (for scoring other potentials cheaply,
``docs/design/tracking_lag.md``) and the level of the demonstrations whose offsets the
regressor fitted freely.
"""

from __future__ import annotations

import math

import numpy as np

from policy_align_ros.learning.anchor import motion_steps
from policy_align_ros.learning.regressors import takes_goal, takes_motion
from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["cv_error", "cv_score", "fixed_hyperparameters", "level_free", "training_set"]


def training_set(trajs: list[Trajectory], masks: list[np.ndarray], keep: np.ndarray,
                 potentials: list[np.ndarray], free: np.ndarray, template,
                 goal: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """The global model's training samples.

    Parameters
    ----------
    trajs, masks : list
        Trajectories (pieces) and their training masks (bool, (N_k,)).
    keep : ndarray of int
        The trajectories fitted (``inliers_``).
    potentials : list of ndarray, shape (N_k,)
        Aligned potentials of every trajectory.
    free : ndarray of int
        Trajectories whose offsets the regressor fits freely.
    template : regressor
        Decides which keyword arguments the fit takes (``goal``, ``motion``).
    goal : ndarray, shape (n,), optional
        The demonstrated goal of an anchored fit.

    Returns
    -------
    X (m, n), y (m,), groups (m,), and the fit's keyword arguments (``free_groups``,
    ``goal`` and the samples' ``motion`` where the template takes them).
    """
    X = np.concatenate([trajs[k].positions[masks[k]] for k in keep])
    y = np.concatenate([potentials[k][masks[k]] for k in keep])
    groups = np.concatenate([np.full(int(masks[k].sum()), k) for k in keep])
    extra = {"free_groups": free} if free.size else {}
    if goal is not None and takes_goal(template):
        extra["goal"] = goal
    if "goal" in extra and takes_motion(template):
        # Timing-free evidence beside where the demonstrations end: which way they move.
        extra["motion"] = np.concatenate([motion_steps(trajs[k].positions)[masks[k]]
                                          for k in keep])
    return X, y, groups, extra


def cv_score(regressor) -> float | None:
    """The regressor's cross-validation score of the hyperparameters it chose, if any."""
    best = getattr(regressor, "cv_best_", None)
    scores = getattr(regressor, "cv_scores_", None)
    if best is None or not scores or best not in scores:
        return None
    score = float(scores[best])
    return score if math.isfinite(score) else None


def cv_error(regressor) -> float:
    """The standard error over the folds of the regressor's chosen CV score (NaN when it
    has none)."""
    best = getattr(regressor, "cv_best_", None)
    errors = getattr(regressor, "cv_standard_errors_", None) or {}
    return float(errors.get(best, math.nan)) if best is not None else math.nan


def fixed_hyperparameters(regressor):
    """An unfitted copy of a CV-fitted ``regressor`` with the hyperparameters it chose
    fixed (a cheap fit that scores other potentials with the same model), or None when
    it has no CV choice to fix."""
    if cv_score(regressor) is None or not hasattr(regressor, "set_params"):
        return None
    names = ("trend_form", "trend_ridge", "length_scale", "kernel_ridge", "offset_ridge")
    if not all(hasattr(regressor, name + "_") for name in names):
        return None
    chosen = {name: getattr(regressor, name + "_") for name in names}
    # NaN: not used by the chosen form (the single-index trend's trend penalty).
    chosen = {k: v for k, v in chosen.items() if not (isinstance(v, float) and math.isnan(v))}
    return type(regressor)(**{**regressor.get_params(), **chosen})


def level_free(offsets: np.ndarray, potentials: list[np.ndarray], free: np.ndarray,
                regressor, trajs: list[Trajectory], masks: list[np.ndarray]
                ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Offsets and aligned potentials with the trajectories ``free`` moved to the level of
    the global model: the mean of ``f(x) - phi`` over their training samples, which is the
    free offset a least-squares fit gives them."""
    offsets, potentials = offsets.copy(), list(potentials)
    for k in free:
        x = trajs[k].positions[masks[k]]
        level = float(np.mean(regressor.predict(x) - potentials[k][masks[k]]))
        offsets[k] += level
        potentials[k] = potentials[k] + level
    return offsets, potentials

