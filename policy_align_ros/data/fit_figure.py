"""A figure of one fit, for the user who recorded the demonstrations
(``policy-align learn --plot FIG.png``).

The fit's numbers (``fit_summary_``, the learn summary) say whether it warned; the figure
shows where the model and the demonstrations part. Four panels:

1. **The potential along each demonstration**: the estimate the model was fitted to
   (``aligned_potentials_``) and the learnt potential, each demonstration shifted by its
   best constant (the CV scores shapes, not levels). A demonstration whose learnt curve
   leaves its estimate was not followed: a teacher's own timing, a contact, a path
   that loops.
2. **Runs of the learnt policy from the demonstrated starts**: the distance to the
   goal over time, beside the demonstration's own, in units of its duration. A run
   from a held-out start is a run from a start the fit never saw. A run that leaves the
   data's box widened by its extent stops there (a policy that diverges).
3. **Held-out error per CV fold** over a zero policy's, on a log scale: 1 is no better
   than standing still (the learner refuses it), 0.5 the poor-fit warning.
4. **The states** (their first two principal directions): the demonstrations, the runs,
   the learnt minima and the demonstrated goal.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from policy_align_ros.learning.descent import data_box
from policy_align_ros.learning.folds import POOR_FIT_RATIO
from policy_align_ros.learning.goal import (
    GOAL_MERGE,
    data_extent,
    demonstrated_goal,
    learnt_goal_index,
)
from policy_align_ros.learning.model_io import atomic_write_bytes
from policy_align_ros.learning.reach import MAX_REACH_STEPS, REACH_TIME
from policy_align_ros.learning.trajectory import Trajectory, sample_period

__all__ = ["FIGURE_FORMATS", "figure_format", "fit_views", "plot_fit", "policy_runs"]

#: Distances below this fraction of the extent are drawn at it (the runs' panel).
FLOOR = 1e-3
#: Points drawn per demonstration's estimate and per run's path, at most about.
DOTS = 100
#: Demonstrations the potential panel's legend names (the first ones).
LEGEND_DEMOS = 8
#: The formats :func:`plot_fit` writes, named by the path's suffix.
FIGURE_FORMATS = ("png", "pdf", "svg")


def policy_runs(policy, starts: np.ndarray, horizon: float, dt: float,
                bounds: tuple[np.ndarray, np.ndarray] | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Explicit Euler runs of ``xdot = policy(x)`` from every start at once.

    Parameters
    ----------
    policy : callable
        ``policy(X)`` (m, n) at states ``X`` (m, n), state units per second.
    starts : ndarray (m, n)
        State units.
    horizon : float
        Duration of the runs (s); at most :data:`~policy_align_ros.learning.reach.
        MAX_REACH_STEPS` steps, longer than ``dt`` when needed (as the goal report's runs).
    dt : float
        Step (s), the demonstrations' sample period.
    bounds : (lower (n,), upper (n,)), optional
        A box, state units (the data's box widened by its extent, :func:`~policy_align_ros.
        learning.descent.data_box`, as the goal report's descents): a run that would leave
        it stops where it was. Without it a diverging policy's runs reach 1e300 and more,
        and the figure's axes show nothing else.

    Returns
    -------
    times : ndarray (steps + 1,)
        Seconds from the start, 0 first.
    states : ndarray (steps + 1, m, n)
        The runs' states, the starts first; a run that leaves the finite numbers, or
        ``bounds``, stops where it was.
    """
    dt = max(dt, horizon / MAX_REACH_STEPS)
    steps = max(1, int(math.ceil(horizon / dt)))
    X = np.array(starts, dtype=float)
    out = np.empty((steps + 1, *X.shape))
    out[0] = X
    moving = np.ones(len(X), dtype=bool)
    with np.errstate(over="ignore", invalid="ignore"):
        for i in range(steps):
            step = X + dt * policy(X)
            ok = np.isfinite(step).all(axis=1)
            if bounds is not None:
                ok &= np.all((step >= bounds[0]) & (step <= bounds[1]), axis=1)
            moving &= ok
            X = np.where(moving[:, None], step, X)
            out[i + 1] = X
    return dt * np.arange(steps + 1), out


