"""The fit's figure (policy_align_ros.data.fit_figure): what it draws, computed."""

import numpy as np
import pytest

from policy_align_ros.data.fit_figure import fit_views, plot_fit, policy_runs
from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.learning.goal import GOAL_MERGE
from policy_align_ros.learning.reach import REACH_TIME

GOAL = np.array([0.4, -0.3])
A = np.array([[1.5, 0.4], [0.4, 0.8]])


def _flows(starts, dt=0.05, steps=200):
    """Exact Euler flows of the potential (x - GOAL)' A (x - GOAL) / 2 from ``starts``."""
    out = []
    for x0 in starts:
        X = [np.asarray(x0, dtype=float)]
        for _ in range(steps - 1):
            X.append(X[-1] - dt * A @ (X[-1] - GOAL))
        out.append(Trajectory(np.array(X), times=dt * np.arange(steps)))
    return out


@pytest.fixture(scope="module")
def fitted():
    rng = np.random.default_rng(0)
    train = _flows(GOAL + rng.uniform(-2.0, 2.0, size=(8, 2)))
    held = _flows(GOAL + rng.uniform(-2.0, 2.0, size=(2, 2)))
    return PolicyAlign(random_state=0).fit(train), train, held


def test_policy_runs_are_euler_steps_and_stop_where_numbers_end():
    starts = np.array([[1.0, -2.0], [3.0, 0.5]])
    times, paths = policy_runs(lambda X: -X, starts, horizon=1.0, dt=0.1)
    assert paths.shape == (11, 2, 2)
    np.testing.assert_allclose(times, 0.1 * np.arange(11))
    np.testing.assert_allclose(paths[-1], 0.9**10 * starts, rtol=1e-12)

    def blows_up(X):  # the second run leaves the finite numbers at once
        V = -X.copy()
        V[1] = np.inf
        return V

    _, paths = policy_runs(blows_up, starts, horizon=1.0, dt=0.1)
    assert np.all(np.isfinite(paths)) and np.array_equal(paths[-1, 1], starts[1])


def test_a_diverging_run_stops_at_the_box_it_is_given():
    # A policy pushing away from the origin: runs grow by 1.5 times a step, unbounded.
    starts = np.array([[1.0, -2.0], [0.1, 0.1]])
    box = (np.array([-5.0, -5.0]), np.array([5.0, 5.0]))
    _, paths = policy_runs(lambda X: 5.0 * X, starts, horizon=10.0, dt=0.1, bounds=box)
    assert np.all(paths >= box[0]) and np.all(paths <= box[1])
    last = paths[-1]
    # Each run stopped at its last state inside the box: one more step would leave it.
    assert np.all(np.abs(1.5 * last).max(axis=1) > 5.0)
    np.testing.assert_allclose(paths[1, 0], 1.5 * starts[0])


def test_a_good_fit_follows_its_estimates_and_every_run_arrives(fitted):
    model, train, held = fitted
    views = fit_views(model, train, held)
    np.testing.assert_allclose(views["goal"], GOAL, atol=0.02)
    assert views["measured_to"] == "the demonstrated goal"
    assert np.min(np.linalg.norm(views["minima"] - GOAL, axis=1)) < 0.02
    assert len(views["potential"]) == len(train)
    for _, s, estimate, learnt in views["potential"]:
        assert s[0] == 0.0 and s[-1] == 1.0
        assert np.max(np.abs(learnt - estimate)) < 0.01 * np.ptp(estimate)
    assert [run["held"] for run in views["runs"]] == [False] * 8 + [True] * 2
    for run in views["runs"]:  # from every start, new ones too, home within 3 durations
        arrived = run["t"][np.flatnonzero(run["run"] < GOAL_MERGE)]
        assert arrived.size and arrived[0] < REACH_TIME
    assert views["fold_ratios"] and max(views["fold_ratios"]) < 0.1
    assert views["new_start_minima"].shape == (0, 2)  # every new start reaches the bowl's


def test_minima_where_new_starts_stop_are_drawn_from_the_goal_report(fitted):
    model, train, _ = fitted
    report = model.fit_summary_["goal"]
    try:
        report["new_start_minima"] = [{"point": [1.0, 2.0]}, {"point": [-1.0, 0.5]}]
        views = fit_views(model, train)
    finally:
        report["new_start_minima"] = []
    np.testing.assert_array_equal(views["new_start_minima"], [[1.0, 2.0], [-1.0, 0.5]])


def test_a_fit_that_misses_its_goal_shows_it(fitted):
    # The same model drawn against demonstrations that end elsewhere: no run arrives.
    model, train, _ = fitted
    moved = [Trajectory(t.positions + [3.0, 3.0], times=t.times) for t in train]
    views = fit_views(model, moved)
    assert all(np.min(run["run"]) > GOAL_MERGE for run in views["runs"])


def test_the_figure_is_a_png_written_whole(fitted, tmp_path):
    model, train, held = fitted
    path = plot_fit(model, train, tmp_path / "sub" / "fit.png", held)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in path.parent.iterdir()] == ["fit.png"]


def test_the_suffix_names_the_format_and_an_unknown_one_is_named(fitted, tmp_path):
    model, train, _ = fitted
    assert b"<svg" in plot_fit(model, train, tmp_path / "fit.svg").read_bytes()[:1000]
    with pytest.raises(ValueError, match=r"fit\.xyz\b.*'xyz'.*\.png\b"):
        plot_fit(model, train, tmp_path / "fit.xyz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit.svg"]
