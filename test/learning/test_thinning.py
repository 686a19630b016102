"""Tests of the one thinning function (policy_align_ros.learning.thinning)."""

import numpy as np
import pytest

from policy_align_ros.learning.thinning import thin_each, thin_trajectories


def _demos(rng, sizes, n=2):
    """Random walks of the given lengths, stored one after the other, and their groups."""
    X = np.concatenate([np.cumsum(rng.normal(size=(s, n)), axis=0) for s in sizes])
    return X, np.repeat(np.arange(len(sizes)), sizes)


def test_thinning_keeps_order_and_every_trajectory():
    rng = np.random.default_rng(9)
    groups = np.repeat(np.arange(30), rng.integers(50, 400, 30))
    idx = thin_trajectories(None, groups, 3000, rule="stride", rng=rng)
    assert np.all(np.diff(idx) > 0)
    assert set(groups[idx]) == set(range(30))  # thinning is enough: all kept
    assert 1500 <= len(idx) <= 3000
    # Too few points for 25 samples of each trajectory: whole trajectories are dropped.
    idx = thin_trajectories(None, groups, 300, rule="stride", rng=rng)
    assert len(set(groups[idx])) < 30 and len(idx) <= 300
    np.testing.assert_array_equal(
        thin_trajectories(None, groups, 10**6, rule="stride", rng=rng), np.arange(len(groups))
    )


def test_share_keeps_everything_under_the_budget_and_shares_it_over():
    rng = np.random.default_rng(0)
    X, g = _demos(rng, [300, 40, 500])
    np.testing.assert_array_equal(thin_trajectories(X, g, len(X)), np.arange(len(X)))
    idx = thin_trajectories(X, g, 300)
    assert np.all(np.diff(idx) > 0)
    counts = np.bincount(g[idx])
    assert counts[1] == 40  # shorter than its share of 100: kept whole
    assert counts[0] <= 100 and counts[2] <= 100
    # The first and last samples of a moving demonstration are kept.
    assert {0, 299, 340, 839} <= set(idx.tolist())


def test_share_is_even_in_arc_length_so_rest_adds_no_weight():
    # A line walked at unit speed, then 900 samples at rest at its end.
    line = np.column_stack([np.arange(100.0), np.zeros(100)])
    X = np.vstack([line, np.repeat(line[-1:], 900, axis=0)])
    g = np.zeros(len(X), dtype=int)
    idx = thin_trajectories(X, g, 50)
    assert idx.max() == 99  # nothing of the rest but the first sample reaching the end
    steps = np.diff(X[idx, 0])
    assert steps.max() - steps.min() <= 1.0


def test_share_keeps_the_ends_of_a_demonstration_that_does_not_move():
    X = np.vstack([np.zeros((200, 2)), np.cumsum(np.ones((200, 2)), axis=0)])
    g = np.repeat([0, 1], 200)
    idx = thin_trajectories(X, g, 100)
    np.testing.assert_array_equal(idx[g[idx] == 0], [0, 199])
    capped = thin_trajectories(X, g, 100, rule="cap")
    np.testing.assert_array_equal(capped[g[capped] == 0], [0])
    np.testing.assert_array_equal(capped[g[capped] == 1], idx[g[idx] == 1])


def test_cap_thins_every_long_demonstration_even_under_the_budget():
    rng = np.random.default_rng(1)
    X, g = _demos(rng, [300, 20])
    idx = thin_trajectories(X, g, 1000, rule="cap")  # share 500: nothing to thin
    np.testing.assert_array_equal(idx, np.arange(len(X)))
    idx = thin_trajectories(X, g, 400, rule="cap")  # share 200, although 320 <= 400
    assert np.bincount(g[idx]).tolist()[1] == 20 and np.sum(g[idx] == 0) <= 200
    parts = thin_each([X[:300], X[300:]], 400)
    np.testing.assert_array_equal(np.concatenate(parts), X[idx])
    assert [len(p) for p in parts] == np.bincount(g[idx]).tolist()
    assert thin_each([], 10) == []


def test_spacing_keeps_the_first_sample_of_every_piece_of_arc_length():
    # A trajectory that rests at its goal for 5000 samples collapses to a few samples.
    rest = np.zeros((5000, 2))
    move = np.column_stack([np.linspace(-1, 0, 50), np.zeros(50)])
    X = np.concatenate([np.concatenate([move, rest]), move[::-1] + [0.0, 0.01]])
    labels = np.repeat([0, 1], [5050, 50])
    keep = thin_trajectories(X, labels, spacing=0.05)
    assert len(keep) < 60 and keep[0] == 0 and 5050 in keep  # every demonstration's start
    # Every sample lies within the spacing (along its demonstration) of the kept one before.
    last = np.maximum.accumulate(np.where(np.isin(np.arange(len(X)), keep), np.arange(len(X)),
                                          0))
    steps = np.linalg.norm(np.diff(X, axis=0), axis=1)
    arc = np.concatenate(([0.0], np.cumsum(steps)))
    assert np.all(arc - arc[last] < 0.05 + 1e-12)
    np.testing.assert_array_equal(thin_trajectories(X, labels, spacing=0.0), np.arange(len(X)))


def test_bad_arguments():
    X, g = np.zeros((5, 2)), np.zeros(5, dtype=int)
    with pytest.raises(ValueError, match="max_points.*spacing"):
        thin_trajectories(X, g, 3, spacing=0.1)
    with pytest.raises(ValueError, match="max_points.*spacing"):
        thin_trajectories(X, g)
    with pytest.raises(ValueError, match="rule.*'random'"):
        thin_trajectories(X, g, 3, rule="random")
    with pytest.raises(ValueError, match="rng"):
        thin_trajectories(X, g, 3, rule="stride")
