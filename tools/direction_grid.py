"""How the goal anchor's direction weight was chosen: every weight fitted on the LASA tuning
shapes (leave one out), and each grid's rule applied afterwards.

For every tuning shape and held-out demonstration, ``PolicyAlign`` is fitted once per
weight of ``--weights`` (``TrendKernelRegression(direction_weight=w)``), and the fit's
``n_starts_elsewhere`` (its training starts that do not reach the goal), whether the goal
is a strict minimum of its potential, the held-out nV and whether the held-out rollout
converged (the bench's measures) are recorded. A grid's rule, the one
``direction_weight="auto"`` applies, takes the largest weight of the grid with no start
elsewhere and a minimum at the goal, else the smallest; its nV (median over shapes) and converged
share are printed per grid (``docs/design/goal_anchor.md``).

    python tools/direction_grid.py --jobs 2                       # 5-10 min on 2 cores
    python tools/direction_grid.py --weights 10,300,3000 --shapes Angle,Sine
"""

from __future__ import annotations

import argparse
import itertools
import sys
import warnings

import numpy as np

from policy_align_ros.experiments import lasa
from policy_align_ros.experiments.lasa_metrics import (
    converged,
    euler_rollout,
    velocity_error,
    workspace_size,
)
from policy_align_ros.experiments.pool import parallel_map
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.regressors import TrendKernelRegression
from policy_align_ros.learning.regressors.trend_kernel.model import DIRECTION_WEIGHTS


def _task(task: tuple[str, int, tuple[float, ...]]) -> list[dict]:
    """One shape with one demonstration held out, fitted at every weight."""
    name, k, weights = task
    demos = lasa.load_shape(name)
    width = workspace_size([d["positions"] for d in demos])
    train = lasa._training(demos, [j for j in range(len(demos)) if j != k], lasa.SUBSAMPLE)
    held = demos[k]
    dt = float(np.median(np.diff(held["times"])))
    steps = int(round(lasa.ROLLOUT_DURATIONS * (held["times"][-1] - held["times"][0]) / dt))
    rows = []
    for w in weights:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = PolicyAlign(random_state=0, regressor=TrendKernelRegression(
                random_state=0, direction_weight=w)).fit(train)
        end = euler_rollout(model.policy, held["positions"][0], dt, steps)[-1]
        rows.append({"shape": name, "demo": k, "weight": w,
                     "elsewhere": model.fit_summary_["goal"]["n_starts_elsewhere"],
                     # An unanchored fit keeps the paper's potential, whose minimum is there.
                     "minimum": model.fit_summary_["anchor"].get("goal_is_minimum", True),
                     "nV": velocity_error(model.policy(held["positions"]), held["velocities"]),
                     "converged": converged(end, np.zeros(2), width)})
    return rows


def _rule(rows: list[dict], grid: tuple[float, ...]) -> dict:
    """The row the grid's rule keeps: the largest weight with no start elsewhere and a
    minimum at the goal, else the smallest."""
    tried = sorted((r for r in rows if r["weight"] in grid), key=lambda r: -r["weight"])
    return next((r for r in tried if r["elsewhere"] == 0 and r["minimum"]), tried[-1])


def _summary(kept: list[dict]) -> str:
    shapes = sorted({r["shape"] for r in kept})
    nv = np.median([np.mean([r["nV"] for r in kept if r["shape"] == s]) for s in shapes])
    conv = 100.0 * np.mean([r["converged"] for r in kept])
    return f"nV {nv:.3f}, converged {conv:.1f} %"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", default=",".join(f"{w:g}" for w in DIRECTION_WEIGHTS),
                        help="comma-separated direction weights (default: the ladder's)")
    parser.add_argument("--shapes", default="tuning")
    parser.add_argument("--jobs", type=int, default=1)
    args = parser.parse_args(argv)
    weights = tuple(sorted(float(w) for w in args.weights.split(",")))
    tasks = [(name, k, weights) for name in lasa.select_shapes(args.shapes)
             for k in range(len(lasa.load_shape(name)))]
    fits = parallel_map(_task, tasks, args.jobs, "direction grid")
    print(f"{len(fits)} fits, leave one out")
    for w in weights:
        kept = [r for rows in fits for r in rows if r["weight"] == w]
        flagged = [r for r in kept if r["elsewhere"]]
        missed = [r for r in kept if not r["converged"]]
        print(f"weight {w:g}: {_summary(kept)}; {len(flagged)} fits with a start elsewhere, "
              f"{len(missed)} held-out rollouts not converged, "
              f"{sum(1 for r in missed if r['elsewhere'])} of them among those fits")
    for size in range(2, len(weights) + 1):
        for grid in itertools.combinations(weights, size):
            kept = [_rule(rows, grid) for rows in fits]
            picks = {f"{w:g}": sum(r["weight"] == w for r in kept) for w in grid}
            print(f"rule over {'/'.join(f'{w:g}' for w in grid)}: {_summary(kept)}; "
                  f"kept {picks}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
