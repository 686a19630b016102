"""Whether runs of the learnt policy from where the demonstrations start reach their goal
in time.

The goal report (:mod:`~policy_align_ros.learning.goal`) descends the learnt potential: it
finds where a run stops, not when. A potential can lead every demonstrated start to the
goal and still hold a run for minutes on a plateau the fit left near the starts (a teacher
who set off slowly makes the potential's estimate flat there): a user sees a robot that
stalls. So the learnt policy is run from every demonstrated start, in time, for
:data:`REACH_TIME` times its demonstration's duration: under a projection constraint a
demonstration moves no faster than the unconstrained policy (``|N pi| <= |pi|``), so a
run that needs several times as long crossed a slope the demonstrations did not show.

A run reaches the goal when it comes within ``GOAL_MERGE`` of the data's extent of it,
the tolerance of :func:`~policy_align_ros.learning.goal.starts_elsewhere`.
``docs/design/goal_report.md`` ("In time, from new starts") gives the numbers behind the
choices.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from policy_align_ros.learning.goal import GOAL_MERGE
from policy_align_ros.learning.trajectory import Trajectory, sample_period

__all__ = ["MAX_REACH_STEPS", "REACH_TIME", "reach_times", "starts_reach"]

#: A run must reach the goal within this many times its demonstration's duration.
REACH_TIME = 3.0
#: Euler steps of a run at most; longer horizons take longer steps.
MAX_REACH_STEPS = 2000

Field = Callable[[np.ndarray], np.ndarray]


def reach_times(gradient: Field, X0: np.ndarray, goal: np.ndarray, horizon: np.ndarray,
                dt: float, tol: float, owner: np.ndarray | None = None) -> np.ndarray:
    """How long runs of ``xdot = -gradient(x)`` take to come within ``tol`` of ``goal``.

    Explicit Euler at ``dt`` (longer when the longest horizon would take more than
    :data:`MAX_REACH_STEPS` steps), all runs at once; a run stops once it has arrived.

    Parameters
    ----------
    gradient : callable
        ``gradient(X)`` (m, n) of the learnt potential (the policy is its negative).
    X0 : ndarray (m, n)
        Starts (state units).
    goal : ndarray (n,)
    horizon : ndarray (m,)
        How long each run may take (seconds, or steps for untimed data).
    dt : float
        Step (the demonstrations' sample period).
    tol : float
        Arrival radius (state units).
    owner : ndarray of int (m,), optional
        With it, runs follow different policies: ``gradient(X, owner)`` is each run's own
        (:func:`~policy_align_ros.learning.regressors.trend_kernel.stacked.
        stacked_gradient`).

    Returns
    -------
    ndarray (m,)
        Time of arrival; ``inf`` for a run that did not arrive within its horizon.
    """
    X = np.array(X0, dtype=float)
    arrival = np.full(len(X), math.inf)
    dt = max(dt, float(np.max(horizon)) / MAX_REACH_STEPS)
    active = np.linalg.norm(X - goal, axis=1) > tol
    arrival[~active] = 0.0
    t = 0.0
    # A run that a potential without a floor throws off overflows: it counts as not arrived,
    # and its overflow is no warning of the fit's.
    with np.errstate(over="ignore", invalid="ignore"):
        while active.any():
            t += dt
            idx = np.flatnonzero(active)
            X[idx] -= dt * (gradient(X[idx]) if owner is None
                            else gradient(X[idx], owner[idx]))
            moving = np.isfinite(X[idx]).all(axis=1)
            there = moving & (np.linalg.norm(X[idx] - goal, axis=1) <= tol)
            arrival[idx[there]] = t
            active[idx[there | ~moving | (t >= horizon[idx])]] = False
    return arrival


def starts_reach(trajs: Sequence[Trajectory], gradient: Field, goal: np.ndarray | None,
                 extent: float, owner: np.ndarray | None = None) -> dict[str, Any]:
    """Whether runs from the demonstrated starts reach the goal within :data:`REACH_TIME`
    times their demonstrations' durations.

    Parameters
    ----------
    trajs : sequence of Trajectory
        The demonstrations (state units; times in seconds, or none: one step per sample).
    gradient : callable
        The learnt potential's gradient (m, n) at states (m, n).
    goal : ndarray (n,) or None
        Where most demonstrations end (:func:`~policy_align_ros.learning.goal.
        demonstrated_goal`); None: nothing is run (several goals, no common end).
    extent : float
        The data's extent W (state units).
    owner : ndarray of int (len(trajs),), optional
        Each run's policy, as in :func:`reach_times`.

    Returns
    -------
    dict
        ``start_reach_ratios``: per demonstration, its run's arrival time over its
        duration (None when it did not arrive within :data:`REACH_TIME` of them; the
        list is None without a goal) and ``n_starts_late``, the count of those None (0
        without a goal).
    """
    if goal is None:
        return {"start_reach_ratios": None, "n_starts_late": 0}
    starts = np.array([t.positions[0] for t in trajs])
    durations = np.array([t.duration for t in trajs])
    arrival = reach_times(gradient, starts, np.asarray(goal, dtype=float),
                          REACH_TIME * durations, sample_period(trajs), GOAL_MERGE * extent,
                          owner)
    ratios = arrival / durations
    return {"start_reach_ratios": [float(r) if math.isfinite(r) else None for r in ratios],
            "n_starts_late": int(np.count_nonzero(~np.isfinite(ratios)))}

