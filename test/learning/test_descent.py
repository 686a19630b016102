"""Descents of a learnt potential (policy_align_ros.learning.descent): minima, where a
capped descent stops, points merged."""

import warnings

import numpy as np
import pytest
from flows import bowl, two_wells

from policy_align_ros.learning import Trajectory
from policy_align_ros.learning.descent import (
    _descend,
    cluster_labels,
    flow_stops,
    learnt_minima,
    merge_points,
)
from policy_align_ros.learning.goal import starts_elsewhere
from policy_align_ros.learning.regressors import TrendKernelRegression


def test_minimum_of_a_known_quadratic_is_found_where_it_is():
    rng = np.random.default_rng(3)
    n = 5
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    A = (Q * np.geomspace(1.0, 100.0, n)) @ Q.T
    c = rng.normal(size=n)
    potential, gradient = bowl(A, c)
    starts = c + rng.normal(scale=2.0, size=(12, n))
    minima = learnt_minima(potential, gradient, starts, scale=4.0, speed=100.0)
    assert minima.points.shape == (1, n) and minima.n_escaped == 0
    np.testing.assert_allclose(minima.points[0], c, atol=1e-4)
    assert minima.values[0] == pytest.approx(0.0, abs=1e-8)


def test_a_model_descends_through_its_joint_evaluation_to_the_same_bits():
    # A model's predict and gradient are evaluated together at each step of a descent;
    # the descent must end where it does with the two called apart, to the last bit.
    rng = np.random.default_rng(4)
    X = rng.uniform(-2.0, 2.0, size=(240, 2))
    y = np.sum((X - [0.3, -0.4]) ** 2, axis=1) + 0.2 * np.sin(2.0 * X[:, 0])
    model = TrendKernelRegression(trend_form="quadratic", length_scale=0.6,
                                  kernel_ridge=1e-4, random_state=0)
    model.fit(X, y, groups=np.repeat(np.arange(12), 20))
    starts = rng.uniform(-2.0, 2.0, size=(9, 2))
    joint = learnt_minima(model.predict, model.gradient, starts, scale=4.0)
    apart = learnt_minima(lambda Z: model.predict(Z), lambda Z: model.gradient(Z), starts,
                          scale=4.0)
    assert len(joint.points) and np.array_equal(joint.points, apart.points)
    t = np.linspace(0.0, 1.0, 30)[:, None]
    demos = [Trajectory(x0 + t * ([0.3, -0.4] - x0), times=t[:, 0]) for x0 in starts]
    assert starts_elsewhere(demos, model.predict, model.gradient, 4.0, 1.0) == \
        starts_elsewhere(demos, lambda Z: model.predict(Z), lambda Z: model.gradient(Z),
                         4.0, 1.0)


def test_a_capped_descent_up_a_concave_slope_raises_no_overflow_warning():
    # Where the potential bends down, every secant step grows the next by 4 until it
    # overflows; the cap must take such a step without a warning the fit would pass on.
    def potential(X):
        return -0.5 * np.sum(X**2, axis=1)

    def gradient(X):
        return -X

    lo, hi = np.full(1, -1e6), np.full(1, 1e6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        end = _descend(potential, gradient, np.array([[1.0]]), lo, hi, 1e-9, 1.0, 700,
                       max_step=0.01)
    assert end[0, 0] == pytest.approx(1.0 + 700 * 0.01, rel=1e-6)  # every step capped


def test_two_wells_give_two_minima_and_a_falling_plane_gives_none():
    potential, gradient = two_wells()
    starts = np.array([[-1.2, 0.3], [-0.8, -0.2], [1.1, 0.2], [0.9, -0.3]])
    minima = learnt_minima(potential, gradient, starts, scale=2.0)
    assert len(minima.points) == 2
    np.testing.assert_allclose(np.sort(minima.points[:, 0]), [-1.0, 1.0], atol=0.02)
    plane = learnt_minima(lambda X: X[:, 0], lambda X: np.tile([1.0, 0.0], (len(X), 1)),
                          starts, scale=2.0)
    assert len(plane.points) == 0 and plane.n_escaped == len(starts)


def test_runs_stop_in_the_well_of_their_start_whatever_its_depth():
    # A deep well beside a shallow one: each start's run stops in its own well, inside
    # the data's box, never in the lower one.
    def potential(X):
        d_left = np.sum((X - [-1.0, 0.0]) ** 2, axis=1)
        d_right = np.sum((X - [1.0, 0.0]) ** 2, axis=1)
        return 0.01 * np.sum(X**2, axis=1) - 0.3 * np.exp(-d_left / 0.2) \
            - 3.0 * np.exp(-d_right / 0.2)

    def gradient(X, h=1e-6):
        return np.stack([(potential(X + h * e) - potential(X - h * e)) / (2 * h)
                         for e in np.eye(2)], axis=1)

    starts = np.array([[-1.4, 0.1], [1.3, -0.2], [-0.7, -0.1]])
    X = np.array([[-2.0, -1.0], [2.0, 1.0]])
    ends, inside = flow_stops(potential, gradient, starts, X, extent=4.0, speed=1.0)
    assert inside.all()
    np.testing.assert_allclose(ends[:, 0], [-1.0, 1.0, -1.0], atol=0.02)


def test_points_chained_closer_than_the_tolerance_are_one_the_lowest_kept():
    points = np.array([[0.0, 0.0], [0.08, 0.0], [0.16, 0.0], [1.0, 0.0]])
    labels = cluster_labels(points, 0.1)
    assert labels[0] == labels[1] == labels[2] != labels[3]
    merged, values = merge_points(points, np.array([3.0, 1.0, 2.0, 0.5]), 0.1)
    np.testing.assert_array_equal(merged, [[1.0, 0.0], [0.08, 0.0]])
    np.testing.assert_array_equal(values, [0.5, 1.0])