def fit_views(model, train: Sequence[Trajectory], held: Sequence[Trajectory] = ()
              ) -> dict[str, Any]:
    """What :func:`plot_fit` draws, computed.

    Parameters
    ----------
    model : PolicyAlign
        Fitted on ``train``.
    train, held : sequences of Trajectory
        The training demonstrations (in the order given to ``fit``) and held-out ones,
        state units, times in seconds.

    Returns
    -------
    dict
        ``potential``: per training demonstration the model aligned, ``(k, s, estimate,
        learnt)`` with ``s`` its normalised time (N_k,) in [0, 1] and both potentials
        (N_k,) shifted to a mean of 0; ``runs``: per start (training, then held out),
        ``{"held": bool, "t": (S,) run time over the demonstration's duration,
        "run": (S,) and "demo_t", "demo": (N_k,) distances to the goal over the extent}``;
        ``goal`` (n,) or None, where most demonstrations end (:func:`~policy_align_ros.
        learning.goal.demonstrated_goal`); ``measured_to``: what the distances are to,
        the demonstrated goal, else the learnt goal (:func:`~policy_align_ros.learning.goal.
        learnt_goal_index`), else each demonstration's end;
        ``extent`` (state units); ``minima`` (k, n); ``new_start_minima`` (j, n), where
        runs from new starts near the data stop instead of the goal; ``fold_ratios`` (list);
        ``basis``: ``(mean (n,), P (2, n))``, the states' first two principal directions;
        ``paths`` (S, m, n): the runs' states.
    """
    trajs = list(train) + list(held)
    extent = data_extent(trajs) or 1.0
    goal = demonstrated_goal(train)
    potential = []
    for k in model.inliers_:
        t, estimate = train[k], model.aligned_potentials_[k]
        learnt = model.potential(t.positions)
        s = np.linspace(0.0, 1.0, t.n_samples)
        potential.append((int(k), s, estimate - estimate.mean(), learnt - learnt.mean()))
    summary = model.fit_summary_ or {}
    goal_report = summary.get("goal") or {}
    minima, beside = (np.array([m["point"] for m in goal_report.get(key) or []],
                               dtype=float).reshape(-1, trajs[0].n_dims)
                      for key in ("minima", "new_start_minima"))
    # Where a run should go: the demonstrated goal; without one (every demonstration rests
    # under its own constraint), the learnt goal, the minimum nearest where they end.
    target, measured_to = goal, "the demonstrated goal"
    if target is None and len(minima):
        target, measured_to = minima[learnt_goal_index(goal_report)], "the learnt goal"
    X = np.concatenate([t.positions for t in trajs])
    times, paths = policy_runs(model.policy, np.array([t.positions[0] for t in trajs]),
                               REACH_TIME * max(t.duration for t in trajs),
                               sample_period(trajs), bounds=data_box(X, extent))
    runs = []
    for k, t in enumerate(trajs):
        end = target if target is not None else t.positions[-1]
        elapsed = np.arange(t.n_samples) if t.times is None else t.times - t.times[0]
        runs.append({"held": k >= len(train),
                     "t": times / t.duration,
                     "run": np.linalg.norm(paths[:, k] - end, axis=1) / extent,
                     "demo_t": elapsed / t.duration,
                     "demo": np.linalg.norm(t.positions - end, axis=1) / extent})
    mean = X.mean(axis=0)
    basis = np.linalg.svd(X - mean, full_matrices=False)[2][:2]
    ratios = (summary.get("heldout_vs_zero") or {}).get("fold_ratios") or []
    return {"potential": potential, "runs": runs, "goal": goal, "extent": extent,
            "measured_to": measured_to if target is not None else "each demonstration's end",
            "minima": minima, "new_start_minima": beside,
            "fold_ratios": [math.nan if r is None else float(r) for r in ratios],
            "basis": (mean, basis), "paths": paths}


def figure_format(path: str | Path) -> str:
    """The format the suffix of ``path`` names, one of :data:`FIGURE_FORMATS` (no suffix:
    ``"png"``); ValueError naming the path otherwise."""
    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    if fmt not in FIGURE_FORMATS:
        raise ValueError(f"{path}: no figure format {fmt!r}; name a "
                         f"{', '.join('.' + f for f in FIGURE_FORMATS)} file")
    return fmt


