"""Keep or drop the trajectories the alignment cannot level: the measurement behind
``docs/design/alignment_and_outliers.md``.

Usage: ``python tools/unaligned_check.py POTENTIAL K N SIGMA FIRST_SEED LAST_SEED`` (the toy
data of ``policy-align bench toy``; for example ``sinusoid 40 40 narrow 0 20``). Each data
set with trajectories outside the aligned set is fitted twice, with the default
``TrendKernelRegression`` (those trajectories levelled by the global model) and with the
same regressor restricted to the aligned set (the paper's rule: they are discarded). Both
models are scored, nUPE and nCPE on the held-out 20 % of the samples, on two sets: the
aligned trajectories only, and all trajectories.
"""

from __future__ import annotations

import sys

import numpy as np

from policy_align_ros.experiments.evaluation import holdout_masks
from policy_align_ros.experiments.toy import make_toy_dataset
from policy_align_ros.learning import PolicyAlign, metrics
from policy_align_ros.learning.outliers import largest_group
from policy_align_ros.learning.regressors import TrendKernelRegression


class AlignedSetOnly(TrendKernelRegression):
    """The default regressor without ``free_groups``: PolicyAlign then discards the
    trajectories outside the aligned set."""

    def fit(self, X, y, groups=None):  # noqa: D102 - same as the parent's
        return super().fit(X, y, groups)


def _errors(model: PolicyAlign, data, masks, keep) -> tuple[float, float]:
    X = np.concatenate([data.trajectories[k].positions[~masks[k]] for k in keep])
    pi = np.concatenate([data.pi[k][~masks[k]] for k in keep])
    N = np.concatenate([data.nullspace[k][~masks[k]] for k in keep])
    pi_hat = model.policy(X)
    return metrics.nupe(pi, pi_hat), metrics.ncpe(pi, pi_hat, N)


def main(argv: list[str]) -> None:
    potential, n_traj, n_samples, sigma = argv[0], int(argv[1]), int(argv[2]), argv[3]
    rows = []
    print("seed  unaligned  nUPE on the aligned set (dropped -> levelled)  "
          "nUPE on all (dropped -> levelled)")
    for seed in range(int(argv[4]), int(argv[5])):
        rng = np.random.default_rng(seed)
        data = make_toy_dataset(potential, n_traj, n_samples, rng)
        masks = holdout_masks([n_samples] * n_traj, rng)
        dropped = PolicyAlign(sigma=sigma, random_state=seed,
                              regressor=AlignedSetOnly(random_state=seed)).fit(
            data.trajectories, train_mask=masks)
        aligned = largest_group(dropped.groups_)
        if len(aligned) == n_traj:
            continue
        levelled = PolicyAlign(sigma=sigma, random_state=seed).fit(
            data.trajectories, train_mask=masks)
        everyone = np.arange(n_traj)
        row = [*_errors(dropped, data, masks, aligned), *_errors(levelled, data, masks, aligned),
               *_errors(dropped, data, masks, everyone),
               *_errors(levelled, data, masks, everyone)]
        rows.append(row)
        print(f"{seed:4d}  {100 * (1 - len(aligned) / n_traj):8.0f} %  "
              f"{row[0]:.4f} -> {row[2]:.4f}{'':28s}{row[4]:.4f} -> {row[6]:.4f}", flush=True)
    if not rows:
        print("no data set had trajectories outside the aligned set")
        return
    table = np.array(rows)
    for label, stat in (("mean", np.mean), ("median", np.median)):
        v = stat(table, axis=0)
        print(f"{label}: aligned set nUPE {v[0]:.4f} -> {v[2]:.4f}, nCPE {v[1]:.4f} -> "
              f"{v[3]:.4f}; all trajectories nUPE {v[4]:.4f} -> {v[6]:.4f}, nCPE {v[5]:.4f} "
              f"-> {v[7]:.4f} ({len(rows)} data sets)")


if __name__ == "__main__":
    main(sys.argv[1:])
