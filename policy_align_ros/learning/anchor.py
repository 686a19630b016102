"""Whether a fit must be made stationary where the demonstrations end (the goal anchor).

Where most demonstrations end (:func:`~policy_align_ros.learning.goal.demonstrated_goal`)
does not depend on how they were timed. PolicyAlign keeps the paper's potential when it has
a minimum within :data:`ANCHOR_TOL` extents of that goal, or within the spread of the ends
around it if wider (a teacher stops a little apart each time), or when it predicts held-out
demonstrations to round-off (their timing is one potential's, so a rest away from its
minimum is a rest under a constraint, not a goal); otherwise (a teacher's timing, a
lagging robot, a potential its family cannot hold) it refits the global model stationary
there, with the direction of the demonstrations' motion (:func:`motion_steps`) as
timing-free evidence of the slope across them (``docs/design/goal_anchor.md``). How much
that evidence weighs against the timed potential values is chosen by whether the
demonstrations' starts reach the goal and the goal is a strict minimum
(:func:`choose_direction_weight`, :func:`goal_curvature`). The demonstrations' durations
bound how flat the anchored bowl may be (:func:`bowl_curvature`).
"""

from __future__ import annotations

import copy
import math
import warnings
from collections.abc import Callable, Sequence

import numpy as np

from policy_align_ros.learning.descent import learnt_minima
from policy_align_ros.learning.goal import (
    GOAL_MERGE,
    data_extent,
    goal_ends,
    starts_elsewhere,
    typical_speed,
)
from policy_align_ros.learning.model_io import json_float
from policy_align_ros.learning.reach import REACH_TIME
from policy_align_ros.learning.regressors.trend_kernel.model import DIRECTION_WEIGHTS
from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["ANCHOR_TOL", "CONSISTENT_SCORE", "REFERENCE_SAMPLES", "anchor_decision",
           "bowl_curvature", "choose_direction_weight", "direction_candidates",
           "goal_curvature", "motion_drops", "motion_steps", "step_scale"]

#: The paper's potential is kept when one of its minima lies within this fraction of the
#: data's extent of where the demonstrations end, or within the ends' own spread around
#: it when that is wider; farther, the model is made stationary there.
ANCHOR_TOL = 0.01
#: A CV score (held-out error over the within-demonstration spread) at or below this is
#: round-off: the demonstrations are exact flows of the fitted potential.
CONSISTENT_SCORE = 1e-10
#: Samples per demonstration at which the direction weights were chosen (LASA, every
#: 5th sample): :func:`step_scale` measures steps as if every demonstration had as many.
REFERENCE_SAMPLES = 200
#: Step of the central differences of :func:`goal_curvature`, as a fraction of the extent.
CURVATURE_STEP = 1e-4


def anchor_decision(regressor, trajs: Sequence[Trajectory], can_anchor: bool = True,
                    cv_score: float | None = None) -> dict:
    """The goal anchor's entry of ``fit_summary_`` for a fitted global model.

    Parameters
    ----------
    regressor : fitted regressor
        With ``predict(X)`` (m,) and ``gradient(X)`` (m, n): the paper's potential.
    trajs : sequence of Trajectory
        The demonstrations (state units).
    can_anchor : bool
        Whether the regressor can be refitted stationary at a goal (``takes_goal``).
    cv_score : float, optional
        The regressor's cross-validation score (held-out error over the spread); at or
        below :data:`CONSISTENT_SCORE` the paper's potential is kept.

    Returns
    -------
    dict
        ``goal`` (list of n floats, or None), ``goal_spread_fraction`` (the largest
        distance of the ends that make the goal from it, over the extent; None without a
        goal), ``unanchored_error_fraction`` (the distance from the goal to the
        potential's nearest minimum over the extent; None when there is no goal, inf as
        None when no minimum was found), ``consistent`` (the CV score is at round-off) and
        ``anchored`` (bool).
    """
    ends = goal_ends(trajs)
    goal = None if ends is None else ends.mean(axis=0)
    consistent = cv_score is not None and cv_score <= CONSISTENT_SCORE
    extent = data_extent(trajs)
    spread = None if goal is None else float(
        np.max(np.linalg.norm(ends - goal, axis=1))) / (extent or 1.0)
    out = {"goal": None if goal is None else [float(v) for v in goal],
           "goal_spread_fraction": spread, "unanchored_error_fraction": None,
           "consistent": consistent, "anchored": False}
    if goal is None or not can_anchor:
        return out
    speed = typical_speed(trajs)
    found = learnt_minima(regressor.predict, regressor.gradient, goal[None], scale=extent,
                          speed=speed)
    error = (float(np.min(np.linalg.norm(found.points - goal, axis=1))) / extent
             if len(found.points) else math.inf)
    out["unanchored_error_fraction"] = json_float(error, "null")
    # The goal is known only to the spread of where the teacher stopped: a minimum inside
    # it is one the demonstrations cannot tell from theirs.
    out["anchored"] = not (error <= max(ANCHOR_TOL, spread) or consistent)
    return out


