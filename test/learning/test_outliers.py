"""Weakly connected groups (policy_align_ros.learning.outliers)."""

import numpy as np
import scipy.sparse as sp

from policy_align_ros.learning.outliers import largest_group, weakly_connected_groups


def _blocks(sizes, inner=1.0):
    n = sum(sizes)
    W = np.zeros((n, n))
    start = 0
    for size in sizes:
        W[start:start + size, start:start + size] = inner
        start += size
    np.fill_diagonal(W, 0.0)
    return W


def test_strongly_connected_graph_is_one_group():
    labels = weakly_connected_groups(sp.csr_matrix(_blocks([6])))
    assert np.all(labels == 0)


def test_weak_link_splits_and_largest_group_is_label_zero():
    W = _blocks([3, 5])
    W[0, 5] = W[5, 0] = 1e-11  # eigenvalue far below 1e-8
    labels = weakly_connected_groups(sp.csr_matrix(W), eigen_tol=1e-8)
    np.testing.assert_array_equal(labels, [1, 1, 1, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(largest_group(labels), [3, 4, 5, 6, 7])


def test_link_above_tolerance_keeps_groups_together():
    W = _blocks([3, 5])
    W[0, 5] = W[5, 0] = 1e-3
    assert np.all(weakly_connected_groups(sp.csr_matrix(W), eigen_tol=1e-8) == 0)


def test_recursive_split_of_three_groups_and_isolated_node():
    W = _blocks([4, 2, 6, 1])
    W[0, 4] = W[4, 0] = 1e-12
    W[5, 6] = W[6, 5] = 1e-12
    labels = weakly_connected_groups(sp.csr_matrix(W))
    assert len(set(labels.tolist())) == 4
    np.testing.assert_array_equal(np.flatnonzero(labels == 0), [6, 7, 8, 9, 10, 11])
    assert np.all(labels[:4] == labels[0])
    assert labels[12] not in labels[:12]
