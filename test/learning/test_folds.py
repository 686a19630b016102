"""Fold refits, the zero-policy comparison and the goal report of a fit
(policy_align_ros.learning.folds, through PolicyAlign.fit)."""

import json
import warnings

import numpy as np
import pytest
from flows import quadratic_flow

from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.learning import folds as folds_module
from policy_align_ros.learning.folds import (
    FoldModel,
    along_motion_errors,
    demonstration_ratios,
    fold_refits,
    heldout_reach,
    heldout_reach_message,
    unfixed_goal,
)
from policy_align_ros.learning.goal import GOAL_MERGE
from policy_align_ros.learning.regressors import TrendKernelRegression

A = np.array([[2.0, 0.5], [0.5, 1.0]])
CENTRE = np.array([0.3, -0.2])
DT = 0.05


def _quadratic_demos(seed, k=8, steps=120, walk=0.0):
    """Unconstrained Euler flows of xdot = -A (x - c), at rest at their ends; ``walk``:
    each step also pushed about by white noise of that standard deviation."""
    rng = np.random.default_rng(seed)
    return [quadratic_flow(A, CENTRE, rng.uniform(-2.0, 2.0, 2), steps, DT, walk, rng)
            for _ in range(k)]


def _random_walks(seed, k=6, steps=60):
    rng = np.random.default_rng(seed)
    return [Trajectory(np.cumsum(rng.normal(scale=0.05, size=(steps, 2)), axis=0)
                       + rng.uniform(-1.0, 1.0, 2), times=DT * np.arange(steps))
            for _ in range(k)]


@pytest.fixture(scope="module")
def quadratic():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean fit warns about nothing
        return PolicyAlign(random_state=0).fit(_quadratic_demos(0))


def test_the_learnt_goal_of_a_quadratic_is_its_minimum_and_where_demos_rest(quadratic):
    summary = quadratic.fit_summary_
    goal = summary["goal"]
    (minimum,) = goal["minima"]
    np.testing.assert_allclose(minimum["point"], CENTRE, atol=1e-4)
    assert goal["n_rests"] == 8 and goal["n_constrained_rests"] == 0
    assert goal["demonstrated_goals"][0]["n_rests"] == 8
    assert goal["goal_error_fraction"] < 0.005
    assert goal["n_folds"] == 8 and goal["fold_spread_fraction"] < 1e-3
    assert goal["n_starts_elsewhere"] == 0
    # Every run from a demonstrated start is home well within 3 of its durations.
    assert goal["n_starts_late"] == 0 and len(goal["start_reach_ratios"]) == 8
    assert all(0.0 < r < 1.0 for r in goal["start_reach_ratios"])
    # And every fold model from the start of each demonstration it was fitted without.
    assert goal["n_heldout_late"] == 0 and len(goal["heldout_reach_ratios"]) == 8
    assert all(0.0 < r < 1.0 for r in goal["heldout_reach_ratios"])
    assert summary["worse_than_zero"] is False and summary["no_minimum"] is False
    assert summary["poor_fit"] is False
    heldout = summary["heldout_vs_zero"]
    assert heldout["ratio"] < 0.01
    # One ratio per fold; the pooled ratio is their average weighted by the zero error.
    folds = heldout["fold_ratios"]
    assert len(folds) == heldout["n_folds"] and min(folds) <= heldout["ratio"] <= max(folds)
    json.dumps(summary, allow_nan=False)  # JSON-able as it is


def test_pure_noise_demonstrations_warn_no_better_than_a_zero_policy():
    with pytest.warns(UserWarning) as caught:
        model = PolicyAlign(random_state=0).fit(_random_walks(1))
    summary = model.fit_summary_
    assert summary["worse_than_zero"] is True
    numbers = summary["heldout_vs_zero"]
    assert numbers["error"] >= numbers["zero_error"] > 0
    # Exactly one warning names both numbers.
    (message,) = [str(w.message) for w in caught if f"{numbers['error']:.4g}" in str(w.message)]
    assert f"{numbers['zero_error']:.4g}" in message