def motion_steps(positions: np.ndarray) -> np.ndarray:
    """Each sample's step along its trajectory (N, n), state units: central differences,
    one-sided at the ends (zeros for a single sample)."""
    if len(positions) < 2:
        return np.zeros_like(positions)
    return np.gradient(positions, axis=0)


def motion_drops(potential: np.ndarray) -> np.ndarray:
    """Each sample's change of a potential estimate (N,) over its :func:`motion_steps`
    step (N,), potential units: central differences, one-sided at the ends."""
    if len(potential) < 2:
        return np.zeros_like(potential)
    return np.gradient(potential)


def step_scale(trajs: Sequence[Trajectory]) -> float:
    """The factor on every sample's step and drop (:func:`motion_steps`,
    :func:`motion_drops`) that measures them as if each demonstration had
    :data:`REFERENCE_SAMPLES` samples: the median over demonstrations of
    ``(N_k - 1) / (REFERENCE_SAMPLES - 1)``, ``N_k`` its samples.

    The direction rows weigh a slope across the motion over one step against an error in
    the potential's values. A step is the motion between two samples, so without this
    factor the same weight would count the square of the recording rate less at a
    higher rate (``docs/design/goal_anchor.md``, "Steps at any recording rate").

    Parameters
    ----------
    trajs : sequence of Trajectory
        The demonstrations as recorded (not their pieces).

    Returns
    -------
    float
        Dimensionless; 1 at :data:`REFERENCE_SAMPLES` samples per demonstration.
    """
    counts = [t.n_samples - 1 for t in trajs]
    return float(np.median(counts)) / (REFERENCE_SAMPLES - 1) if counts else 1.0


def bowl_curvature(trajs: Sequence[Trajectory]) -> float:
    """The smallest curvature of an anchored fit's quadratic trend at the goal:
    ``ln(1 / GOAL_MERGE) / (REACH_TIME T)``, with ``T`` the demonstrations' median
    duration.

    The demonstrations show the goal reached within about ``T`` from where they start. A
    bowl flatter than they are in some direction lets runs crawl there: the flow
    ``xdot = -lambda x`` of an eigenvalue ``lambda`` shrinks an offset by
    ``exp(-lambda t)``. At this bound, the slowest direction of the trend brings an
    offset to :data:`~policy_align_ros.learning.goal.GOAL_MERGE` of itself in
    :data:`~policy_align_ros.learning.reach.REACH_TIME` times ``T``: the time and the
    tolerance within which the fit's own checks expect a run at the goal
    (:func:`~policy_align_ros.learning.reach.reach_times`). The kernel residual can still
    bend the potential beside the data; the bound is the trend's, which decides away
    from it (``docs/design/goal_anchor.md``, "The bowl's least curvature").

    Parameters
    ----------
    trajs : sequence of Trajectory
        The demonstrations; untimed ones count their steps (one per sample).

    Returns
    -------
    float
        1/s: potential units (state units squared per second) per squared state unit;
        per step without times.
    """
    duration = float(np.median([t.duration for t in trajs]))
    return math.log(1.0 / GOAL_MERGE) / (REACH_TIME * duration) if duration > 0 else 0.0


def goal_curvature(gradient: Callable[[np.ndarray], np.ndarray], goal: np.ndarray,
                   extent: float) -> float:
    """The smallest eigenvalue of the potential's Hessian at ``goal``.

    The anchored fit makes the goal stationary, which a saddle is too: a residual that
    bends the potential near the goal can leave a minimum beside it, where runs then stop.
    Positive: the goal is a strict minimum.

    Parameters
    ----------
    gradient : callable
        ``gradient(X)`` (m, n) of the potential at states ``X`` (m, n).
    goal : ndarray (n,)
        State units.
    extent : float
        The data's extent (state units); the central differences step
        :data:`CURVATURE_STEP` of it.

    Returns
    -------
    float
        Potential units per squared state unit (the symmetric part of the
        central-difference Hessian).
    """
    goal = np.asarray(goal, dtype=float)
    step = CURVATURE_STEP * (extent if extent > 0 else 1.0)
    probes = goal + step * np.concatenate([np.eye(len(goal)), -np.eye(len(goal))])
    g = np.asarray(gradient(probes), dtype=float)
    H = (g[:len(goal)] - g[len(goal):]) / (2.0 * step)
    return float(np.linalg.eigvalsh(0.5 * (H + H.T))[0])


