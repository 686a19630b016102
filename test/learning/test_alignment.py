"""Sparse alignment against the paper's dense formulas (policy_align_ros.learning.alignment)."""

import numpy as np
import pytest

from policy_align_ros.experiments.toy import make_toy_dataset
from policy_align_ros.learning.alignment import (
    alignment_system,
    dense_local_model_table,
    dense_offsets,
    local_model_table,
    solve_chained_offsets,
    solve_offsets,
)
from policy_align_ros.learning.potential import euler_potential
from policy_align_ros.learning.thinning import thin_trajectories


def _problem(seed=0, K=12, N=15):
    data = make_toy_dataset("parabola", K, N, np.random.default_rng(seed))
    X = np.concatenate([t.positions for t in data.trajectories])
    labels = np.repeat(np.arange(K), N)
    phi = np.concatenate([euler_potential(t.positions) for t in data.trajectories])
    return X, labels, phi, data


@pytest.mark.parametrize("sigma2", [0.05, 0.3, 2.0])
def test_sparse_offsets_agree_with_dense_formulas(sigma2):
    X, labels, phi, _ = _problem()
    Q, F = dense_local_model_table(X, labels, phi, sigma2)
    b_dense = dense_offsets(Q, F)
    table = local_model_table(X, labels, phi, sigma2, weight_tol=1e-300, merge_tol=0.0)
    H, a, _ = alignment_system(table)
    b_sparse = solve_offsets(H, a)
    b_dense -= b_dense.mean()
    assert np.linalg.norm(b_sparse - b_dense) <= 1e-8 * np.linalg.norm(b_dense)
    # H is the paper's h_ij and a its a_k.
    H_dense = np.diag(Q.sum(0)) - Q.T @ Q
    np.testing.assert_allclose(H.toarray(), H_dense, rtol=1e-8, atol=1e-10)
    a_dense = np.sum(Q * F, 0) - Q.T @ np.sum(Q * F, 1)
    np.testing.assert_allclose(a, a_dense, rtol=1e-8, atol=1e-10)


def test_default_cutoff_and_merging_stay_close_to_dense():
    X, labels, phi, _ = _problem(seed=1)
    b_dense = dense_offsets(*dense_local_model_table(X, labels, phi, 0.3))
    b_dense -= b_dense.mean()
    cut = local_model_table(X, labels, phi, 0.3, merge_tol=0.0)  # default weight_tol
    b = solve_offsets(*alignment_system(cut)[:2])
    assert np.linalg.norm(b - b_dense) <= 1e-6 * np.linalg.norm(b_dense)
    merged = local_model_table(X, labels, phi, 0.3)  # default merge_tol
    b = solve_offsets(*alignment_system(merged)[:2])
    assert np.linalg.norm(b - b_dense) <= 0.05 * np.linalg.norm(b_dense)


def test_offsets_absorb_a_constant_added_to_any_trajectory():
    X, labels, phi, _ = _problem(seed=2)
    shifts = np.random.default_rng(5).normal(scale=10.0, size=labels.max() + 1)
    b0 = solve_offsets(*alignment_system(local_model_table(X, labels, phi, 0.3))[:2])
    b1 = solve_offsets(
        *alignment_system(local_model_table(X, labels, phi + shifts[labels], 0.3))[:2]
    )
    aligned0 = phi + b0[labels]
    aligned1 = phi + shifts[labels] + b1[labels]
    diff = aligned1 - aligned0
    np.testing.assert_allclose(diff, diff.mean(), atol=1e-8)


def test_aligned_potentials_match_the_truth_up_to_a_constant():
    X, labels, phi, data = _problem(seed=3, K=30, N=30)
    b = solve_offsets(*alignment_system(local_model_table(X, labels, phi, 0.05))[:2])
    truth = np.concatenate(data.phi)
    err = phi + b[labels] - truth
    assert np.std(err) < 0.2 * np.std(truth)
    unaligned = phi - truth
    assert np.std(err) < 0.1 * np.std(unaligned)


def test_merging_keeps_counts_and_resting_robot_is_cheap():
    # A trajectory that rests at its goal for 5000 samples collapses to a few queries.
    rest = np.zeros((5000, 2))
    move = np.column_stack([np.linspace(-1, 0, 50), np.zeros(50)])
    X = np.concatenate([np.concatenate([move, rest]), move[::-1] + [0.0, 0.01]])
    labels = np.repeat([0, 1], [5050, 50])
    keep = thin_trajectories(X, labels, spacing=0.01)
    assert len(keep) < 200
    phi = np.concatenate([euler_potential(X[:5050]), euler_potential(X[5050:])])
    table = local_model_table(X, labels, phi, 0.01, merge_tol=0.1)
    assert table.weights.sum() == len(X)
    assert table.n_points < 200


