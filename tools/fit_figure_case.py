"""Draw the fit of one suite data set as ``policy-align learn --plot`` draws a user's
(``policy_align_ros.data.fit_figure``): the training demonstrations as
``policy-align bench suite --cases NAME --seed SEED`` draws them, fitted on all their
samples, with the data set's demonstrations from new starts as the held-out ones:

    python tools/fit_figure_case.py --case human_timing_2 --seed 0 \
        --out docs/fit_human_timing_2.png --dpi 80
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

from policy_align_ros.data.fit_figure import plot_fit
from policy_align_ros.experiments import suite
from policy_align_ros.learning import PolicyAlign


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--case", required=True, help=", ".join(sorted(suite.ALL_CASES)))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--dpi", type=int, default=120)
    args = parser.parse_args(argv)
    if args.case not in suite.ALL_CASES:
        parser.error(f"--case: unknown case {args.case!r}; one of "
                     f"{', '.join(sorted(suite.ALL_CASES))}")
    rng = np.random.default_rng(args.seed)
    problem = suite.ALL_CASES[args.case].make(rng)
    train, test, _ = suite.draw_data_set(problem, rng)
    trajs = [d.trajectory for d in train]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = PolicyAlign(sigma=problem.sigma, random_state=args.seed).fit(trajs)
    for w in caught:
        print(f"fit warning: {w.message}")
    print(plot_fit(model, trajs, args.out, [d.trajectory for d in test], dpi=args.dpi))
    return 0


if __name__ == "__main__":
    sys.exit(main())
