"""The global model's training set and the cross-validation scores read from it.

Helpers of stage 4 of :class:`~policy_align_ros.learning.PolicyAlign`: the samples and
aligned potentials the regressor is fitted on, its CV score of the hyperparameters it
chose, a copy with those hyperparameters fixed (for the fold refits, and for scoring
other potentials cheaply, ``docs/design/tracking_lag.md``) and the level of the
demonstrations whose offsets the regressor fitted freely.
"""

from __future__ import annotations

import math

import numpy as np

from policy_align_ros.learning.anchor import motion_drops, motion_steps
from policy_align_ros.learning.regressors import (
    TrendKernelRegression,
    takes_drops,
    takes_goal,
    takes_min_curvature,
    takes_motion,
)
from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["cv_error", "cv_score", "fixed_copy", "level_free", "training_set"]


def training_set(trajs: list[Trajectory], masks: list[np.ndarray], keep: np.ndarray,
                 potentials: list[np.ndarray], free: np.ndarray, template,
                 goal: np.ndarray | None = None, min_curvature: float | None = None,
                 step_scale: float = 1.0
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
    min_curvature : float, optional
        With ``goal``: the smallest curvature of the fit's bowl there
        (:func:`~policy_align_ros.learning.anchor.bowl_curvature`).
    step_scale : float
        With ``goal``: the factor on the samples' steps and drops
        (:func:`~policy_align_ros.learning.anchor.step_scale`).

    Returns
    -------
    X (m, n), y (m,), groups (m,), and the fit's keyword arguments (``free_groups``,
    ``goal``, ``min_curvature`` and the samples' ``motion`` and ``drops`` where the
    template takes them).
    """
    X = np.concatenate([trajs[k].positions[masks[k]] for k in keep])
    y = np.concatenate([potentials[k][masks[k]] for k in keep])
    groups = np.concatenate([np.full(int(masks[k].sum()), k) for k in keep])
    extra = {"free_groups": free} if free.size else {}
    if goal is not None and takes_goal(template):
        extra["goal"] = goal
        if min_curvature is not None and takes_min_curvature(template):
            extra["min_curvature"] = min_curvature
    if "goal" in extra and takes_motion(template):
        # Timing-free evidence beside where the demonstrations end: which way they move.
        extra["motion"] = step_scale * np.concatenate(
            [motion_steps(trajs[k].positions)[masks[k]] for k in keep])
        if takes_drops(template):
            # And how steeply the potential falls along it, sample by sample.
            extra["drops"] = step_scale * np.concatenate(
                [motion_drops(potentials[k])[masks[k]] for k in keep])
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


def fixed_copy(regressor, n_folds: int | None = None):
    """An unfitted copy of ``regressor`` with its CV's choice (``cv_best_``) fixed.

    A ``TrendKernelRegression`` with a CV gets the hyperparameters it chose and the
    number of centres it drew; NaN marks what a candidate has none of (the single-index
    trend's index starts from the quadratic its own CV picks, as in the full fit). Any
    other regressor is a fresh copy of its parameters.

    Parameters
    ----------
    regressor : fitted regressor
    n_folds : int, optional
        The copy's CV folds; the regressor's own when None. Its score is then comparable
        with the regressor's (``cv_score``); fewer folds cost less where no score is read.
    """
    params = regressor.get_params(deep=False)
    best = getattr(regressor, "cv_best_", None)
    if isinstance(regressor, TrendKernelRegression) and best is not None:
        form, trend, length, kernel, offset = best
        params.update(trend_form=form, trend_ridge="cv" if math.isnan(trend) else trend,
                      length_scale=1.0 if math.isnan(length) else length,
                      kernel_ridge=kernel, offset_ridge=offset)
        if n_folds is not None:
            params["n_folds"] = n_folds
        if hasattr(regressor, "n_centres_"):
            # As many centres as the fit drew: a refit on fewer demonstrations is the
            # same model on less data.
            params["n_centres"] = regressor.n_centres_
    return type(regressor)(**params)


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

