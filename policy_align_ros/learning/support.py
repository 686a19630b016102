"""The region of state space that the demonstrations cover (for the extrapolation guard).

Notation: ``S`` (m, n) are support states, the training states thinned evenly in arc
length along each kept demonstration; ``g`` (m,) the demonstration of each. For a support
state ``s_i`` let ``e_i`` be its distance to the nearest support state of *another*
demonstration (a leave-one-demonstration-out distance). The spacing of the data is the
``SPACING_QUANTILE`` quantile of the ``e_i``: a new demonstration drawn from the same
distribution as the training ones lies about that far from them, so a guard that acts
beyond a few spacings leaves such runs alone. Distances are in state units.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from policy_align_ros.learning.thinning import thin_each

__all__ = ["SUPPORT_POINTS", "SPACING_QUANTILE", "support_states", "support_spacing",
           "query_support"]

#: Support states kept in a model file (trajectories thinned beyond).
SUPPORT_POINTS = 4000
#: Quantile of the leave-one-demonstration-out distances that defines the spacing.
SPACING_QUANTILE = 0.9
#: Rows of the dense distance matrix computed at once.
_BLOCK = 512


def support_states(trajectories: Sequence[np.ndarray], max_points: int = SUPPORT_POINTS
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Thin demonstrations to at most about ``max_points`` support states.

    Parameters
    ----------
    trajectories : sequence of ndarray (N_k, n)
    max_points : int

    Returns
    -------
    S : ndarray (m, n)
    groups : ndarray of int (m,)
        Index (into ``trajectories``) of the demonstration of each support state.
    """
    thinned = thin_each([np.asarray(t, dtype=float) for t in trajectories], max_points)
    groups = np.repeat(np.arange(len(thinned)), [len(t) for t in thinned])
    return np.concatenate(thinned), groups


def support_spacing(S: np.ndarray, groups: np.ndarray) -> float:
    """Spacing of the data: a quantile of the leave-one-demonstration-out distances.

    Parameters
    ----------
    S : ndarray (m, n)
        Support states (at most a few thousand: the distances are computed densely, in
        blocks, which beats a k-d tree in many dimensions).
    groups : ndarray of int (m,)
        Demonstration of each support state (with a single demonstration, the spread of
        its states about their mean stands in).

    Returns
    -------
    float
        Spacing in state units (> 0).
    """
    if len(np.unique(groups)) < 2:
        # One demonstration: nothing to leave out, so its spread stands in for the spacing.
        spread = np.linalg.norm(S - S.mean(axis=0), axis=1)
        return float(np.quantile(spread, SPACING_QUANTILE)) or 1.0
    sq = np.einsum("ij,ij->i", S, S)
    nearest = np.empty(len(S))
    for start in range(0, len(S), _BLOCK):
        rows = slice(start, start + _BLOCK)
        d2 = sq[rows, None] - 2.0 * S[rows] @ S.T + sq[None, :]
        d2[groups[rows, None] == groups[None, :]] = np.inf
        nearest[rows] = np.sqrt(np.maximum(d2.min(axis=1), 0.0))
    spacing = float(np.quantile(nearest, SPACING_QUANTILE))
    if not spacing > 0:
        spacing = float(np.max(nearest)) or 1.0
    return spacing


def query_support(tree: cKDTree, S: np.ndarray, spacing: float, X: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Distance of states to the nearest support state, in spacings, and that state.

    Parameters
    ----------
    tree : scipy.spatial.cKDTree
        Built on ``S``.
    S : ndarray (m, n)
    spacing : float
        State units per spacing.
    X : ndarray (q, n)

    Returns
    -------
    d : ndarray (q,)
        ``min_i ||x - s_i|| / spacing``.
    nearest : ndarray (q, n)
        The nearest support state of each row of ``X``.
    """
    dist, idx = tree.query(X, k=1)
    return np.asarray(dist) / spacing, S[np.asarray(idx)]