def test_disconnected_components_are_each_zero_mean():
    X, labels, phi, _ = _problem(seed=4)
    far = X.copy()
    far[labels >= 6] += 100.0  # two clouds that never see each other
    table = local_model_table(far, labels, phi, 0.3)
    H, a, W = alignment_system(table)
    assert W[:6, 6:].nnz == 0
    b = solve_offsets(H, a)
    assert abs(b[:6].mean()) < 1e-10
    assert abs(b[6:].mean()) < 1e-10


def test_chained_offsets_keep_the_ties_and_minimise_the_rest():
    X, labels, phi, _ = _problem(seed=2)
    H, a, _ = alignment_system(local_model_table(X, labels, phi, 0.3))
    pairs = np.array([[0, 1], [1, 2], [5, 9]])
    jumps = np.array([0.3, -0.2, 1.5])
    b = solve_chained_offsets(H, a, pairs, jumps)
    np.testing.assert_allclose(b[pairs[:, 1]] - b[pairs[:, 0]], jumps, atol=1e-12)
    # Stationary along every direction the ties leave free: the gradient H b + a sums to
    # zero over each tied set and vanishes on the untied trajectories.
    grad = H @ b + a
    free = np.setdiff1d(np.arange(len(b)), pairs)
    np.testing.assert_allclose(grad[free], 0.0, atol=1e-9)
    assert abs(grad[[0, 1, 2]].sum()) < 1e-9 and abs(grad[[5, 9]].sum()) < 1e-9
    assert abs(b.mean()) < 1e-10
    # Ties that agree with the free solution change nothing; no ties is solve_offsets.
    b0 = solve_offsets(H, a)
    np.testing.assert_allclose(
        solve_chained_offsets(H, a, pairs, b0[pairs[:, 1]] - b0[pairs[:, 0]]), b0, atol=1e-9)
    np.testing.assert_array_equal(solve_chained_offsets(H, a, np.zeros((0, 2)), []), b0)
    with pytest.raises(ValueError, match=r"^jumps\b.*\b2\b.*\b3\b"):
        solve_chained_offsets(H, a, pairs, jumps[:2])
    with pytest.raises(ValueError, match="^pairs"):
        solve_chained_offsets(H, a, pairs[:, ::-1], jumps)


def test_blocked_approximation_matches_the_exact_table(monkeypatch):
    # Force the approximation used for large overlapping data on a small problem.
    import policy_align_ros.learning.alignment as alignment

    X, labels, phi, data = _problem(seed=6, K=40, N=40)
    truth = np.concatenate(data.phi)
    exact = solve_offsets(*alignment_system(local_model_table(X, labels, phi, 0.05))[:2])
    monkeypatch.setattr(alignment, "_TREE_MAX_PAIRS", 0)
    monkeypatch.setattr(alignment, "_DENSE_MAX_ENTRIES", 0)
    monkeypatch.setattr(alignment, "_BLOCK_QUERIES", 600)  # coarser than every sample
    table = local_model_table(X, labels, phi, 0.05, max_neighbours=8)
    assert table.n_points <= 700
    assert table.weights.sum() == len(X)
    assert np.bincount(table.rows).max() <= 1 + 8  # own trajectory + max_neighbours
    approx = solve_offsets(*alignment_system(table)[:2])

    def nmse(b):
        err = phi + b[labels] - truth
        return np.var(err) / np.var(truth)

    assert nmse(approx) < 1.5 * nmse(exact) + 1e-3


@pytest.mark.parametrize("offset", [0.0, 1e7, 1e8])
def test_blocked_table_is_exact_far_from_the_origin(monkeypatch, offset):
    # With every sample kept and every trajectory a neighbour, the blocked table is the
    # exact one; its expanded distances on uncentred states at 1e8 moved the offsets in
    # the second digit.
    import policy_align_ros.learning.alignment as alignment

    X, labels, phi, _ = _problem(seed=2, K=8, N=20)
    X = X + offset
    exact = solve_offsets(*alignment_system(
        local_model_table(X, labels, phi, 0.05, merge_tol=0.0))[:2])
    monkeypatch.setattr(alignment, "_TREE_MAX_PAIRS", 0)
    monkeypatch.setattr(alignment, "_DENSE_MAX_ENTRIES", 0)
    monkeypatch.setattr(alignment, "_BLOCK_QUERIES", 10**12)  # no merging of samples
    monkeypatch.setattr(alignment, "_BLOCK_REFERENCES", 10**12)
    blocked_table = local_model_table(X, labels, phi, 0.05, merge_tol=0.0, max_neighbours=8)
    assert blocked_table.n_points == len(X)
    blocked = solve_offsets(*alignment_system(blocked_table)[:2])
    np.testing.assert_allclose(blocked, exact, atol=1e-6 * np.ptp(phi))
