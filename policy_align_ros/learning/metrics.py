"""Error measures of the paper's experiments (section IV-B), as fixed in docs/design.md.

Notation: ``phi`` true and ``phi_hat`` predicted potentials, shape (m,); ``pi`` and
``pi_hat`` true and predicted policies, shape (m, n); ``N`` the nullspace projectors of the
constraints in force at each point, shape (m, n, n). All measures are normalised, so unitless.
"""

from __future__ import annotations

import numpy as np

__all__ = ["potential_nmse", "nupe", "ncpe", "percent_discarded", "percent_unaligned"]


def potential_nmse(predicted: np.ndarray, true: np.ndarray) -> float:
    """nMSE of a potential, which is only defined up to a constant.

    ``e = pred - true``, ``e -= mean(e)``, result ``mean(e**2) / var(true)``.
    """
    predicted = np.asarray(predicted, dtype=float)
    true = np.asarray(true, dtype=float)
    if predicted.shape != true.shape or predicted.ndim != 1:
        raise ValueError(
            f"potentials must be 1-D of equal shape, got {predicted.shape} and {true.shape}"
        )
    err = predicted - true
    err -= err.mean()
    return float(np.mean(err**2) / np.var(true))


def nupe(pi: np.ndarray, pi_hat: np.ndarray) -> float:
    """Normalised unconstrained policy error.

    ``mean_i ||pi_i - pi_hat_i||^2 / sum_d var(pi[:, d])``.
    """
    pi, pi_hat = _policies(pi, pi_hat)
    return float(np.mean(np.sum((pi - pi_hat) ** 2, axis=1)) / np.sum(np.var(pi, axis=0)))


def ncpe(pi: np.ndarray, pi_hat: np.ndarray, N: np.ndarray) -> float:
    """Normalised constrained policy error.

    ``mean_i ||N_i (pi_i - pi_hat_i)||^2 / sum_d var((N pi)[:, d])``.
    """
    pi, pi_hat = _policies(pi, pi_hat)
    N = np.asarray(N, dtype=float)
    if N.shape != pi.shape + (pi.shape[1],):
        raise ValueError(f"N must have shape {pi.shape + (pi.shape[1],)}, got {N.shape}")
    constrained = np.einsum("mij,mj->mi", N, pi)
    err = np.einsum("mij,mj->mi", N, pi - pi_hat)
    return float(np.mean(np.sum(err**2, axis=1)) / np.sum(np.var(constrained, axis=0)))


def percent_discarded(model) -> float:
    """Percentage of trajectories a fitted ``PolicyAlign`` left out of its global model."""
    total = len(model.offsets_)
    return 100.0 * (total - len(model.inliers_)) / total


def percent_unaligned(model) -> float:
    """Percentage of trajectories outside a fitted ``PolicyAlign``'s aligned set: those the
    alignment could not level (the paper's outliers). Its default regressor levels them
    and keeps them; with other regressors they are discarded."""
    total = len(model.offsets_)
    return 100.0 * (total - int(np.sum(model.groups_ == 0))) / total


def _policies(pi: np.ndarray, pi_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pi = np.asarray(pi, dtype=float)
    pi_hat = np.asarray(pi_hat, dtype=float)
    if pi.ndim != 2 or pi.shape != pi_hat.shape:
        raise ValueError(
            f"policies must be (m, n) arrays of equal shape, got {pi.shape} and {pi_hat.shape}"
        )
    return pi, pi_hat