def direction_candidates(template) -> list:
    """The regressors an anchored fit tries, in order: copies of ``template`` with each of
    :data:`DIRECTION_WEIGHTS`, largest first, when its ``direction_weight`` is
    ``"auto"``; otherwise ``template`` alone."""
    params = template.get_params(deep=False) if hasattr(template, "get_params") else {}
    if params.get("direction_weight") != "auto":
        return [template]
    return [copy.deepcopy(template).set_params(direction_weight=w) for w in DIRECTION_WEIGHTS]


def choose_direction_weight(fit: Callable[[object], object], candidates: Sequence,
                            trajs: Sequence[Trajectory], goal: np.ndarray) -> dict:
    """Fit the candidates in turn and keep the first from whose every demonstration's start
    the learnt policy reaches the goal, and whose goal is a strict minimum.

    A demonstration shows a path from its start to the goal, whatever its timing. The
    direction of motion is the timing-free part of that evidence, the potential's values
    the timed part: the more the fit trusts the directions, the less a teacher's
    changing speed bends the field across the paths, until too little of the values is
    left to keep every start in the goal's basin. The largest weight whose policy still
    takes every start to the goal (:func:`~policy_align_ros.learning.goal.
    starts_elsewhere`) and stops there (:func:`goal_curvature` positive: the descent from
    a start counts a stop within a few percent of the extent as the goal, a held-out
    start may take the other side of a saddle) is kept; if none does, the last
    candidate's fit.

    Parameters
    ----------
    fit : callable
        ``fit(candidate)`` fits the global model with that regressor template and returns
        the fitted regressor (``predict`` (m,), ``gradient`` (m, n)); the last call's fit
        is the one kept.
    candidates : sequence of regressors
        From :func:`direction_candidates`.
    trajs : sequence of Trajectory
        The demonstrations (state units).
    goal : ndarray (n,)
        Where they end together (:func:`anchor_decision`'s ``goal``), state units.

    Returns
    -------
    dict
        ``direction_weight`` (the kept candidate's, None for a regressor without one),
        ``direction_weights_tried``: per candidate fitted, its ``direction_weight``,
        ``n_starts_elsewhere`` (None for the last candidate, which is kept unchecked: the
        goal report counts its starts, ``fit_summary_["goal"]``) and ``goal_curvature``,
        ``goal_is_minimum`` (the kept candidate's; a warning names it when False) and
        ``starts``: the kept candidate's :func:`~policy_align_ros.learning.goal.
        starts_elsewhere` (None when unchecked), which the goal report then need not
        compute again.
    """
    # As goal_summary measures them, so that ``starts`` is the goal report's own result.
    extent, speed = data_extent(trajs) or 1.0, typical_speed(trajs)
    goal = np.asarray(goal, dtype=float)
    tried: list[dict] = []
    found = None
    for i, candidate in enumerate(candidates):
        regressor = fit(candidate)
        weight = candidate.get_params(deep=False).get("direction_weight") if hasattr(
            candidate, "get_params") else None
        curvature = goal_curvature(regressor.gradient, goal, extent)
        entry = {"direction_weight": weight, "n_starts_elsewhere": None,
                 "goal_curvature": json_float(curvature, "null")}
        tried.append(entry)
        if i == len(candidates) - 1:
            found = None
            break
        found = starts_elsewhere(trajs, regressor.predict, regressor.gradient, extent, speed)
        entry["n_starts_elsewhere"] = found["n_starts_elsewhere"]
        if found["n_starts_elsewhere"] == 0 and curvature > 0.0:
            break
    minimum = bool(curvature > 0.0)
    if not minimum:
        warnings.warn(
            f"PolicyAlign: where the demonstrations end, {np.round(goal, 6).tolist()}, the "
            f"learnt potential is stationary but not a minimum (smallest curvature "
            f"{curvature:.3g}): runs stop beside it (fit_summary_['goal'] lists the minima)",
            UserWarning, stacklevel=3)
    return {"direction_weight": tried[-1]["direction_weight"],
            "direction_weights_tried": tried, "goal_is_minimum": minimum, "starts": found}
