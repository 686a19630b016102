"""Held-out evaluation shared by the benchmarks (paper section IV-B protocol).

Notation: for each trajectory ``k`` a random ``holdout`` share of its samples is hidden
from the global regression (``train_mask``); the errors are measured on the hidden samples
of the trajectories PolicyAlign kept (``inliers_``), the alignment's error on those of the
aligned set (group 0 of ``groups_``: the others' levels come from the global model).
``phi``, ``pi`` and ``N`` are the ground truth potential, unconstrained policy and nullspace
projector at every sample.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from policy_align_ros.learning import PolicyAlign, metrics
from policy_align_ros.learning.outliers import largest_group

__all__ = ["holdout_masks", "evaluate_policy_align", "METRIC_NAMES"]

METRIC_NAMES = ("alignment_nmse", "potential_nmse", "nupe", "ncpe", "discarded_pct",
                "unaligned_pct")


def holdout_masks(
    lengths: Sequence[int], rng: np.random.Generator, holdout: float = 0.2
) -> list[np.ndarray]:
    """Training masks that hide a random ``holdout`` share of each trajectory's samples."""
    return [rng.random(n) >= holdout for n in lengths]


def evaluate_policy_align(
    model: PolicyAlign,
    positions: Sequence[np.ndarray],
    phi: Sequence[np.ndarray],
    pi: Sequence[np.ndarray],
    nullspace: Sequence[np.ndarray],
    train_masks: Sequence[np.ndarray],
) -> dict[str, float]:
    """The paper's five measures on the held-out samples of the kept trajectories.

    Parameters
    ----------
    model : PolicyAlign
        Fitted with ``train_mask=train_masks``.
    positions, phi, pi, nullspace : sequences over trajectories
        States (N_k, n), true potential (N_k,), true policy (N_k, n), projectors (N_k, n, n).
    train_masks : sequence of bool arrays (N_k,)

    Returns
    -------
    dict
        ``alignment_nmse``, ``potential_nmse``, ``nupe``, ``ncpe``, ``discarded_pct``,
        ``unaligned_pct``.
    """
    def gather(seq, keep=model.inliers_):
        return np.concatenate([np.asarray(seq[k])[~np.asarray(train_masks[k])] for k in keep])

    X = gather(positions)
    true_phi = gather(phi)
    true_pi = gather(pi)
    N = gather(nullspace)
    aligned_set = largest_group(model.groups_)
    pi_hat = model.policy(X)
    return {
        "alignment_nmse": metrics.potential_nmse(gather(model.aligned_potentials_, aligned_set),
                                                 gather(phi, aligned_set)),
        "potential_nmse": metrics.potential_nmse(model.potential(X), true_phi),
        "nupe": metrics.nupe(true_pi, pi_hat),
        "ncpe": metrics.ncpe(true_pi, pi_hat, N),
        "discarded_pct": metrics.percent_discarded(model),
        "unaligned_pct": metrics.percent_unaligned(model),
    }