def test_a_fit_that_explains_at_most_half_of_the_held_out_motion_warns_and_is_kept():
    # About as much random walk as flow: the policy is right on average, but the held-out
    # motion along its own direction is mostly not the policy's.
    with pytest.warns(UserWarning) as caught:
        model = PolicyAlign(random_state=0).fit(_quadratic_demos(0, steps=80, walk=0.02))
    summary = model.fit_summary_
    ratio = summary["heldout_vs_zero"]["ratio"]
    assert 0.5 <= ratio < 1.0
    assert summary["poor_fit"] is True and summary["worse_than_zero"] is False
    numbers = summary["heldout_vs_zero"]
    assert any(f"{numbers['error']:.4g}" in str(w.message)
               and f"{numbers['zero_error']:.4g}" in str(w.message) for w in caught)
    # Half as much walk: a fair fit, no warning.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fair = PolicyAlign(random_state=0).fit(_quadratic_demos(0, steps=80, walk=0.01))
    assert fair.fit_summary_["poor_fit"] is False
    assert fair.fit_summary_["heldout_vs_zero"]["ratio"] < 0.5


def _uniform_motion(seed, k=8, steps=100):
    """Straight lines at one constant velocity: the potential of a constant policy (a
    plane) has no minimum anywhere."""
    rng = np.random.default_rng(seed)
    t = 0.02 * np.arange(steps)
    return [Trajectory(rng.normal(scale=0.3, size=2) + t[:, None] * np.array([1.0, 0.5]),
                       times=t) for _ in range(k)]


def test_a_potential_without_a_minimum_warns_and_is_recorded():
    with pytest.warns(UserWarning) as caught:
        model = PolicyAlign(random_state=0).fit(_uniform_motion(0))
    summary = model.fit_summary_
    assert summary["no_minimum"] is True and summary["worse_than_zero"] is False
    assert summary["goal"]["minima"] == [] and summary["goal"]["n_escaped"] == 8
    assert len(caught) == 1
    json.dumps(summary, allow_nan=False)


