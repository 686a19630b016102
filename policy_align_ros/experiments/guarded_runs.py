"""Closed-loop runs as the executor's extrapolation guard lets them go: each one reaches
the expert's end, is held at the data's edge (which the executor reports), is flagged by
its check of the CV folds' stops, or misses silently.

The suite's closed-loop columns run the bare policy. On the robot the executor's
extrapolation guard (:mod:`policy_align_ros.control.guard`) scales down commands that lead
away from the demonstrated data and holds the robot at the data's edge, reporting the hold
on ``/diagnostics`` (:mod:`policy_align_ros.control.guard_hold`). What a user sees of a
run from a new start is therefore one of four outcomes.

Each guarded run lasts :data:`SETTLE_HORIZONS` times the expert's horizon (the steps the
expert takes to get within 1 % of its end), so that a run still slowing into the guard's
hold, or arriving late, has settled; how far a run gets within the expert's own horizon
is the suite's ``end/start`` column. The outcomes:

* **reached**: the guarded run ends within :data:`REACH_TOLERANCE` of its start distance
  from where the expert ends;
* **held**: it does not, and the guard holds its command at the end (scale at most
  :data:`~policy_align_ros.control.guard_hold.HOLD_SCALE`): the executor says so;
* **flagged**: neither, but the check of the run before it starts
  (:func:`~policy_align_ros.learning.fold_stops.stop_spread`: the CV folds' models stop
  it more than :data:`~policy_align_ros.learning.fold_stops.STOP_SPREAD_LIMIT` of its
  travel from the model's stop) says that its stop is uncertain;
* **silent**: none of these: the robot settles, crawls on under a guard that slows it, or
  is still on its way, somewhere the user was not warned about.

A run that reaches the goal and was flagged is a false alarm; the suite counts those too.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from policy_align_ros.control.guard import (
    DEFAULT_MAX_EXTRAPOLATION_RAD,
    ExtrapolationGuard,
    SupportDistance,
)
from policy_align_ros.control.guard_hold import HOLD_SCALE
from policy_align_ros.learning.fold_stops import settle

__all__ = ["OUTCOMES", "REACH_TOLERANCE", "SETTLE_HORIZONS", "default_guard", "guard_table",
           "guarded_rollout", "relative_end", "run_outcome"]

#: A run reaches the expert's end within this share of its start distance (the closed-loop
#: target of the real-recording cases).
REACH_TOLERANCE = 0.02
#: A guarded run lasts this many times the expert's horizon (as the LASA rollouts last 3
#: demonstration durations).
SETTLE_HORIZONS = 3
#: The outcomes of :func:`run_outcome`, in report order.
OUTCOMES = ("reached", "held", "flagged", "silent")


def guarded_rollout(policy: Callable[[np.ndarray], np.ndarray],
                    guard: ExtrapolationGuard | None,
                    x0: np.ndarray, dt: float, steps: int,
                    project: Callable[[np.ndarray, int, np.ndarray], np.ndarray] | None
                    ) -> tuple[np.ndarray, float]:
    """Explicit Euler of the policy, guarded or bare
    (:func:`~policy_align_ros.learning.fold_stops.settle`, the guard after the projection).

    Parameters
    ----------
    policy : callable
        ``policy(X (1, n)) -> (1, n)``, state units per s.
    guard : ExtrapolationGuard or None
        None: the bare policy. Else applied as the executor applies it, after the
        projection, without the executor's velocity and acceleration limits: they widen
        the guard's band, not its edge, wherever the data's spacing is above about
        0.07 rad (0.5 rad cap, 7 joints at the default 0.5 rad/s and 2 rad/s^2).
    x0 : ndarray (n,)
        Start, state units (rad for a joint-space model).
    dt : float
        Step, s.
    steps : int
        Number of steps.
    project : callable or None
        ``project(x (n,), i, v (n,)) -> (n,)``: the constraint's projection of the command
        at step ``i`` (None: free).

    Returns
    -------
    end : ndarray (n,)
        The state after ``steps`` steps.
    scale : float
        The guard's scale at the last step (1: not scaled).
    """
    inf = np.full(len(x0), np.inf)
    last = [1.0]  # the guard's scale at the last step

    def command(x: np.ndarray, i: int, v: np.ndarray) -> np.ndarray:
        if project is not None:
            v = project(x, i, v)
        if guard is not None:
            last[0], _ = guard.scale(x, v, inf, None)
            v = last[0] * v
        return v

    return settle(policy, x0, dt, steps, command), last[0]


def relative_end(end: np.ndarray, x0: np.ndarray, goal: np.ndarray) -> float:
    """How far a run from ``x0`` (n,) ended at ``end`` (n,) from where the expert ends,
    ``goal`` (n,), over its start distance."""
    return float(np.linalg.norm(end - goal)) / max(float(np.linalg.norm(x0 - goal)), 1e-12)


def run_outcome(end: np.ndarray, scale: float, x0: np.ndarray, goal: np.ndarray,
                flagged: bool = False) -> str:
    """One of :data:`OUTCOMES` (see the module's docstring) for a guarded run from ``x0``
    (n,) that ended at ``end`` (n,) with the guard's last ``scale``, where the expert ends
    at ``goal`` (n,); ``flagged``: its fold-stop check found the stop uncertain."""
    start = max(float(np.linalg.norm(x0 - goal)), 1e-12)
    if float(np.linalg.norm(end - goal)) <= REACH_TOLERANCE * start:
        return "reached"
    if scale <= HOLD_SCALE:
        return "held"
    return "flagged" if flagged else "silent"


def default_guard(model, max_extrapolation_rad: float = DEFAULT_MAX_EXTRAPOLATION_RAD
                  ) -> ExtrapolationGuard:
    """The executor's guard at its default parameters for ``model`` learnt on joint
    positions (its states taken as rad), with the cap ``max_extrapolation_rad`` (rad)."""
    return ExtrapolationGuard(SupportDistance(model),
                              max_extrapolation_rad=max_extrapolation_rad)


def guard_table(results: list[dict], order: list[str]) -> list[str]:
    """Markdown lines of the suite's guarded runs (``results`` of ``suite.run_case``, cases
    in ``order``): per case, the new model's runs reached-held-flagged-silent per data set,
    in seed order, how many runs that reached were flagged (false alarms), where its
    silent runs end (over their start distance: median and largest over the data sets)
    and its fit's warnings per data set."""
    rows = [r for r in results if "free_outcomes" in r["models"]["new"]]
    if not rows:
        return []
    caps = sorted({r.get("guard_rad", DEFAULT_MAX_EXTRAPOLATION_RAD) for r in rows})
    lines = ["", "Runs from new starts under the executor's extrapolation guard, capped at "
             + "/".join(f"{c:g}" for c in caps) + " rad, and their fold-stop check (new "
             "model; per data set, in seed order):", "",
             "| case | free runs reached-held-flagged-silent | unseen runs reached-held-"
             "flagged-silent | reached but flagged, free/unseen | silent free runs end "
             "(median, largest) | silent unseen runs end | fit warnings |",
             "|---|---|---|---|---|---|---|"]
    for name in order:
        mine = sorted((r for r in rows if r["case"] == name), key=lambda r: r["seed"])
        if not mine:
            continue
        new = [r["models"]["new"] for r in mine]
        cells = ["/".join("-".join(str(c) for c in m[f"{label}_outcomes"]) for m in new)
                 for label in ("free", "unseen")]
        cells.append("/".join(str(sum(m.get(f"{label}_reached_flagged", 0) for m in new))
                              for label in ("free", "unseen")))
        for label in ("free", "unseen"):
            ends = [e for m in new for e in m[f"{label}_silent_rel"]]
            cells.append(f"{np.median(ends):.3f} ({max(ends):.3f})" if ends else "-")
        cells.append("/".join(str(r.get("fit_warnings", "-")) for r in mine))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines
