"""Alignment of the local potential models (paper section III-B, eqs. 8-15).

Notation: ``M`` points ``x_m`` from ``K`` trajectories; ``phi_km`` the Euler estimate of
trajectory ``k`` at its own points. Trajectory ``k``'s local model is nearest-neighbour
regression, ``f_k(x) = phi_{k,i*}`` with ``i* = argmin_i ||x - x_ki||^2`` (eq. 8), weighted by

    w_k(x) = exp(-min_i ||x - x_ki||^2 / (2 sigma^2)),    q_km = w_k(x_m) / sum_j w_j(x_m).

The offsets ``b`` minimise ``E(b) = 1/2 sum_{m,k,j} q_km q_jm (f_km + b_k - f_jm - b_j)^2``,
i.e. ``H b = -a`` with (eq. 14)

    h_ij = delta_ij sum_m q_jm - sum_m q_im q_jm,
    a_k  = sum_m q_km f_km - sum_{m,j} q_km q_jm f_jm,

and ``b = -pinv(H) a`` (eq. 15). Because ``sum_k q_km = 1``, ``H`` is the Laplacian of the
graph whose edge weights are ``W_kj = sum_m q_km q_jm`` (k != j). That is what makes the
problem scale: ``q`` is stored sparsely, keeping only weights above ``weight_tol`` (a cut-off
radius for a KD-tree search), ``H`` is a sparse Laplacian, and ``pinv(H) a`` is a sparse solve
per connected group (the minimum-norm solution: offsets have zero mean in each group).

When the trajectories are split into groups (outlier detection), each group is aligned on its
own: the objective keeps only pairs ``k, j`` of the same group, which gives the same formulas
with ``sum_k q_km`` replaced by the group's share of point ``m``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import spsolve
from scipy.spatial import cKDTree

from policy_align_ros.learning.thinning import thin_each, thin_trajectories

__all__ = [
    "LocalModelTable",
    "local_model_table",
    "dense_local_model_table",
    "alignment_system",
    "solve_offsets",
    "solve_chained_offsets",
    "dense_offsets",
]

_CHUNK_PAIRS = 4_000_000  # bound on neighbour pairs held at once
_TREE_MAX_PAIRS = 20_000_000  # above this many neighbour pairs, a tree search is too slow
_EXACT_MAX_SECONDS = 5.0  # estimated time beyond which the blocked approximation is used
_DENSE_MAX_ENTRIES = 20_000_000  # (M, K) distances the exact dense search may compute
_BLOCK_QUERIES = 60_000  # query points of the approximate (blocked) table
_BLOCK_REFERENCES = 250_000  # reference points of the approximate table


@dataclass
class LocalModelTable:
    """Sparse table of ``(m, k, q_km, f_km)`` for the non-negligible responsibilities.

    Attributes
    ----------
    rows, cols : ndarray of int, shape (nnz,)
        Query point index ``m`` and trajectory index ``k``.
    q : ndarray, shape (nnz,)
        Responsibilities ``q_km`` (each row sums to 1).
    f : ndarray, shape (nnz,)
        Local predictions ``f_km = f_k(x_m)``.
    source : ndarray of int, shape (nnz,)
        The sample (index into the arrays the table was built from) whose potential is
        ``f_km``: :meth:`with_potential` swaps the potentials without a new search.
    weights : ndarray, shape (n_points,)
        Number of samples each query point stands for (1 without merging).
    n_points, n_trajectories : int
        Query points and ``K``.
    """

    rows: np.ndarray
    cols: np.ndarray
    q: np.ndarray
    f: np.ndarray
    source: np.ndarray
    weights: np.ndarray
    n_points: int
    n_trajectories: int

    def with_potential(self, phi: np.ndarray) -> LocalModelTable:
        """The same table for other potential estimates ``phi`` (M,) at the same samples
        (the responsibilities depend on the states only)."""
        return replace(self, f=np.asarray(phi, dtype=float)[self.source])


def local_model_table(
    X: np.ndarray,
    labels: np.ndarray,
    phi: np.ndarray,
    sigma2: float,
    *,
    weight_tol: float = 1e-12,
    merge_tol: float = 0.1,
    max_neighbours: int = 32,
    closest: np.ndarray | None = None,
) -> LocalModelTable:
    """Responsibilities and local predictions, keeping weights above ``weight_tol``.

    Parameters
    ----------
    X : ndarray, shape (M, n)
        All points, trajectories stored contiguously.
    labels : ndarray of int, shape (M,)
        Trajectory index ``k`` of each point, non-decreasing, values in ``0..K-1``.
    phi : ndarray, shape (M,)
        Potential estimates along each trajectory.
    sigma2 : float
        Kernel width ``sigma^2`` (squared state units).
    weight_tol : float
        Weights ``w_k(x_m)`` below this are dropped (cut-off radius
        ``sqrt(-2 sigma^2 log weight_tol)``).
    merge_tol : float
        Samples closer than ``merge_tol * sigma`` along a trajectory are merged: into one
        reference point of the nearest-neighbour models, and into one query point that
        counts for all of them in the objective (0 keeps every sample, as in the paper).
    max_neighbours : int
        Only used when the exact table would take too long or too much memory (many
        trajectories whose kernels overlap, typical near a common attractor in high
        dimension): each point then sees the ``max_neighbours`` trajectories that come
        closest to its own, and samples are merged more coarsely (see ``_blocked_table``).
    closest : ndarray, shape (K, K), optional
        Closest approaches between trajectories (``bandwidth.closest_approach_matrix``),
        which choose those neighbours; computed on thinned trajectories when missing.

    Returns
    -------
    LocalModelTable
    """
    K = int(labels[-1]) + 1
    radius = float(np.sqrt(-2.0 * sigma2 * np.log(weight_tol)))
    ref = thin_trajectories(X, labels, spacing=merge_tol * np.sqrt(sigma2))
    tree = cKDTree(X[ref])
    # A few hundred probes estimate the neighbour count well enough to choose a search
    # (counting is itself a search: in many dimensions, thousands of probes cost seconds).
    sample = X[ref][:: max(1, len(ref) // 256)]
    per_point = max(1.0, tree.count_neighbors(cKDTree(sample), radius) / len(sample))
    pairs = per_point * len(ref)
    # Rough costs in seconds: a tree search pays per neighbour pair found, the dense search
    # per distance computed (one matrix product per trajectory, far cheaper per item).
    # The exact table is built the cheaper way when that is affordable; otherwise (many
    # overlapping trajectories) the blocked approximation.
    costs = {}
    if pairs <= _TREE_MAX_PAIRS:
        costs["tree"] = 1e-6 * pairs
    if len(ref) * K <= _DENSE_MAX_ENTRIES:
        costs["dense"] = 5e-10 * len(ref) ** 2 * (X.shape[1] + 10)
    mode = min(costs, key=costs.get) if costs else None
    if mode is None or costs[mode] > _EXACT_MAX_SECONDS:
        return _blocked_table(X, labels, phi, sigma2, radius, merge_tol, max_neighbours,
                              closest)
    weights = np.diff(np.append(ref, len(X))).astype(float)
    X_ref, labels_ref = X[ref], labels[ref]
    if mode == "tree":
        searches = _nearest_per_trajectory_tree(X_ref, labels_ref, tree, labels_ref, radius,
                                                per_point)
    else:
        searches = _nearest_per_trajectory_dense(X_ref, labels_ref, X_ref, labels_ref, radius)
    return _assemble(labels_ref, ref, ref, phi, weights, searches, sigma2, K)


def _assemble(labels, query, ref, phi, weights, searches, sigma2, K) -> LocalModelTable:
    """Table from the own-trajectory entries (distance 0) and the neighbour searches.

    ``query`` and ``ref`` are the sample indices of the query and reference points; the
    searches index into them.
    """
    M = len(labels)
    rows_parts = [np.arange(M)]
    cols_parts = [labels.astype(np.int64)]
    d_parts = [np.zeros(M)]
    source_parts = [np.asarray(query, dtype=np.int64)]
    for i, k, j, d2 in searches:
        rows_parts.append(i)
        cols_parts.append(k)
        d_parts.append(d2)
        source_parts.append(ref[j])
    rows = np.concatenate(rows_parts)
    cols = np.concatenate(cols_parts)
    d2 = np.concatenate(d_parts)
    source = np.concatenate(source_parts)
    w = np.exp(-0.5 * d2 / sigma2)
    q = w / np.bincount(rows, weights=w, minlength=M)[rows]
    return LocalModelTable(rows, cols, q, np.asarray(phi, dtype=float)[source], source,
                           weights, M, K)


def _blocked_table(X, labels, phi, sigma2, radius, merge_tol, max_neighbours, closest):
    """Approximate table for large data sets whose kernels overlap massively.

    Queries and references are merged along each trajectory with spacings that bound their
    numbers (``_BLOCK_QUERIES``, ``_BLOCK_REFERENCES``), never finer than ``merge_tol``
    sigma; each query sees the ``max_neighbours`` trajectories that approach its own most
    closely. Weakly connected trajectories have few neighbours, so the links that outlier
    detection looks for are kept; what is dropped are the far members of crowds.

    The distances are expanded as ``|q|^2 + |r|^2 - 2 q.r``, on states centred first (the
    mean of all samples subtracted): far from the origin the expansion cancels (states at
    1e8 state units changed the offsets in the second digit). The thinning works on the
    states as given, so on ordinary data centring changes the table by round-off only.
    """
    from policy_align_ros.learning.bandwidth import (
        HEURISTIC_POINTS,
        closest_approach_matrix,
    )

    K = int(labels[-1]) + 1
    starts = np.searchsorted(labels, np.arange(K + 1))
    if closest is None:
        trajs = [X[starts[k]:starts[k + 1]] for k in range(K)]
        closest = closest_approach_matrix(thin_each(trajs, HEURISTIC_POINTS))
    steps = np.linalg.norm(np.diff(X, axis=0), axis=1)
    steps[labels[1:] != labels[:-1]] = 0.0
    total_arc = float(steps.sum())
    fine = merge_tol * np.sqrt(sigma2)
    ref_spacing = max(fine, total_arc / _BLOCK_REFERENCES)
    query_spacing = max(ref_spacing, total_arc / _BLOCK_QUERIES)
    ref = thin_trajectories(X, labels, spacing=ref_spacing)
    qry = thin_trajectories(X, labels, spacing=query_spacing)
    weights = np.diff(np.append(qry, len(X))).astype(float)
    ref_starts = np.searchsorted(labels[ref], np.arange(K + 1))
    qry_starts = np.searchsorted(labels[qry], np.arange(K + 1))
    centred = X - X.mean(axis=0)
    R = centred[ref]
    sq_r = np.einsum("ij,ij->i", R, R)
    neighbours = np.argsort(closest, axis=1)[:, :max_neighbours]
    r2 = radius**2

    def searches():
        for k in range(K):
            rows = np.arange(qry_starts[k], qry_starts[k + 1])
            Q = centred[qry[rows]]
            cand = neighbours[k][np.isfinite(closest[k, neighbours[k]])]
            segs = [np.arange(ref_starts[j], ref_starts[j + 1]) for j in cand]
            cols = np.concatenate(segs)
            d2 = np.einsum("ij,ij->i", Q, Q)[:, None] + sq_r[cols][None, :]
            d2 -= 2.0 * Q @ R[cols].T
            offset = 0
            for j, seg in zip(cand, segs, strict=True):
                block = d2[:, offset:offset + len(seg)]
                offset += len(seg)
                arg = np.argmin(block, axis=1)
                best = np.maximum(block[np.arange(len(rows)), arg], 0.0)
                keep = best <= r2
                if keep.any():
                    yield rows[keep], np.full(int(keep.sum()), j), seg[arg[keep]], best[keep]

    return _assemble(labels[qry], qry, ref, phi, weights, searches(), sigma2, K)


def _nearest_per_trajectory_tree(X, labels, tree, ref_labels, radius, per_point):
    """Yield ``(m, k, reference index, squared distance)`` of the nearest reference point
    of every other trajectory within ``radius``, by chunked KD-tree pair searches."""
    M = len(X)
    chunk = int(max(256, min(M, _CHUNK_PAIRS // per_point)))
    for start in range(0, M, chunk):
        stop = min(M, start + chunk)
        pairs = cKDTree(X[start:stop]).sparse_distance_matrix(
            tree, radius, output_type="ndarray"
        )
        i = pairs["i"].astype(np.int64) + start
        j = pairs["j"]
        k = ref_labels[j].astype(np.int64)
        foreign = k != labels[i]
        i, j, k, dist = i[foreign], j[foreign], k[foreign], pairs["v"][foreign]
        order = np.lexsort((dist, k, i))
        i, j, k, dist = i[order], j[order], k[order], dist[order]
        first = np.ones(len(i), dtype=bool)
        first[1:] = (i[1:] != i[:-1]) | (k[1:] != k[:-1])
        yield i[first], k[first], j[first], dist[first] ** 2


def _nearest_per_trajectory_dense(X, labels, R, ref_labels, radius):
    """Same as the tree search, from distance blocks of whole reference trajectories.

    The nearest reference point of every query is found in single precision (half the
    work of the matrix product, which dominates),
    on data centred first so that the expanded distances do not cancel; its squared
    distance is then computed again exactly. Two references within single-precision
    round-off of each other may swap, which changes a weight by as little.
    """
    centre = R.mean(axis=0)
    X32 = (X - centre).astype(np.float32)
    R32 = (R - centre).astype(np.float32)
    sq_r = np.einsum("ij,ij->i", R32, R32)
    M = len(X)
    K = int(ref_labels[-1]) + 1
    bounds = np.searchsorted(ref_labels, np.arange(K + 1))
    per_block = max(1, _CHUNK_PAIRS // max(M, 1))
    k0 = 0
    while k0 < K:
        k1 = k0 + 1
        while k1 < K and bounds[k1 + 1] - bounds[k0] <= per_block:
            k1 += 1
        rows = slice(bounds[k0], bounds[k1])
        # ||x - r||^2 - ||x||^2: the same nearest r for every x, one pass less.
        part = sq_r[rows, None] - 2.0 * (R32[rows] @ X32.T)
        for k in range(k0, k1):
            block = part[bounds[k] - bounds[k0]:bounds[k + 1] - bounds[k0]]
            j = bounds[k] + np.argmin(block, axis=0)
            diff = X - R[j]
            best = np.einsum("ij,ij->i", diff, diff)
            m = np.flatnonzero((best <= radius**2) & (labels != k))
            yield m, np.full(len(m), k, dtype=np.int64), j[m], best[m]
        k0 = k1


def dense_local_model_table(
    X: np.ndarray, labels: np.ndarray, phi: np.ndarray, sigma2: float
) -> tuple[np.ndarray, np.ndarray]:
    """The paper's dense ``Q`` and ``F`` (shape (M, K) each); for tests and small data."""
    K = int(labels[-1]) + 1
    d2 = np.sum((X[:, None, :] - X[None, :, :]) ** 2, axis=-1)
    Q = np.empty((len(X), K))
    F = np.empty((len(X), K))
    for k in range(K):
        cols = np.flatnonzero(labels == k)
        nearest = cols[np.argmin(d2[:, cols], axis=1)]
        Q[:, k] = np.exp(-0.5 * d2[np.arange(len(X)), nearest] / sigma2)
        F[:, k] = phi[nearest]
    Q /= Q.sum(axis=1, keepdims=True)
    return Q, F


