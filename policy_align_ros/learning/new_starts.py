"""Whether runs of the learnt policy from new starts near the data stop at the goal.

The goal report (:mod:`~policy_align_ros.learning.goal`) descends the learnt potential from
where the demonstrations rest and end, and from where they start: it finds the minima on
the demonstrated paths. A user's new start need not lie on one. Between and beside the
paths the potential is the model's extrapolation, and a kernel residual can leave a
minimum there that no demonstration passes (on LASA, trained on all 7 demonstrations,
runs from new starts stop at such minima on 4 of the 13 tuning shapes).
So the fit also descends the potential from :data:`NEW_STARTS` random states in the data's
bounding box widened by :data:`NEW_START_MARGIN` of its extent, where demonstrations end
together (:func:`~policy_align_ros.learning.goal.demonstrated_goal`), and reports the
minima those runs stop at instead of the goal. Where some do, an anchored fit tries once
more with a stiffer kernel residual (:func:`stiffer_residual`) and keeps it when fewer
runs stop elsewhere (``docs/design/goal_report.md``, "From new starts").

A run can stop at the goal and still take far longer than any demonstration did, crawling
over a plateau the fit left beside the paths: a user sees a robot that stalls. So the fit
kept also runs the policy, in time, from the new starts whose descent stops at the goal
(:func:`new_starts_late`, with the clock and tolerance of
:func:`~policy_align_ros.learning.reach.starts_reach`), and warns where some are still on
their way after :data:`~policy_align_ros.learning.reach.REACH_TIME` times the
demonstrations' median duration.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np

from policy_align_ros.learning.descent import MINIMA_MERGE, Field, flow_stops, merge_points
from policy_align_ros.learning.goal import GOAL_MERGE, _nearest
from policy_align_ros.learning.reach import REACH_TIME, reach_times
from policy_align_ros.learning.regressors.trend_kernel.cv import KERNEL_RIDGE_GRID
from policy_align_ros.learning.trajectory import Trajectory, sample_period

__all__ = ["NEW_STARTS", "NEW_START_MARGIN", "new_start_runs", "new_starts_late",
           "new_starts_late_message", "new_starts_message", "stiffer_residual"]

#: Random new starts descended, whatever the dimension: a run stopped by a minimum in a
#: basin that covers 3.5 % of the box is then found with a probability of 0.9.
NEW_STARTS = 64
#: The new starts lie in the data's bounding box widened by this fraction of its extent on
#: each side (the margin of the LASA bench's field, where a user may start a run).
NEW_START_MARGIN = 0.15


def new_start_runs(trajs: Sequence[Trajectory], potential: Field, gradient: Field,
                   goal: np.ndarray | None, extent: float, speed: float,
                   random_state: int | np.random.Generator | None = None
                   ) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    """Descents of the learnt potential from random new starts near the data.

    Each start follows the policy's flow as the demonstrated starts do
    (:func:`~policy_align_ros.learning.descent.flow_stops`), and counts when it stops more
    than ``GOAL_MERGE`` of the extent from ``goal`` or leaves the data's box widened by
    its extent.

    Parameters
    ----------
    trajs : sequence of Trajectory
        The demonstrations (state units).
    potential, gradient : callable
        The learnt potential (m,) and its gradient (m, n) at states (m, n).
    goal : ndarray (n,) or None
        Where the demonstrations end together; None: nothing is run (several goals, or
        none), and every entry is None.
    extent, speed : float
        The data's extent W (state units) and typical speed (state units/s).
    random_state : int, Generator or None
        Seeds the starts.

    Returns
    -------
    report : dict
        ``n_new_starts``, ``n_new_starts_elsewhere`` (those that stop away from the goal
        or leave the box), ``n_new_starts_escaped`` (those that leave it) and
        ``new_start_minima``: where the others stop, merged within ``MINIMA_MERGE`` of
        the extent, lowest potential first, each ``point``, ``potential``, ``n_starts``
        (how many runs stop there), ``goal_fraction`` and ``data_fraction`` (distance to
        the goal and to the nearest sample, over W).
    starts : ndarray (NEW_STARTS, n)
        The new starts (state units; none without a goal).
    at_goal : ndarray of bool (NEW_STARTS,)
        Whose descent stopped at the goal.
    """
    if goal is None:
        return ({"n_new_starts": None, "n_new_starts_elsewhere": None,
                 "n_new_starts_escaped": None, "new_start_minima": None},
                np.zeros((0, trajs[0].positions.shape[1])), np.zeros(0, dtype=bool))
    X = np.concatenate([t.positions for t in trajs])
    rng = np.random.default_rng(random_state)
    lo, hi = X.min(axis=0) - NEW_START_MARGIN * extent, X.max(axis=0) + NEW_START_MARGIN * extent
    starts = lo + rng.random((NEW_STARTS, X.shape[1])) * (hi - lo)
    ends, inside = flow_stops(potential, gradient, starts, X, extent, speed)
    elsewhere = inside & (np.linalg.norm(ends - goal, axis=1) > GOAL_MERGE * extent)
    minima = []
    if elsewhere.any():
        points, values = merge_points(ends[elsewhere], potential(ends[elsewhere]),
                                MINIMA_MERGE * extent)
        # Each run's stop to its merged minimum: the nearest of them.
        owner = np.argmin(np.linalg.norm(ends[elsewhere][:, None] - points[None], axis=2),
                          axis=1)
        for i, (p, v) in enumerate(zip(points, values, strict=True)):
            minima.append({"point": [float(c) for c in p], "potential": float(v),
                           "n_starts": int(np.count_nonzero(owner == i)),
                           "goal_fraction": float(np.linalg.norm(p - goal)) / extent,
                           "data_fraction": _nearest(X, p) / extent})
    escaped = int(np.count_nonzero(~inside))
    return ({"n_new_starts": NEW_STARTS,
             "n_new_starts_elsewhere": int(np.count_nonzero(elsewhere)) + escaped,
             "n_new_starts_escaped": escaped, "new_start_minima": minima},
            starts, inside & ~elsewhere)


def new_starts_late(trajs: Sequence[Trajectory], gradient: Field, goal: np.ndarray,
                    extent: float, starts: np.ndarray) -> int:
    """How many runs of ``xdot = -gradient(x)`` from ``starts`` (s, n) do not come within
    ``GOAL_MERGE`` of the extent of ``goal`` (n,) within :data:`~policy_align_ros.learning.
    reach.REACH_TIME` times the demonstrations' median duration: explicit Euler at their
    sample period (:func:`~policy_align_ros.learning.reach.reach_times`), as for the
    demonstrated starts.

    ``trajs``: the demonstrations (state units; times in s, or none: one step per
    sample); ``extent``: the data's extent W (state units).
    """
    if not len(starts):
        return 0
    horizon = REACH_TIME * float(np.median([t.duration for t in trajs]))
    arrival = reach_times(gradient, starts, np.asarray(goal, dtype=float),
                          np.full(len(starts), horizon), sample_period(trajs),
                          GOAL_MERGE * extent)
    return int(np.count_nonzero(~np.isfinite(arrival)))


def new_starts_late_message(goal: dict[str, Any]) -> str | None:
    """The warning of a goal report whose new starts reach the goal late; None if none
    does."""
    late = goal.get("n_new_starts_late")
    if not late:
        return None
    return (f"PolicyAlign: runs of the learnt policy from {late} of {goal['n_new_starts']} "
            f"random new starts within {100 * NEW_START_MARGIN:g} % of the data's extent of "
            f"its box are still on their way to the goal after {REACH_TIME:g} times the "
            "demonstrations' median duration (fit_summary_['goal']['n_new_starts_late']): "
            "beside the demonstrated paths the learnt potential is nearly flat, and a robot "
            "started there would crawl (record demonstrations from there?)")


def stiffer_residual(template: Any, fitted: Any, direction_weight: float | None
                     ) -> Any | None:
    """The candidate an anchored fit tries when runs from new starts stop elsewhere: a copy
    of ``template`` with the direction weight ``fitted`` was chosen with and the largest
    finite kernel penalty of the CV's grid, when the CV chose the penalty (``template``'s
    ``kernel_ridge`` is ``"cv"``) and ``fitted``'s is smaller; None otherwise.

    The CV scores the residual along held-out demonstrations only; between and beside
    them a small penalty lets the kernel weights grow into wells no demonstration showed
    (``docs/design/goal_report.md``, "From new starts").
    """
    params = template.get_params(deep=False) if hasattr(template, "get_params") else {}
    largest = max(k for k in KERNEL_RIDGE_GRID if np.isfinite(k))
    if params.get("kernel_ridge") != "cv" or not getattr(fitted, "kernel_ridge_",
                                                         np.inf) < largest:
        return None
    return copy.deepcopy(template).set_params(direction_weight=direction_weight,
                                              kernel_ridge=largest)


def new_starts_message(goal: dict[str, Any]) -> str | None:
    """The warning of a goal report whose new starts stop elsewhere; None if none does."""
    count = goal.get("n_new_starts_elsewhere")
    if not count:
        return None
    minima = goal["new_start_minima"]
    where = []
    if minima:
        far = max(m["goal_fraction"] for m in minima)
        where.append(f"{len(minima)} minima up to {100 * far:.3g} % of the data's extent "
                     "from the goal")
    if goal["n_new_starts_escaped"]:
        where.append(f"{goal['n_new_starts_escaped']} out of the data's region")
    return (f"PolicyAlign: runs of the learnt policy from {count} of {goal['n_new_starts']} "
            f"random new starts within {100 * NEW_START_MARGIN:g} % of the data's extent of "
            f"its box stop away from the goal ({', '.join(where)}; fit_summary_['goal']"
            "['new_start_minima']): between or beside the demonstrated paths the learnt "
            "potential has minima no demonstration showed, and a robot started there would "
            "stop short (record demonstrations from there?)")
