"""The learnt goal: the learnt potential's minima beside where the demonstrations rest.

A potential-based policy ``pi(x) = -grad f(x)`` stops at the minima of ``f``. A user
wants them where the demonstrations came to rest; a fit can explain the velocities well and
still put its minimum elsewhere (human timing, tracking lag, contact), or have none (a
potential that keeps falling past the goal). This module measures that, from the data and
the learnt model only:

- :func:`rest_points`: where each demonstration comes to rest at its end (its final samples
  below ``fraction`` of its peak speed);
- the learnt potential's local minima, and where its flow from given starts stops, come
  from descents of it (:mod:`~policy_align_ros.learning.descent`);
- :func:`starts_elsewhere`: demonstrations from whose start the learnt policy stops
  somewhere else than from their end;
- :func:`goal_summary`: the learnt minima, each with its distance to the nearest
  *demonstrated goal* (a cluster of rest points), and the data's extent to read the
  distances as fractions. A rest where the learnt policy is far from zero is a rest under
  an active constraint (a hand stopped by a table), not a goal: it is left out of the
  demonstrated goals and counted;
- :func:`learnt_goal_index`: which of those minima is the learnt goal, the one a user's
  runs are meant to stop at.

Notation: ``K`` demonstrations ``X_k`` (``N_k`` x ``n``, state units) with times in seconds
(speeds in state units per second; per step without times). The *extent* ``W`` of a set
of demonstrations is the largest side of their bounding box (state units).
``docs/design/goal_report.md`` gives the reasons for the thresholds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import t as student_t

from policy_align_ros.learning.descent import (
    Field,
    Minima,
    cluster_labels,
    data_box,
    flow_stops,
    learnt_minima,
)
from policy_align_ros.learning.trajectory import Trajectory, as_trajectories

__all__ = [
    "ACTIVE_FRACTION",
    "CREEP_LEVEL",
    "GOAL_MERGE",
    "REST_FRACTION",
    "creep_limit",
    "data_extent",
    "demonstrated_goal",
    "goal_ends",
    "goal_summary",
    "learnt_goal_index",
    "rest_points",
    "sample_speeds",
    "starts_elsewhere",
    "typical_speed",
]

#: A demonstration rests where its speed is below this fraction of its peak speed.
REST_FRACTION = 0.02
#: A rest where the learnt policy's speed exceeds this fraction of the typical demonstrated
#: (peak) speed is a rest under an active constraint, not a goal.
ACTIVE_FRACTION = 0.1
#: One-sided confidence level of the lower bound on a creeping end's time constant
#: (:func:`creep_limit`; two standard errors of a normal): the limit is extrapolated only
#: as far as the run determines it.
CREEP_LEVEL = 0.977
#: Rest points, and the ends of demonstrations (:func:`demonstrated_goal`), closer than
#: this fraction of the extent are one demonstrated goal: a teacher never stops twice at
#: the same point.
GOAL_MERGE = 0.05


def sample_speeds(traj: Trajectory) -> np.ndarray:
    """Speed ``|xdot|`` at every sample, shape (N,), in state units per second (per step
    without times).

    From the recorded velocities when the trajectory has them; otherwise from finite
    differences: each sample takes the speed of the step that ends at it (the first sample
    that of the first step), so a sample counts as at rest only once it has stopped.
    """
    if traj.velocities is not None:
        return np.linalg.norm(traj.velocities, axis=1)
    step = np.linalg.norm(np.diff(traj.positions, axis=0), axis=1) / traj.dt
    return np.concatenate([step[:1], step])


def rest_points(trajs: Sequence[Trajectory | np.ndarray], fraction: float = REST_FRACTION
                ) -> list[np.ndarray | None]:
    """Where each demonstration comes to rest at its end.

    Parameters
    ----------
    trajs : sequence of Trajectory or array_like (N_k, n)
        The demonstrations (state units; times in seconds, or none: dt = 1).
    fraction : float in (0, 1)
        A sample rests when its speed (:func:`sample_speeds`) is below ``fraction`` of its
        demonstration's peak speed.

    Returns
    -------
    list of ndarray (n,) or None
        Per demonstration, the mean position of its final run of resting samples; None
        when its last sample does not rest (it ends in motion) or it never moves.
    """
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction: must be in (0, 1), got {fraction!r}")
    out: list[np.ndarray | None] = []
    for traj in as_trajectories(trajs):
        first = _final_rest(traj, fraction)
        out.append(None if first is None else traj.positions[first:].mean(axis=0))
    return out


def _final_rest(traj: Trajectory, fraction: float) -> int | None:
    """Index of the first sample of a demonstration's final run of samples below
    ``fraction`` of its peak speed; None when its last sample moves or it never moves."""
    speed = sample_speeds(traj)
    peak = float(speed.max())
    resting = speed < fraction * peak
    if peak <= 0.0 or not resting[-1]:
        return None
    moving = np.flatnonzero(~resting)
    return int(moving[-1]) + 1 if moving.size else 0


def demonstrated_goal(trajs: Sequence[Trajectory | np.ndarray],
                      radius: float = GOAL_MERGE) -> np.ndarray | None:
    """Where most demonstrations end: the goal the demonstrator meant (n,), state units,
    or None. The mean of :func:`goal_ends` of ``trajs`` and ``radius``."""
    ends = goal_ends(trajs, radius)
    return None if ends is None else ends.mean(axis=0)


def goal_ends(trajs: Sequence[Trajectory | np.ndarray], radius: float = GOAL_MERGE
              ) -> np.ndarray | None:
    """The ends of the demonstrations that end together (k, n), or None.

    Each demonstration ends at the limit of its final rest run's creep (:func:`creep_limit`)
    or, when it is still moving at its last sample (a recording cut as the goal is
    reached), at that sample.
    Trajectories of one potential-based policy end at its minima, whatever their timing; a
    constraint holds each demonstration at a minimum of its own, so ends far apart mean
    constraints (or demonstrations cut short). A teacher, though, never stops twice at
    the same point: the ends within ``radius`` extents of the end that has the most such
    neighbours are one goal, when they are more than half of the demonstrations (and at
    least two); otherwise there is none. The ends at rest are tried first, and all ends
    only when those are too few: a recording cut while it still moves shows where it was
    heading, not where it stopped, and a few such ends beside the rests would move the
    goal. A ball rather than chains of ends: a chain grows with the number of
    demonstrations, and the ends of constrained ones chain across a tenth of the extent
    and more. How far they lie from their mean is how well the demonstrations show the
    goal (:func:`~policy_align_ros.learning.anchor.anchor_decision` reads it).

    Parameters
    ----------
    trajs : sequence of Trajectory or array_like (N_k, n)
        The demonstrations (state units).
    radius : float
        Ends within ``radius`` times the extent (:func:`data_extent`) are one place.

    Returns
    -------
    ndarray (k, n) or None
        Those ends (state units).
    """
    trajs = as_trajectories(trajs)
    if len(trajs) < 2:
        return None
    rests = [_final_rest(t, REST_FRACTION) for t in trajs]
    ends = np.array([_end_point(t, first) for t, first in zip(trajs, rests, strict=True)])
    resting = np.array([first is not None for first in rests])
    scale = radius * data_extent(trajs)
    # A demonstration at rest at its end shows the goal; one still moving at its last
    # sample only heads for it: the rests decide where they are enough on their own.
    for candidates in (np.flatnonzero(resting), np.arange(len(ends))):
        best = _largest_ball(ends[candidates], scale)
        if len(best) >= 2 and 2 * len(best) > len(ends):
            return ends[candidates[best]]
    return None


def _largest_ball(points: np.ndarray, radius: float) -> np.ndarray:
    """Indices of the points within ``radius`` of the point that has the most of them
    (none for no points)."""
    if not len(points):
        return np.zeros(0, dtype=int)
    near = cKDTree(points).query_ball_point(points, radius)
    return np.asarray(max(near, key=len), dtype=int)


def _end_point(traj: Trajectory, first: int | None, tail: float = 0.1) -> np.ndarray:
    """Where a demonstration ends (n,): the :func:`creep_limit` of its final rest run,
    which starts at sample ``first`` (:func:`_final_rest`), seen from the last ``tail`` of
    the run and at most ``GOAL_MERGE`` of the demonstration's travel (start to end) from
    there, or its last sample when it ends in motion (``first`` None)."""
    if first is None:
        return traj.positions[-1]
    run = traj.n_samples - first
    velocities = traj.velocity_estimate()
    travel = float(np.linalg.norm(traj.positions[-1] - traj.positions[0]))
    return creep_limit(traj.positions[first:], velocities[first:],
                       max(1, int(math.ceil(tail * run))), GOAL_MERGE * travel)


def creep_limit(positions: np.ndarray, velocities: np.ndarray, tail: int,
                max_step: float = math.inf) -> np.ndarray:
    """Where a demonstration's final creep toward rest would stop (n,), state units.

    A flow near its minimum ``g`` slows as ``xdot = -(x - g) / c``: a robot servoing to
    its goal rests only in the limit, and a recording stops while it still creeps. The
    time constant ``c`` (s) is fitted by least squares to the run, ``x = g - c xdot``
    (demeaned, so ``g`` drops out), and the limit is seen from the run's last ``tail``
    samples: their mean position plus ``c`` times their mean velocity. Only what the run
    determines is taken: ``c`` is its one-sided lower confidence bound at level
    ``CREEP_LEVEL`` (Student's t; the standard error widened by the residuals' serial
    correlation, which a smooth model error or filtered velocities carry), at least 0,
    and the step is at most ``max_step`` long. At rest, with velocities that are noise
    (noise differenced into velocities does not correlate with the positions it came
    from, or correlates negatively), or drifting without slowing, the bound is mostly 0
    and the end the mean position (``docs/design/goal_anchor.md``, "Ends that still
    creep").

    Parameters
    ----------
    positions, velocities : numpy.ndarray, shape (m, n)
        The final rest run's samples (state units, state units per second).
    tail : int
        How many of its last samples the limit is seen from (>= 1).
    max_step : float
        The longest step from there (state units, >= 0).

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    if tail < 1:
        raise ValueError(f"tail: must be >= 1 sample, got {tail}")
    X, V = np.asarray(positions, dtype=float), np.asarray(velocities, dtype=float)
    end, v_end = X[-tail:].mean(axis=0), V[-tail:].mean(axis=0)
    dx, dv = X - X.mean(axis=0), V - V.mean(axis=0)
    dof = dx.size - X.shape[1] - 1  # the n means and the slope fitted
    spread = float(np.sum(dv * dv))
    if dof < 1 or spread <= 0.0:
        return end
    c = -float(np.sum(dx * dv)) / spread
    residual = dx + c * dv
    energy = float(np.sum(residual * residual))
    rho = float(np.sum(residual[1:] * residual[:-1])) / energy if energy > 0.0 else 0.0
    if rho >= 1.0:
        return end
    widen = math.sqrt((1.0 + rho) / (1.0 - rho)) if rho > 0.0 else 1.0
    error = widen * math.sqrt(energy / dof / spread)
    step = max(0.0, c - float(student_t.ppf(CREEP_LEVEL, dof)) * error) * v_end
    length = float(np.linalg.norm(step))
    return end + (step if length <= max_step else step * (max_step / length))


def typical_speed(trajs: Sequence[Trajectory]) -> float:
    """The median over demonstrations of their peak speed (state units per second), or 1
    when none moves."""
    return float(np.median([sample_speeds(t).max() for t in trajs])) or 1.0


def data_extent(trajs: Sequence[Trajectory | np.ndarray]) -> float:
    """The largest side of the bounding box of all samples (state units)."""
    X = np.concatenate([t.positions for t in as_trajectories(trajs)])
    return float(np.max(X.max(axis=0) - X.min(axis=0)))


def goal_summary(trajs: Sequence[Trajectory | np.ndarray], potential: Field,
                 gradient: Field, *, fraction: float = REST_FRACTION,
                 active_fraction: float = ACTIVE_FRACTION,
                 starts_check: dict[str, Any] | None = None) -> dict[str, Any]:
    """The learnt minima beside the demonstrated goals, as JSON-able numbers.

    Parameters
    ----------
    trajs : sequence of Trajectory or array_like (N_k, n)
        The demonstrations the model was fitted on (state units, times in seconds).
    potential, gradient : callable
        The learnt potential (m,) and its gradient (m, n) at states (m, n).
    fraction : float
        Rest threshold of :func:`rest_points`.
    active_fraction : float
        A rest where the learnt speed ``|grad f|`` exceeds ``active_fraction`` times the
        typical speed (the median of the demonstrations' peak speeds) is a rest under an
        active constraint: not a demonstrated goal.
    starts_check : dict, optional
        :func:`starts_elsewhere` of these demonstrations and this potential, when the
        caller has computed it already (the goal anchor's choice of direction weight).

    Returns
    -------
    dict
        ``extent`` (W, state units); ``typical_speed`` (state units/s); ``n_rests``
        (demonstrations that end at rest), ``n_not_at_rest``, ``n_constrained_rests``;
        ``n_rest_places``: the rests chained closer than :data:`GOAL_MERGE` of W as one
        place, constrained or not, and ``rest_spread_fraction``, the largest distance
        between two places over W (0 for one place or none);
        ``rest_speed_ratio`` (learnt speed over the typical speed at every rest);
        ``demonstrated_goals`` [{``point``, ``n_rests``, ``nearest_minimum``,
        ``fraction``}] (largest cluster first; ``nearest_minimum`` is the distance to the
        nearest learnt minimum, None without minima, ``fraction`` that over W);
        ``minima`` [{``point``, ``potential``, ``goal_distance``, ``goal_fraction``,
        ``end_distance``, ``end_fraction``, ``data_distance``, ``data_fraction``}]
        (distance to the nearest demonstrated goal, None without goals; the median
        distance to the demonstrations' last samples, which is all there is when they do
        not come to rest; the distance to the nearest sample: how far the fit
        extrapolated);
        ``n_escaped`` (descents that found no minimum); ``goal_error`` and
        ``goal_error_fraction``: the largest demonstrated goal's ``nearest_minimum`` (None
        without goals or minima); ``n_starts_elsewhere``, ``n_starts_escaped`` and
        ``starts_elsewhere_fraction`` (:func:`starts_elsewhere`).
    """
    trajs = as_trajectories(trajs)
    if not 0.0 < active_fraction:
        raise ValueError(f"active_fraction: must be positive, got {active_fraction!r}")
    extent = data_extent(trajs) or 1.0
    speed = typical_speed(trajs)
    rests = rest_points(trajs, fraction)
    found = [r for r in rests if r is not None]
    ratios = (np.linalg.norm(gradient(np.array(found)), axis=1) / speed if found
              else np.zeros(0))
    goals = [r for r, ratio in zip(found, ratios, strict=True) if ratio <= active_fraction]
    X = np.concatenate([t.positions for t in trajs])
    ends = np.array([t.positions[-1] for t in trajs])
    starts = np.concatenate([np.array(found).reshape(-1, X.shape[1]), ends])
    minima = learnt_minima(potential, gradient, starts, scale=extent, speed=speed,
                           bounds=data_box(X, extent))
    goal_points, goal_sizes = _goal_clusters(goals, GOAL_MERGE * extent)
    # Every rest, whatever the learnt speed there: where the teacher stopped. Places apart
    # are a sign the learnt speed cannot give when the fit is wrong at all of them.
    places, _ = _goal_clusters(found, GOAL_MERGE * extent)
    rest_spread = (float(np.max(np.linalg.norm(places[:, None] - places[None], axis=2)))
                   if len(places) > 1 else 0.0)
    summary: dict[str, Any] = {
        "extent": extent,
        "typical_speed": speed,
        "rest_fraction": fraction,
        "n_rests": len(found),
        "n_not_at_rest": len(rests) - len(found),
        "n_constrained_rests": len(found) - len(goals),
        "n_rest_places": len(places),
        "rest_spread_fraction": rest_spread / extent,
        "rest_speed_ratio": [float(r) for r in ratios],
        "demonstrated_goals": [],
        "minima": [],
        "n_escaped": int(minima.n_escaped),
    }
    for g, size in zip(goal_points, goal_sizes, strict=True):
        d = _nearest(minima.points, g)
        summary["demonstrated_goals"].append({
            "point": [float(v) for v in g], "n_rests": int(size), "nearest_minimum": d,
            "fraction": None if d is None else d / extent})
    summary["minima"] = _minima_entries(minima, goal_points, ends, X, extent)
    first = summary["demonstrated_goals"][:1]
    summary["goal_error"] = first[0]["nearest_minimum"] if first else None
    summary["goal_error_fraction"] = first[0]["fraction"] if first else None
    summary.update(starts_elsewhere(trajs, potential, gradient, extent, speed)
                   if starts_check is None else starts_check)
    return summary


def learnt_goal_index(goal: Mapping[str, Any]) -> int | None:
    """Which of a goal report's minima is the learnt goal: where runs of the policy are
    meant to stop.

    The minimum nearest to the largest demonstrated goal (where most demonstrations rest);
    without one, the minimum nearest to where the demonstrations end (the median distance
    of their last samples), not the lowest: a minimum the fit extrapolated far from the
    data can be lower than the one every demonstration leads to.

    Parameters
    ----------
    goal : mapping
        :func:`goal_summary`'s report (``minima``, ``demonstrated_goals``), as a fit
        summary or a model file holds it.

    Returns
    -------
    int or None
        Index into ``goal["minima"]`` (lowest first); None when there is no minimum. A
        report whose minima lack a ``point`` or an ``end_distance`` (written by an older
        version) gets the lowest.
    """
    minima = goal.get("minima") or []
    if not minima:
        return None
    rests = goal.get("demonstrated_goals") or []
    if rests and all("point" in m for m in minima):
        points = np.array([m["point"] for m in minima], dtype=float)
        target = np.asarray(rests[0]["point"], dtype=float)
        return int(np.argmin(np.linalg.norm(points - target, axis=1)))
    # A report written before minima carried their distance to the ends: the lowest.
    ends = np.array([m.get("end_distance", math.inf) for m in minima], dtype=float)
    return int(np.argmin(ends)) if np.isfinite(ends).any() else 0


def starts_elsewhere(trajs: Sequence[Trajectory], potential: Field, gradient: Field,
                     extent: float, speed: float) -> dict[str, Any]:
    """Demonstrations from whose start the learnt policy stops where no demonstration's
    end leads.

    Every demonstration's first and last samples are descended
    (:func:`~policy_align_ros.learning.descent.flow_stops`: in :func:`~policy_align_ros.
    learning.descent.learnt_minima`'s box, with steps of at most ``END_RADIUS`` of the
    extent, so that the descent follows the policy's flow instead of leaping into another
    basin). A start counts when its
    descent ends more than ``GOAL_MERGE`` of the extent from where every end's descent
    ends, or leaves the box while some end's does not: a run of the learnt policy from
    there stops at a minimum the demonstrations never stopped at (a path that loops or
    crosses itself, which no potential's gradient follows), or never stops. Several
    goals are fine (each end leads to its own minimum), and so is a rest under a
    constraint (both descents are free). Where most demonstrations end together
    (:func:`demonstrated_goal`), that place is the only one a start may lead to.

    Parameters
    ----------
    trajs : sequence of Trajectory
    potential, gradient : callable
    extent, speed : float
        The data's extent W (state units) and typical speed (state units/s).

    Returns
    -------
    dict
        ``n_starts_elsewhere`` (int), ``n_starts_escaped`` (those of them whose start's
        descent left the box), ``starts_elsewhere_fraction`` (over W, the largest distance
        from a counted start's stop to the nearest end's stop; None when there is none).
    """
    X = np.concatenate([t.positions for t in trajs])
    both = np.concatenate([[t.positions[0] for t in trajs], [t.positions[-1] for t in trajs]])
    out, inside = flow_stops(potential, gradient, both, X, extent, speed)
    K = len(trajs)
    start, end = out[:K], out[K:]
    reached = end[inside[K:]]
    goal = demonstrated_goal(trajs)
    if goal is not None:
        # Most demonstrations end together: runs should stop there, not wherever an end
        # next to it slides (the goal anchor makes the goal stationary, not a minimum).
        reached = goal[None]
    if not len(reached):
        return {"n_starts_elsewhere": 0, "n_starts_escaped": 0,
                "starts_elsewhere_fraction": None}
    gap = cKDTree(reached).query(start)[0] / extent
    gap[~inside[:K]] = math.inf
    counted = gap > GOAL_MERGE
    stopped = counted & np.isfinite(gap)
    return {"n_starts_elsewhere": int(counted.sum()),
            "n_starts_escaped": int(np.count_nonzero(counted & ~stopped)),
            "starts_elsewhere_fraction": (float(np.max(gap[stopped])) if stopped.any()
                                          else None)}


def _goal_clusters(goals: list[np.ndarray], tol: float) -> tuple[np.ndarray, list[int]]:
    """Rest points chained closer than ``tol`` as one goal: the clusters' means, largest
    cluster first, and their sizes."""
    if not goals:
        return np.zeros((0, 0)), []
    P = np.array(goals)
    labels = cluster_labels(P, tol)
    sizes = np.bincount(labels)
    order = np.argsort(-sizes, kind="stable")
    return np.array([P[labels == c].mean(axis=0) for c in order]), [int(sizes[c])
                                                                   for c in order]


def _minima_entries(minima: Minima, goal_points: np.ndarray, ends: np.ndarray,
                    X: np.ndarray, extent: float) -> list[dict[str, Any]]:
    """:func:`goal_summary`'s ``minima``: each learnt minimum's point and potential, and
    its distances (state units, and over ``extent``) to the nearest demonstrated goal of
    ``goal_points``, to the demonstrations' last samples ``ends`` (median) and to the
    nearest sample of ``X``: how far the fit extrapolated to place it."""
    out = []
    for p, v in zip(minima.points, minima.values, strict=True):
        d, near = _nearest(goal_points, p), _nearest(X, p)
        end = float(np.median(np.linalg.norm(ends - p, axis=1)))
        out.append({
            "point": [float(c) for c in p], "potential": float(v), "goal_distance": d,
            "goal_fraction": None if d is None else d / extent,
            "end_distance": end, "end_fraction": end / extent,
            "data_distance": near, "data_fraction": near / extent})
    return out


def _nearest(points: np.ndarray, x: np.ndarray, block: int = 65536) -> float | None:
    """Distance from ``x`` to the nearest of ``points`` (None when there are none), in
    blocks of ``block`` points: they may be every sample of a large data set, where one
    difference array would cost hundreds of MB (and a KD-tree's build seconds)."""
    if not len(points):
        return None
    return float(min(np.min(np.linalg.norm(points[s:s + block] - x, axis=1))
                     for s in range(0, len(points), block)))
