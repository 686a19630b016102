"""Detection of weakly connected trajectories (paper section III-C and footnote 3).

Notation: ``W`` (K x K) holds the alignment graph's edge weights
``W_kj = sum_m q_km q_jm`` and ``L = diag(W 1) - W`` is its Laplacian, the Hessian ``H`` of
the alignment objective. A zero eigenvalue of ``L`` belongs to a shift of all offsets; every
further eigenvalue below ``eigen_tol`` means a subset of trajectories can be shifted against
the rest at (almost) no cost, so its offset is not determined by the data. Such groups are
split off by recursive spectral bi-partitioning (sign of the Fiedler vector) until every group
has a single eigenvalue below ``eigen_tol``; the largest group is kept.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, laplacian

__all__ = ["weakly_connected_groups", "largest_group"]


def _fiedler(W: sp.spmatrix) -> tuple[float, np.ndarray]:
    """Second-smallest eigenvalue and its eigenvector of the graph Laplacian of ``W``."""
    L = laplacian(sp.csr_matrix(W)).toarray()
    values, vectors = scipy.linalg.eigh(L, subset_by_index=[0, 1])
    return float(values[1]), vectors[:, 1]


def weakly_connected_groups(W: sp.spmatrix, eigen_tol: float = 1e-8) -> np.ndarray:
    """Split the trajectories into groups that are well connected internally.

    Parameters
    ----------
    W : sparse matrix, shape (K, K)
        Symmetric non-negative edge weights of the alignment graph.
    eigen_tol : float
        Eigenvalues of a group's Laplacian below this count as zero (paper: 1e-8).

    Returns
    -------
    ndarray of int, shape (K,)
        Group label of each trajectory; labels are ordered by decreasing group size, so
        group 0 is the largest (ties: the group holding the lowest trajectory index).
    """
    W = sp.csr_matrix(W)
    K = W.shape[0]
    n_comp, comp = connected_components(W, directed=False)
    pending = [np.flatnonzero(comp == c) for c in range(n_comp)]
    final: list[np.ndarray] = []
    while pending:
        idx = pending.pop()
        if len(idx) < 2:
            final.append(idx)
            continue
        value, vector = _fiedler(W[idx][:, idx])
        if value >= eigen_tol:
            final.append(idx)
            continue
        side = vector >= 0
        if side.all() or not side.any():  # numerically flat vector: split at the median
            side = vector > np.median(vector)
        if side.all() or not side.any():
            final.append(idx)
            continue
        pending.extend([idx[side], idx[~side]])
    final.sort(key=lambda g: (-len(g), g.min()))
    labels = np.empty(K, dtype=np.int64)
    for g, idx in enumerate(final):
        labels[idx] = g
    return labels


def largest_group(labels: np.ndarray) -> np.ndarray:
    """Indices of the trajectories in group 0 (the largest), sorted."""
    return np.flatnonzero(labels == 0)