def plot_fit(model, train: Sequence[Trajectory], path: str | Path,
             held: Sequence[Trajectory] = (), dpi: int = 120) -> Path:
    """Draw :func:`fit_views` into ``path`` (written whole or not at all), in the format its
    suffix names (``.png``, ``.pdf``, ``.svg``; none: PNG).

    Parameters
    ----------
    model : PolicyAlign
        Fitted on ``train``.
    train, held : sequences of Trajectory
        As in :func:`fit_views`.
    path : str or Path
        The figure (parents created).
    dpi : int
        Its resolution.

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        A suffix of none of :data:`FIGURE_FORMATS` (:func:`figure_format`), before anything
        is computed.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fmt = figure_format(path)
    views = fit_views(model, train, held)
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    _potential_panel(axes[0, 0], views, colors)
    _runs_panel(axes[0, 1], views, colors)
    _folds_panel(axes[1, 0], views)
    _states_panel(axes[1, 1], views, train, held, colors)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=dpi, format=fmt)
    plt.close(fig)
    return atomic_write_bytes(path, lambda fh: fh.write(buffer.getvalue()))


def _potential_panel(ax, views: dict, colors: list[str]) -> None:
    for i, (k, s, estimate, learnt) in enumerate(views["potential"]):
        color = colors[i % len(colors)]
        every = max(1, len(s) // DOTS)
        ax.plot(s[::every], estimate[::every], ".", ms=2, color=color, alpha=0.5)
        ax.plot(s, learnt, "-", lw=1, color=color,
                label=f"demo {k}" if i < LEGEND_DEMOS else None)
    ax.set_xlabel("time along the demonstration (normalised)")
    ax.set_ylabel("potential, each shifted to mean 0")
    ax.set_title("The potential along each demonstration:\nestimate (dots), learnt (lines)",
                 fontsize=9)
    n = len(views["potential"])
    if n:
        ax.legend(fontsize=7, ncol=2,
                  title=f"first {LEGEND_DEMOS} of {n}" if n > LEGEND_DEMOS else None,
                  title_fontsize=7)


def _runs_panel(ax, views: dict, colors: list[str]) -> None:
    for k, run in enumerate(views["runs"]):
        color = colors[k % len(colors)]
        width = 2.0 if run["held"] else 0.8
        ax.plot(run["t"], np.maximum(run["run"], FLOOR), "-", lw=width, color=color)
        ax.plot(run["demo_t"], np.maximum(run["demo"], FLOOR), ":", lw=width, color=color)
    ax.axhline(GOAL_MERGE, color="k", lw=0.8, ls="--")
    ax.set_yscale("log")
    ax.set_xlim(0.0, REACH_TIME)
    ax.set_ylim(bottom=0.5 * FLOOR)
    ax.set_xlabel("time over the demonstration's duration")
    ax.set_ylabel(f"distance to {views['measured_to']}\nover the data's extent")
    ax.set_title("Runs of the learnt policy (solid) and the demonstrations (dotted);\n"
                 "bold: from held-out starts; below the dashed line: arrived", fontsize=9)


def _folds_panel(ax, views: dict) -> None:
    ratios = views["fold_ratios"]
    if ratios:
        ax.bar(np.arange(len(ratios)), ratios, color="tab:blue")
    ax.axhline(1.0, color="tab:red", lw=1, label="no better than a zero policy")
    ax.axhline(POOR_FIT_RATIO, color="tab:orange", lw=1, ls="--", label="poor-fit warning")
    # A good fit's ratios are 1e-4 and less: on a linear axis its bars would not show.
    ax.set_yscale("log")
    ax.set_xlabel("CV fold")
    ax.set_ylabel("held-out error / zero policy's")
    ax.set_title("Held-out error along the observed motion, per CV fold", fontsize=9)
    ax.legend(fontsize=7)


def _states_panel(ax, views: dict, train, held, colors: list[str]) -> None:
    mean, P = views["basis"]
    project = (lambda X: (np.atleast_2d(X) - mean) @ P.T) if P.shape[0] == 2 else (
        lambda X: np.column_stack([(np.atleast_2d(X) - mean) @ P.T,
                                   np.zeros(len(np.atleast_2d(X)))]))
    for k, t in enumerate(list(train) + list(held)):
        color = colors[k % len(colors)]
        width = 2.0 if k >= len(train) else 0.8
        ax.plot(*project(t.positions).T, ":", lw=width, color=color)
        run = views["paths"][:, k]
        ax.plot(*project(run[::max(1, len(run) // DOTS)]).T, "-", lw=width, color=color,
                alpha=0.8)
        ax.plot(*project(t.positions[0]).T, "o", ms=3, color=color)
    if len(views["minima"]):
        ax.plot(*project(views["minima"]).T, "kx", ms=9, mew=2, label="learnt minima")
    if len(views["new_start_minima"]):
        ax.plot(*project(views["new_start_minima"]).T, "x", color="tab:red", ms=7, mew=1.5,
                label="minima where new starts stop")
    if views["goal"] is not None:
        ax.plot(*project(views["goal"]).T, "*", color="gold", mec="k", ms=14,
                label="demonstrated goal")
    ax.set_xlabel("first principal direction")
    ax.set_ylabel("second principal direction")
    ax.set_title("States: demonstrations (dotted), runs (solid)", fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)

