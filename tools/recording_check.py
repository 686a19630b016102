#!/usr/bin/env python3
"""The suite's data sets recorded as a real robot records them: rest, dropped samples, jitter.

The suite (``policy-align bench suite``) samples every demonstration at exact, even times
from its first motion to its end. A recording from a robot differs in three ways, each
applied here to every training demonstration (``KIND``):

* ``rest``: the robot stands still for 10-59 samples before it moves and 20-99 samples
  after it arrives (positions held with encoder noise of 2 % of a median step, velocities
  zero);
* ``drop``: 5 % of the samples lost at random (a loaded executor, a lossy network): the
  time steps become uneven, the stamps stay right;
* ``jitter``: every stamp off by up to +-20 % of the time step (stamps taken in a callback
  rather than by the driver), positions and velocities unchanged;
* ``all``: the three together; ``clean``: the suite's data as they are.

For every case and seed, ``PolicyAlign`` is fitted with its defaults, as a user would
(not the suite's settings of ``sigma`` or its held-out samples), and scored by nUPE and
nCPE on the suite's new-start demonstrations, which stay clean (the expert's true policy).

Usage: ``python tools/recording_check.py [--seed 0] [--datasets 3] [--cases a,b]
[--kinds clean,rest,...] [--jobs 2]``. Prints one Markdown table: per case and kind, the
median nUPE over the data sets, and the worst.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from policy_align_ros.experiments import suite
from policy_align_ros.experiments.pool import parallel_map
from policy_align_ros.experiments.suite_cases import CASES
from policy_align_ros.learning import PolicyAlign, Trajectory, metrics

KINDS = ("clean", "rest", "drop", "jitter", "all")


def record(traj: Trajectory, kind: str, dt: float, rng: np.random.Generator) -> Trajectory:
    """``traj`` with the recording artefacts of ``kind`` (see the module docstring)."""
    q, v = traj.positions, traj.velocities
    t = traj.times if traj.times is not None else np.arange(len(q)) * dt
    if kind in ("rest", "all"):
        before, after = int(rng.integers(10, 60)), int(rng.integers(20, 100))
        step = float(np.median(np.linalg.norm(np.diff(q, axis=0), axis=1)))
        sd = 0.02 * step / np.sqrt(q.shape[1])
        q = np.vstack([q[0] + sd * rng.standard_normal((before, q.shape[1])), q,
                       q[-1] + sd * rng.standard_normal((after, q.shape[1]))])
        t = np.concatenate([t[0] - dt * np.arange(before, 0, -1), t,
                            t[-1] + dt * np.arange(1, after + 1)])
        if v is not None:
            v = np.vstack([np.zeros((before, q.shape[1])), v, np.zeros((after, q.shape[1]))])
    if kind in ("drop", "all"):
        keep = rng.random(len(q)) > 0.05
        keep[[0, -1]] = True
        q, t = q[keep], t[keep]
        v = None if v is None else v[keep]
    if kind in ("jitter", "all"):
        t = t + rng.uniform(-0.2, 0.2, len(t)) * dt
    return Trajectory(q, t, v, name=traj.name)


def run(task: tuple[str, int, str]) -> tuple[str, int, str, float, float]:
    """Fit one data set of case ``name`` recorded as ``kind``; its nUPE and nCPE."""
    name, seed, kind = task
    rng = np.random.default_rng(seed)
    problem = CASES[name].make(rng)
    train = suite._demos(problem, problem.sample_starts(rng, problem.n_train), rng)
    test = suite._demos(problem, problem.sample_starts(rng, suite.N_TEST_DEMOS), rng)
    artefacts = np.random.default_rng([seed, 99])
    recorded = [record(d.trajectory, kind, problem.dt, artefacts) for d in train]
    model = PolicyAlign(random_state=seed).fit(recorded)
    X, pi, N = suite._stack(test)
    pi_hat = model.policy(X)
    return name, seed, kind, metrics.nupe(pi, pi_hat), metrics.ncpe(pi, pi_hat, N)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--datasets", type=int, default=3)
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--kinds", default=",".join(KINDS))
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    cases, kinds = args.cases.split(","), args.kinds.split(",")
    for item, known in [(c, CASES) for c in cases] + [(k, KINDS) for k in kinds]:
        if item not in known:
            parser.error(f"unknown case or kind {item!r}; known: {', '.join(known)}")
    tasks = [(c, args.seed + i, k) for c in cases for i in range(args.datasets) for k in kinds]
    results = parallel_map(run, tasks, args.jobs, "recording_check")
    print("| case | " + " | ".join(kinds) + " |")
    print("|---|" + "---|" * len(kinds))
    for c in cases:
        cells = []
        for k in kinds:
            e = [r[3] for r in results if r[0] == c and r[2] == k]
            cells.append(f"{np.median(e):.2g} ({max(e):.2g})")
        print(f"| {c} | " + " | ".join(cells) + " |")
    print(f"\nnUPE from new starts: median over {args.datasets} data sets (worst), "
          f"seeds {args.seed}..{args.seed + args.datasets - 1}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
