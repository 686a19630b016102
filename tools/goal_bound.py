"""How well the global model could place a suite case's minimum: the default fit's learnt
minimum against the same model fitted to the expert's true potential values at the same
training samples (no potential estimate and no alignment: the regression alone, with its
own cross-validation), and how close the training data came to the true minimum.

Each row is one seed's data set as ``policy-align bench suite --cases NAME`` draws it:

    python tools/goal_bound.py --cases arm_task_7,bumps_2,bumps_noisy_6 \
        --seeds 1000,1001,1002 --jobs 2
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

from policy_align_ros.experiments import suite
from policy_align_ros.experiments.pool import parallel_map
from policy_align_ros.experiments.retiming import learnt_minimum
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.regressors import TrendKernelRegression


class _AsPolicy:
    """A fitted regressor seen as a policy (``learnt_minimum`` descends ``potential``)."""

    def __init__(self, regressor) -> None:
        self.potential = regressor.predict
        self.policy = lambda X: -regressor.gradient(X)


def _row(task: tuple[str, int]) -> dict:
    name, seed = task
    rng = np.random.default_rng(seed)
    problem = suite.ALL_CASES[name].make(rng)
    train, _, masks = suite.draw_data_set(problem, rng)
    X = np.concatenate([d.trajectory.positions[m] for d, m in zip(train, masks, strict=True)])
    groups = np.repeat(np.arange(len(train)), [int(m.sum()) for m in masks])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the fits' own warnings are not what is measured
        model = PolicyAlign(sigma=problem.sigma, random_state=seed).fit(
            [d.trajectory for d in train], train_mask=masks)
        true = _AsPolicy(TrendKernelRegression(random_state=seed).fit(
            X, problem.potential.value(X), groups=groups))
    return {"case": name, "seed": seed,
            "default": float(np.linalg.norm(learnt_minimum(model, problem.minimum)
                                            - problem.minimum)),
            "true": float(np.linalg.norm(learnt_minimum(true, problem.minimum)
                                         - problem.minimum)),
            "gap": suite.data_gap(train, problem.minimum)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="arm_task_7,bumps_2,bumps_noisy_6")
    parser.add_argument("--seeds", default="1000,1001,1002")
    parser.add_argument("--jobs", type=int, default=1)
    args = parser.parse_args(argv)
    names, seeds = args.cases.split(","), [int(s) for s in args.seeds.split(",")]
    unknown = [n for n in names if n not in suite.ALL_CASES
               or suite.ALL_CASES[n].make(np.random.default_rng(0)).minimum is None]
    if unknown:
        raise SystemExit(f"--cases: {unknown} are not suite cases with a true minimum")
    rows = parallel_map(_row, [(n, s) for n in names for s in seeds], args.jobs,
                        "goal bound")
    print("| case | learnt min - true min, default [state units] | fitted to the true "
          "potential values | closest training sample - true min |\n|---|---|---|---|")
    for name in names:
        mine = [r for r in rows if r["case"] == name]
        cells = ["/".join(f"{r[key]:.4f}" for r in mine) for key in ("default", "true", "gap")]
        print(f"| {name} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