def alignment_system(
    table: LocalModelTable, groups: np.ndarray | None = None
) -> tuple[sp.csr_matrix, np.ndarray, sp.csr_matrix]:
    """Hessian ``H``, linear term ``a`` and graph weights ``W`` of eq. 14.

    Parameters
    ----------
    table : LocalModelTable
    groups : ndarray of int, shape (K,), optional
        Group of each trajectory; only pairs within a group enter the objective.

    Returns
    -------
    H : csr_matrix, shape (K, K)
        Graph Laplacian ``diag(W 1) - W``.
    a : ndarray, shape (K,)
    W : csr_matrix, shape (K, K)
        Edge weights ``W_kj = sum_m q_km q_jm`` for ``k != j`` in the same group.
    """
    rows, cols, q, f = table.rows, table.cols, table.q, table.f
    K, M = table.n_trajectories, table.n_points
    if groups is None:
        share = np.ones(len(rows))
        key = rows
        n_keys = M
    else:
        # A point's share and mean prediction are taken within each group separately:
        # one row of Q per (point, group) pair.
        pair = rows * np.int64(K) + groups[cols]
        unique_pairs, key = np.unique(pair, return_inverse=True)
        n_keys = len(unique_pairs)
        share = np.bincount(key, weights=q, minlength=n_keys)[key]
    mean_f = np.bincount(key, weights=q * f, minlength=n_keys)[key]
    count = table.weights[rows]
    a = np.bincount(cols, weights=count * q * (f * share - mean_f), minlength=K)

    Q = sp.csr_matrix((q, (key, cols)), shape=(n_keys, K))
    Qw = sp.csr_matrix((count * q, (key, cols)), shape=(n_keys, K))
    W = (Q.T @ Qw).tocsr()
    W.setdiag(0.0)
    W.eliminate_zeros()
    H = sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W
    return H.tocsr(), a, W


