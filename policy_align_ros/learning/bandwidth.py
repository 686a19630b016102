"""Kernel-width heuristics for the alignment responsibilities (paper section IV-A).

Notation: ``d_kj = min_{n,m} ||x_kn - x_jm||^2`` is the squared closest approach of
trajectories ``k`` and ``j``; ``d_k^min = min_{j != k} d_kj``. The paper's three choices are

    sigma2_narrow = median_k d_k^min                       (eq. 17)
    sigma2_wide   = median_{j != k} d_jk                   (eq. 18)
    sigma2_medium = sqrt(sigma2_narrow * sigma2_wide)      (eq. 19)

Distances are in squared state units. For large data sets the heuristics work on at most
``max_points`` points (each trajectory thinned evenly) and ``wide`` on a random sample of
trajectory pairs; a median needs no more.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["RULES", "closest_approach_matrix", "sigma2_heuristics", "resolve_sigma2"]

RULES = ("narrow", "medium", "wide")
_DENSE_LIMIT = 12_000  # points for which the full trajectory-distance matrix is cheap
_MAX_PAIRS = 5_000


def _thin(trajectories: list[np.ndarray], max_points: int) -> list[np.ndarray]:
    per_traj = max(2, max_points // max(len(trajectories), 1))
    out = []
    for x in trajectories:
        if len(x) > per_traj:
            x = x[np.linspace(0, len(x) - 1, per_traj).round().astype(int)]
        out.append(x)
    return out


def closest_approach_matrix(trajectories: list[np.ndarray]) -> np.ndarray:
    """Squared closest approach ``d_kj`` between every pair of trajectories.

    Parameters
    ----------
    trajectories : list of ndarray, each of shape (N_k, n)

    Returns
    -------
    ndarray, shape (K, K)
        Symmetric, with ``inf`` on the diagonal.
    """
    points = np.concatenate(trajectories)
    sizes = np.array([len(x) for x in trajectories])
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    sq_norms = np.einsum("ij,ij->i", points, points)
    d = np.empty((len(trajectories), len(trajectories)))
    for k, x in enumerate(trajectories):
        block = (
            np.einsum("ij,ij->i", x, x)[:, None] + sq_norms[None, :] - 2.0 * x @ points.T
        )
        d[k] = np.minimum.reduceat(block.min(axis=0), starts)
    d = np.maximum(np.minimum(d, d.T), 0.0)
    np.fill_diagonal(d, np.inf)
    return d


def _nearest_other(trajectories: list[np.ndarray]) -> np.ndarray:
    """``d_k^min`` by a k-nearest-neighbour query that must reach another trajectory."""
    points = np.concatenate(trajectories)
    labels = np.repeat(np.arange(len(trajectories)), [len(x) for x in trajectories])
    # A point's own trajectory holds at most max_len points, so max_len + 1 neighbours
    # always include one from another trajectory.
    kq = min(max(len(x) for x in trajectories) + 1, len(points))
    dist, idx = cKDTree(points).query(points, k=kq)
    foreign = labels[idx] != labels[:, None]
    dist = np.where(foreign, dist, np.inf).min(axis=1)
    best = np.full(len(trajectories), np.inf)
    np.minimum.at(best, labels, dist**2)
    return best


def _sampled_pairs(
    trajectories: list[np.ndarray], rng: np.random.Generator, n_pairs: int
) -> np.ndarray:
    K = len(trajectories)
    j = rng.integers(0, K, size=n_pairs)
    k = (j + rng.integers(1, K, size=n_pairs)) % K
    trees = {}
    out = np.empty(n_pairs)
    for p, (a, b) in enumerate(zip(j, k, strict=True)):
        if a not in trees:
            trees[a] = cKDTree(trajectories[a])
        out[p] = trees[a].query(trajectories[b], k=1)[0].min() ** 2
    return out


def sigma2_heuristics(
    trajectories: list[np.ndarray],
    *,
    max_points: int = 50_000,
    random_state: int | np.random.Generator | None = 0,
) -> dict[str, float]:
    """The paper's narrow, wide and medium kernel widths ``sigma^2``.

    Parameters
    ----------
    trajectories : list of ndarray, each of shape (N_k, n)
        At least two trajectories.
    max_points : int
        Thin the trajectories evenly to at most this many points in total.
    random_state : int, Generator or None
        Seeds the sample of trajectory pairs used for ``wide`` on large data sets.

    Returns
    -------
    dict
        ``{"narrow": float, "medium": float, "wide": float}`` in squared state units.
    """
    if len(trajectories) < 2:
        raise ValueError("the sigma heuristics need at least 2 trajectories")
    thin = _thin(trajectories, max_points)
    K = len(thin)
    n_points = sum(len(x) for x in thin)
    if n_points <= _DENSE_LIMIT:
        d = closest_approach_matrix(thin)
        nearest = d.min(axis=1)
        pairs = d[np.triu_indices(K, 1)]
    else:
        nearest = _nearest_other(thin)
        rng = np.random.default_rng(random_state)
        if K * (K - 1) // 2 <= _MAX_PAIRS:
            d = closest_approach_matrix(thin)
            pairs = d[np.triu_indices(K, 1)]
        else:
            pairs = _sampled_pairs(thin, rng, _MAX_PAIRS)
    narrow = float(np.median(nearest))
    wide = float(np.median(pairs))
    # Coincident trajectories give a zero closest approach; keep the width positive.
    floor = 1e-12 * max(wide, 1e-300)
    narrow = max(narrow, floor)
    wide = max(wide, narrow)
    return {"narrow": narrow, "medium": float(np.sqrt(narrow * wide)), "wide": wide}


def resolve_sigma2(
    sigma: str | float,
    trajectories: list[np.ndarray],
    *,
    random_state: int | np.random.Generator | None = 0,
) -> float:
    """Kernel width ``sigma^2`` from a rule name or a given positive value."""
    if isinstance(sigma, str):
        if sigma not in RULES:
            raise ValueError(f"sigma must be one of {RULES} or a positive float, got {sigma!r}")
        return sigma2_heuristics(trajectories, random_state=random_state)[sigma]
    value = float(sigma)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"sigma (sigma^2) must be a positive finite float, got {sigma!r}")
    return value
