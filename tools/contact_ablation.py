"""What the table costs ``contact_arm_7``'s learnt goal: the same data sets recorded with
the table and friction (the case), with the table and no friction, and with no table
(``tools/goal_bound.py`` fits the case's samples to the expert's true potential values).

Each row is one seed's data set as ``policy-align bench suite --cases contact_arm_7``
draws it (same starts, planes and held-out samples), fitted by ``PolicyAlign`` with the
suite's settings; the learnt minimum (``experiments.retiming.learnt_minimum``) against the
expert's, in joint space and at the hand, and how close the training data came to the
expert's minimum (a minimum the data never reach is an extrapolation):

    python tools/contact_ablation.py --seeds 1000,1001,1002 --jobs 2
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

from policy_align_ros.experiments import suite
from policy_align_ros.experiments.pool import parallel_map
from policy_align_ros.experiments.recording_cases import contact_arm
from policy_align_ros.experiments.retiming import learnt_minimum
from policy_align_ros.learning import PolicyAlign

#: (label, contact_arm keywords): the case first.
VARIANTS = (("table, mu 0.4", {}), ("table, mu 0", {"mu": 0.0}),
            ("no table", {"table": False}))


def _row(task: tuple[str, int]) -> dict:
    label, seed = task
    rng = np.random.default_rng(seed)
    problem = contact_arm(rng, **dict(VARIANTS)[label])
    train, _, masks = suite.draw_data_set(problem, rng)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the fit's own warnings are not what is measured
        model = PolicyAlign(sigma=problem.sigma, random_state=seed).fit(
            [d.trajectory for d in train], train_mask=masks)
    found = learnt_minimum(model, problem.minimum)
    hand = problem.extras["hand"]
    return {"variant": label, "seed": seed,
            "error": float(np.linalg.norm(found - problem.minimum)),
            "hand_mm": 1e3 * float(np.linalg.norm(hand(found) - hand(problem.minimum))),
            "gap": suite.data_gap(train, problem.minimum)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1000,1001,1002")
    parser.add_argument("--jobs", type=int, default=1)
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = parallel_map(_row, [(label, s) for label, _ in VARIANTS for s in seeds],
                        args.jobs, "contact ablation")
    print("| recording | learnt min - true min [rad] | at the hand [mm] "
          "| closest training sample - true min [rad] |\n|---|---|---|---|")
    for label, _ in VARIANTS:
        mine = [r for r in rows if r["variant"] == label]
        cells = ["/".join(f"{r[key]:{fmt}}" for r in mine)
                 for key, fmt in (("error", ".4f"), ("hand_mm", ".1f"), ("gap", ".4f"))]
        print(f"| {label} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