def _cut_while_moving(scatter, k=6, seed=0):
    """Flows of xdot = -(x - c_k) from starts 3 from the origin, cut at 0.7 s while still
    moving; each teacher heads for its own goal c_k, ``scatter`` about the origin."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 0.7, 50)
    out = []
    for i in range(k):
        c = scatter * rng.standard_normal(2)
        x0 = 3.0 * np.array([np.cos(i), np.sin(i)])
        out.append(Trajectory(c + (x0 - c) * np.exp(-t)[:, None], times=t, name=str(i)))
    return out


def test_a_goal_the_cv_folds_put_apart_warns_and_one_they_agree_on_does_not():
    # One goal, never reached: the fit extrapolates it, and every fold agrees.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        one = PolicyAlign(random_state=0).fit(_cut_while_moving(0.0))
    goal = one.fit_summary_["goal"]
    assert goal["n_rests"] == 0 and goal["minima"][0]["data_fraction"] > 0.2
    np.testing.assert_allclose(goal["minima"][0]["point"], [0.0, 0.0], atol=1e-3)
    assert goal["fold_spread_fraction"] < 1e-3 and one.fit_summary_["unfixed_goal"] is False
    # Teachers heading for goals about 1 apart: leaving one out moves the minimum.
    with pytest.warns(UserWarning) as caught:
        apart = PolicyAlign(random_state=0).fit(_cut_while_moving(1.0))
    goal = apart.fit_summary_["goal"]
    assert goal["fold_spread_fraction"] > GOAL_MERGE
    assert apart.fit_summary_["unfixed_goal"] is True and len(caught) == 1
    assert apart.fit_summary_["poor_fit"] is False and goal["n_starts_elsewhere"] == 0


def test_the_goal_is_the_minimum_where_the_demonstrations_end_and_no_folds_cannot_say():
    def goal(spreads, n_folds=8):
        # Two minima: the first far from where the demonstrations end, the second at it.
        return {"extent": 10.0, "n_folds": n_folds, "demonstrated_goals": [],
                "minima": [{"point": [5.0, 0.0], "end_distance": 5.0, "fold_spread": spreads[0]},
                           {"point": [0.0, 0.0], "end_distance": 0.1, "fold_spread": spreads[1]}]}

    # Only the goal's spread counts: the other minimum may move (few demonstrations lead
    # there), and a fold model without a minimum near the goal leaves it open.
    assert not unfixed_goal(goal([3.0, 0.4]))
    assert unfixed_goal(goal([0.0, 0.6])) and unfixed_goal(goal([0.0, None]))
    assert not unfixed_goal(goal([0.0, None], n_folds=0))
    # With a demonstrated goal, the minimum nearest it is the goal.
    near_first = goal([0.6, 0.0]) | {"demonstrated_goals": [{"point": [4.9, 0.1]}]}
    assert unfixed_goal(near_first)


class _Drift:
    """A fitted model whose policy is (1, 0) everywhere: ``gradient = -(1, 0)``."""

    def gradient(self, X):
        return np.tile([-1.0, 0.0], (len(X), 1))


def test_the_demonstration_the_others_contradict_is_named():
    t = DT * np.arange(20)
    along = Trajectory(np.column_stack([t, 0.0 * t]), times=t, name="forth")
    back = Trajectory(np.column_stack([-t, 0.0 * t]), times=t, name="back")
    # Demonstration "forth" cut into two pieces (0, 1), "back" one piece (2); each fold
    # holds one demonstration out.
    pieces, owners = [along, along, back], np.array([0, 0, 1])
    folds = [FoldModel(np.array([0, 1]), _Drift()), FoldModel(np.array([2]), _Drift())]
    ratios = demonstration_ratios(folds, pieces, owners, 2)
    # Along the motion: 0 where the policy is the motion; (1 - (-1))^2 = 4 against it.
    np.testing.assert_allclose(ratios, [0.0, 4.0], atol=1e-12)
    heldout = {"error": 1.0, "zero_error": 1.5, "ratio": 0.67, "n_samples": 57,
               "n_folds": 2, "demonstration_ratios": ratios}
    message = folds_module._heldout_message(heldout, False, [along, back])
    assert "back" in message and "forth" not in message
    # Every demonstration contradicted is no single culprit: none is named.
    heldout["demonstration_ratios"] = [4.0, 4.0]
    assert "back" not in folds_module._heldout_message(heldout, False, [along, back])


def test_runs_still_on_their_way_after_the_allowed_time_warn_and_are_counted(monkeypatch):
    # Allow each run a thousandth of its demonstration's duration: none is home by then.
    monkeypatch.setattr("policy_align_ros.learning.reach.REACH_TIME", 1e-3)
    demos = [Trajectory(t.positions, t.times, name=f"walk{k}")
             for k, t in enumerate(_quadratic_demos(0))]
    with pytest.warns(UserWarning) as caught:
        model = PolicyAlign(random_state=0).fit(demos)
    goal = model.fit_summary_["goal"]
    assert goal["n_starts_late"] == 8 and goal["start_reach_ratios"] == [None] * 8
    assert goal["n_starts_elsewhere"] == 0 and len(caught) == 1
    # The warning names the demonstrations whose runs did not arrive, the first few.
    message = str(caught[0].message)
    assert all(f"walk{k}" in message for k in range(4)) and "walk7" not in message


def test_the_goal_report_round_trips_and_files_without_it_load(quadratic, tmp_path):
    path = quadratic.save(tmp_path / "model.npz")
    loaded = PolicyAlign.load(path)
    for key in ("goal", "heldout_vs_zero", "worse_than_zero"):
        assert loaded.fit_summary_[key] == quadratic.fit_summary_[key]
    # A file written before the report existed.
    old = PolicyAlign.load(path)
    for key in ("goal", "heldout_vs_zero", "worse_than_zero"):
        del old.fit_summary_[key]
    old_path = old.save(tmp_path / "old.npz")
    again = PolicyAlign.load(old_path)
    assert "goal" not in again.fit_summary_
    np.testing.assert_allclose(again.policy(CENTRE[None] + 1.0), quadratic.policy(
        CENTRE[None] + 1.0))


def test_fold_refits_use_the_regressors_folds_with_its_choice_fixed():
    trajs = _quadratic_demos(2, k=6, steps=40)
    X = np.concatenate([t.positions for t in trajs])
    y = 0.5 * np.einsum("ij,jk,ik->i", X - CENTRE, A, X - CENTRE)
    groups = np.repeat(np.arange(6), 40)
    reg = TrendKernelRegression(random_state=0).fit(X, y, groups=groups)
    assert set(reg.cv_folds_) == set(range(6))
    folds = fold_refits(reg, X, y, groups)
    held = np.concatenate([f.held_out for f in folds])
    assert sorted(held.tolist()) == list(range(6))
    for fold in folds:
        assert fold.regressor.trend_form_ == reg.trend_form_
        np.testing.assert_allclose(fold.regressor.gradient(X), reg.gradient(X), rtol=1e-4,
                                   atol=1e-5)


def test_fold_refits_of_an_anchored_fit_keep_its_goal_and_bowl():
    trajs = _quadratic_demos(2, k=6, steps=40)
    X = np.concatenate([t.positions for t in trajs])
    y = 0.5 * np.einsum("ij,jk,ik->i", X - CENTRE, A, X - CENTRE)
    groups = np.repeat(np.arange(6), 40)
    reg = TrendKernelRegression(random_state=0).fit(X, y, groups=groups, goal=CENTRE,
                                                    min_curvature=0.25)
    for fold in fold_refits(reg, X, y, groups):
        np.testing.assert_array_equal(fold.regressor.goal_, CENTRE)
        assert fold.regressor.min_curvature_ == 0.25


def test_along_motion_error_is_zero_for_the_true_policy_under_a_constraint():
    rng = np.random.default_rng(4)
    X = rng.normal(size=(30, 2))
    # Motion along x1 only: the blocked x2 component of the policy is not charged.
    V = -X * np.array([1.0, 0.0])
    Xs = np.concatenate([X[:1], X[:1] + np.cumsum(DT * V[:-1], axis=0)])
    traj = Trajectory(Xs, times=DT * np.arange(30))
    u = np.diff(Xs, axis=0) / DT

    def policy(P):  # the recorded velocity plus a component the constraint blocks
        return u + np.array([0.0, 5.0])

    sums, count = along_motion_errors(policy, [traj])
    assert count == 29
    assert sums[0] == pytest.approx(0.0, abs=1e-20)
    assert sums[1] == pytest.approx(float(np.sum(u**2)))
    assert sums[2] == pytest.approx(25.0 * 29)


class _Bowl:
    """A fold model whose policy is -(x - centre), or zero (``still``)."""

    def __init__(self, still=False):
        self.still = still

    def gradient(self, X):
        return np.zeros_like(X) if self.still else X - CENTRE


def test_held_out_starts_a_fold_model_does_not_take_home_are_counted_and_warned():
    demos = _quadratic_demos(1, k=4)
    # Pieces 0-3 start demonstrations 0-3 (demonstration 2 after a leading rest of 5
    # samples); piece 4 is the second part of demonstration 3 (not a start). The second
    # fold's model stands still: its held-out start is late.
    spans = np.array([[0, 0, 120], [1, 0, 120], [2, 5, 120], [3, 0, 60], [3, 60, 120]])
    folds = [FoldModel(np.array([0, 4]), _Bowl()), FoldModel(np.array([1]), _Bowl(True)),
             FoldModel(np.array([2, 3]), _Bowl())]
    reach = heldout_reach(folds, spans, demos, CENTRE, extent=4.0)
    assert reach["n_heldout_late"] == 1 and len(reach["heldout_reach_ratios"]) == 4
    assert reach["heldout_reach_ratios"][1] is None
    assert all(0.0 < r < 3.0 for i, r in enumerate(reach["heldout_reach_ratios"]) if i != 1)
    goal = {**reach, "n_starts_elsewhere": 0, "n_starts_late": 0}
    assert heldout_reach_message(goal) is not None
    # The goal report's own warnings already speak for stranded or late starts.
    assert heldout_reach_message({**goal, "n_starts_late": 2}) is None
    assert heldout_reach_message({**goal, "n_heldout_late": 0}) is None
    assert heldout_reach(folds, spans, demos, None, 4.0) == {
        "heldout_reach_ratios": None, "n_heldout_late": 0}
