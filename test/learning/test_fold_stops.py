"""Where the CV folds' models stop a run (policy_align_ros.learning.fold_stops)."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.fold_stops import (
    STOP_SPREAD_LIMIT,
    settle,
    settled_speed,
    stop_spread,
)

sys.path.insert(0, str(Path(__file__).parent))
from flows import quadratic_flow  # noqa: E402


class _Bowl:
    """A regressor whose potential is ``0.5 |x - centre|^2``."""

    def __init__(self, centre):
        self.centre = np.asarray(centre, dtype=float)

    def gradient(self, X):
        return X - self.centre


def _model(centre, fold_centres, spacing=0.01):
    """A fitted-model stand-in: the bowl at ``centre`` and fold models at
    ``fold_centres``."""
    own = _Bowl(centre)
    return SimpleNamespace(policy=lambda X: -own.gradient(X), n_features_in_=len(centre),
                           fold_regressors_=[_Bowl(c) for c in fold_centres],
                           support_spacing_=spacing)


def test_the_spread_is_the_farthest_fold_stop_over_the_travel():
    model = _model([0.0, 0.0], [[0.02, 0.0], [0.0, -0.3]])
    found = stop_spread(model, np.array([2.0, 0.0]), 0.1, 300)
    np.testing.assert_allclose(found.stop, [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(found.fold_stops, [[0.02, 0.0], [0.0, -0.3]], atol=1e-9)
    assert found.travel == pytest.approx(2.0)
    assert found.spread == pytest.approx(0.3 / 2.0)
    assert found.uncertain
    assert not stop_spread(_model([0.0, 0.0], [[0.05, 0.0]]), np.array([2.0, 0.0]), 0.1,
                           300).uncertain  # 2.5 % of the travel


def test_the_runs_follow_the_projection():
    # Motion along the first axis only: every run keeps its start's second coordinate.
    model = _model([0.0, 0.0], [[0.0, 5.0], [0.4, 0.0]])

    def project(x, i, v):
        return np.array([v[0], 0.0])

    found = stop_spread(model, np.array([1.0, 0.7]), 0.1, 300, project)
    np.testing.assert_allclose(found.stop, [0.0, 0.7], atol=1e-9)
    np.testing.assert_allclose(found.fold_stops[:, 1], 0.7)
    # The fold whose centre lies across the constraint stops where the model stops.
    np.testing.assert_allclose(found.fold_stops[0], found.stop, atol=1e-9)
    assert found.spread == pytest.approx(0.4)


def test_a_start_at_the_stop_measures_against_the_floor_and_no_folds_say_nothing():
    model = _model([0.0, 0.0], [[0.001, 0.0]], spacing=0.1)
    found = stop_spread(model, np.zeros(2), 0.1, 300)
    assert found.travel == pytest.approx(0.1)
    assert found.spread == pytest.approx(0.01, rel=1e-6)
    assert stop_spread(model, np.zeros(2), 0.1, 300, floor=0.01).spread == pytest.approx(
        0.1, rel=1e-6)
    alone = stop_spread(_model([0.0, 0.0], []), np.ones(2), 0.1, 50)
    assert np.isnan(alone.spread) and not alone.uncertain
    assert alone.fold_stops.shape == (0, 2)


@pytest.mark.parametrize(("x0", "dt", "steps", "message"), [
    (np.ones(3), 0.1, 10, r"x0\b.*\b2\b"),
    (np.array([np.nan, 0.0]), 0.1, 10, r"x0\b.*finite"),
    (np.ones(2), 0.0, 10, r"dt\b"),
    (np.ones(2), np.inf, 10, r"dt\b"),
    (np.ones(2), 0.1, 0, r"steps\b"),
])
def test_bad_arguments_are_named(x0, dt, steps, message):
    with pytest.raises(ValueError, match=message):
        stop_spread(_model([0.0, 0.0], []), x0, dt, steps)


def test_settle_is_explicit_euler_until_the_command_falls_to_the_settled_speed():
    end = settle(lambda X: -X, np.array([1.0]), 0.5, 3)
    assert end == pytest.approx([0.125])
    # Commands 1, 0.5, 0.25 move it; at 0.125 (<= 0.2) it has stopped.
    assert settle(lambda X: -X, np.array([1.0]), 0.5, 100, settled=0.2) == pytest.approx(
        [0.125])


def test_folds_of_an_exact_quadratic_agree_where_the_model_stops():
    rng = np.random.default_rng(0)
    A, centre = np.array([[2.0, 0.3], [0.3, 1.0]]), np.array([0.2, -0.1])
    trajs = [quadratic_flow(A, centre, rng.uniform(-1, 1, 2), 60, 0.05) for _ in range(8)]
    model = PolicyAlign(random_state=0).fit(trajs)
    assert len(model.fold_regressors_) >= 2
    direction = np.array([1.0, 2.0]) / np.sqrt(5.0)

    def project(x, i, v):  # a constraint no demonstration showed
        return v - direction * (direction @ v)

    for x0 in ([0.9, -0.8], [-0.7, 0.6]):
        for proj in (None, project):
            found = stop_spread(model, np.array(x0), 0.05, 300, proj)
            assert found.spread < STOP_SPREAD_LIMIT / 5
    found = stop_spread(model, np.array([0.9, -0.8]), 0.05, 300)
    np.testing.assert_allclose(found.stop, centre, atol=0.02)


def test_a_run_has_stopped_at_one_percent_of_the_typical_speed_of_a_timed_model():
    timed = SimpleNamespace(timed_=True, fit_summary_={"goal": {"typical_speed": 0.4}})
    assert settled_speed(timed) == pytest.approx(0.004)
    # Per sample, or without a goal report: no speed to compare with, the runs go on.
    assert settled_speed(SimpleNamespace(timed_=False, fit_summary_=timed.fit_summary_)) == 0
    assert settled_speed(SimpleNamespace(timed_=True, fit_summary_={})) == 0
