"""Kernel-width heuristics for the alignment responsibilities (paper section IV-A).

Notation: ``d_kj = min_{n,m} ||x_kn - x_jm||^2`` is the squared closest approach of
trajectories ``k`` and ``j``; ``d_k^min = min_{j != k} d_kj``. The paper's three choices are

    sigma2_narrow = median_k d_k^min                       (eq. 17)
    sigma2_wide   = median_{j != k} d_jk                   (eq. 18)
    sigma2_medium = sqrt(sigma2_narrow * sigma2_wide)      (eq. 19)

Distances are in squared state units. For large data sets the heuristics work on at most
``max_points`` points, each trajectory thinned evenly in arc length; the medians of
closest approaches need no more.

A closest approach is measured between samples, so it cannot resolve distances below the
sampling step: two trajectories that meet (or both settle at the attractor, as real
demonstrations do) give ``d_kj = 0`` exactly, and a median of zeros would make the
alignment's kernel a delta. ``sigma2_narrow`` is therefore at least ``(s / 2)^2``, with ``s``
the median sample spacing along the (thinned) trajectories (:func:`sampling_resolution`).
"""

from __future__ import annotations

import numpy as np

from policy_align_ros.learning.thinning import thin_each

__all__ = [
    "RULES",
    "closest_approach_matrix",
    "sampling_resolution",
    "sigma2_from_closest",
    "sigma2_heuristics",
    "resolve_sigma2",
]

RULES = ("narrow", "medium", "wide")
#: Points the closest-approach matrix is computed on (trajectories thinned beyond).
HEURISTIC_POINTS = 20_000


def closest_approach_matrix(trajectories: list[np.ndarray]) -> np.ndarray:
    """Squared closest approach ``d_kj`` between every pair of trajectories.

    Parameters
    ----------
    trajectories : list of ndarray, each of shape (N_k, n)

    Returns
    -------
    ndarray, shape (K, K)
        Symmetric, with ``inf`` on the diagonal.

    Notes
    -----
    The distances are expanded as ``|a|^2 + |b|^2 - 2 a.b`` (one matrix product per block
    of trajectories), on states centred first (the mean of all points subtracted): far
    from the origin the expansion would cancel, at 1e7 state units every ``d_kj`` of unit
    size to 0. Centring changes the distances on ordinary data by round-off only.
    """
    points = np.concatenate(trajectories)
    points = points - points.mean(axis=0)
    sizes = np.array([len(x) for x in trajectories])
    starts = np.concatenate(([0], np.cumsum(sizes)))
    sq_norms = np.einsum("ij,ij->i", points, points)
    K = len(trajectories)
    d = np.zeros((K, K))
    # Rows in blocks of whole trajectories, each against the trajectories from its own on
    # (the matrix is symmetric: every pair once): one matrix product per block, bounded
    # memory.
    block_rows = max(1, 4_000_000 // len(points))
    k = 0
    while k < K:
        stop = k + 1
        while stop < K and starts[stop + 1] - starts[k] <= block_rows:
            stop += 1
        rows, cols = slice(starts[k], starts[stop]), slice(starts[k], None)
        block = (sq_norms[rows, None] + sq_norms[None, cols]
                 - 2.0 * points[rows] @ points[cols].T)
        per_col = np.minimum.reduceat(block, starts[k:stop] - starts[k], axis=0)
        d[k:stop, k:] = np.minimum.reduceat(per_col, starts[k:-1] - starts[k], axis=1)
        k = stop
    d = np.maximum(np.triu(d) + np.triu(d, 1).T, 0.0)
    np.fill_diagonal(d, np.inf)
    return d


def sigma2_heuristics(
    trajectories: list[np.ndarray],
    *,
    max_points: int = HEURISTIC_POINTS,
) -> dict[str, float]:
    """The paper's narrow, wide and medium kernel widths ``sigma^2``.

    Parameters
    ----------
    trajectories : list of ndarray, each of shape (N_k, n)
        At least two trajectories.
    max_points : int
        Thin the trajectories evenly to at most this many points in total.

    Returns
    -------
    dict
        ``{"narrow": float, "medium": float, "wide": float}`` in squared state units.
    """
    if len(trajectories) < 2:
        raise ValueError("the sigma heuristics need at least 2 trajectories")
    thin = thin_each(trajectories, max_points)
    return sigma2_from_closest(closest_approach_matrix(thin), sampling_resolution(thin))


def sampling_resolution(trajectories: list[np.ndarray]) -> float:
    """Squared half sample spacing ``(s / 2)^2``, ``s`` the median mean step per trajectory.

    The smallest closest approach that samples spaced ``s`` apart can resolve (squared
    state units); 0 when no trajectory moves.
    """
    steps = [np.linalg.norm(np.diff(x, axis=0), axis=1).mean() for x in trajectories
             if len(x) > 1]
    return float(np.median(steps)) ** 2 / 4.0 if steps else 0.0


def sigma2_from_closest(d: np.ndarray, resolution: float = 0.0) -> dict[str, float]:
    """Narrow, medium and wide ``sigma^2`` from a closest-approach matrix (K x K).

    ``resolution`` (squared state units, :func:`sampling_resolution`) bounds the narrow
    width from below: closest approaches below it are not measurable.
    """
    nearest = d.min(axis=1)
    pairs = d[np.triu_indices(len(d), 1)]
    narrow = float(np.median(nearest))
    wide = float(np.median(pairs))
    # The tiny relative floor keeps the width positive when nothing moves at all.
    narrow = max(narrow, resolution, 1e-12 * max(wide, 1e-300))
    wide = max(wide, narrow)
    return {"narrow": narrow, "medium": float(np.sqrt(narrow * wide)), "wide": wide}


def resolve_sigma2(
    sigma: str | float, trajectories: list[np.ndarray], closest: np.ndarray | None = None
) -> float:
    """Kernel width ``sigma^2`` from a rule name or a given positive value.

    ``closest`` is a precomputed ``closest_approach_matrix`` of (thinned) trajectories.
    """
    if isinstance(sigma, str):
        if sigma not in RULES:
            raise ValueError(f"sigma must be one of {RULES} or a positive float, got {sigma!r}")
        if closest is None:
            return sigma2_heuristics(trajectories)[sigma]
        resolution = sampling_resolution(thin_each(trajectories, HEURISTIC_POINTS))
        return sigma2_from_closest(closest, resolution)[sigma]
    value = float(sigma)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"sigma (sigma^2) must be a positive finite float, got {sigma!r}")
    return value