def solve_offsets(H: sp.spmatrix, a: np.ndarray) -> np.ndarray:
    """Minimum-norm solution ``b = -pinv(H) a`` of the Laplacian system (eq. 15).

    Each connected component of ``H`` is solved on its own with one node grounded, then
    shifted to zero mean, which is what the pseudo-inverse returns for a Laplacian whose
    right-hand side sums to zero on every component.
    """
    H = sp.csr_matrix(H)
    n_comp, comp = connected_components(H, directed=False)
    b = np.zeros(H.shape[0])
    for c in range(n_comp):
        idx = np.flatnonzero(comp == c)
        if len(idx) < 2:
            continue
        sub = H[idx][:, idx].tocsc()
        rest = sub[1:, 1:]
        if len(idx) == 2:
            x = -a[idx[1:]] / rest.toarray().ravel()
        else:
            x = spsolve(rest, -a[idx[1:]])
        b_c = np.concatenate(([0.0], np.atleast_1d(x)))
        b[idx] = b_c - b_c.mean()
    return b


def solve_chained_offsets(H: sp.spmatrix, a: np.ndarray, pairs: np.ndarray,
                          jumps: np.ndarray) -> np.ndarray:
    """Minimiser of eq. 14's objective with some offset differences fixed.

    Parameters
    ----------
    H : sparse matrix, shape (K, K)
        Laplacian of :func:`alignment_system`.
    a : ndarray, shape (K,)
    pairs : ndarray of int, shape (L, 2)
        Trajectories ``(p, q)`` whose offsets are tied, ``p < q``.
    jumps : ndarray, shape (L,)
        ``b_q - b_p`` for each pair (potential units).

    Returns
    -------
    ndarray, shape (K,)
        ``b = T beta + c``: ``c`` chains the fixed differences from the first member of
        each tied set, ``T`` maps one free offset per set to its members, and ``beta``
        solves the reduced system ``T' H T beta = -T' (H c + a)`` with
        :func:`solve_offsets`. Without pairs, :func:`solve_offsets` itself.
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    jumps = np.asarray(jumps, dtype=float).reshape(-1)
    K = H.shape[0]
    if len(jumps) != len(pairs):
        raise ValueError(f"jumps: {len(jumps)} values for {len(pairs)} pairs")
    if len(pairs) == 0:
        return solve_offsets(H, a)
    if not (np.all(pairs[:, 0] < pairs[:, 1]) and pairs.min() >= 0 and pairs.max() < K):
        raise ValueError(f"pairs must be (p, q) with 0 <= p < q < {K}")
    links = sp.csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(K, K))
    n_sets, member = connected_components(links, directed=False)
    c = np.zeros(K)
    # Chains are walked in index order: every pair's first member already has its level.
    for (p, q), jump in sorted(zip(pairs.tolist(), jumps.tolist(), strict=True)):
        c[q] = c[p] + jump
    T = sp.csr_matrix((np.ones(K), (np.arange(K), member)), shape=(K, n_sets))
    H = sp.csr_matrix(H)
    beta = solve_offsets((T.T @ H @ T).tocsr(), T.T @ (H @ c + a))
    b = T @ beta + c
    # Zero mean per connected part of the tied graph, as solve_offsets leaves its groups.
    n_comp, comp = connected_components(abs(H) + links + links.T, directed=False)
    return b - (np.bincount(comp, weights=b, minlength=n_comp) / np.bincount(comp))[comp]


def dense_offsets(Q: np.ndarray, F: np.ndarray) -> np.ndarray:
    """The paper's formulas verbatim: ``H``, ``a`` from dense ``Q``, ``F`` and ``-pinv(H) a``."""
    H = np.diag(Q.sum(axis=0)) - Q.T @ Q
    a = np.sum(Q * F, axis=0) - Q.T @ np.sum(Q * F, axis=1)
    return -np.linalg.pinv(H) @ a
