"""Runs from new starts near the data (policy_align_ros.learning.new_starts)."""

import warnings

import numpy as np
import pytest

from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.learning.new_starts import (
    NEW_STARTS,
    new_start_runs,
    new_starts_late,
    new_starts_late_message,
    new_starts_message,
    stiffer_residual,
)

GOAL = np.zeros(2)
WELL = np.array([0.0, 1.1])  # beside the demonstrated paths, inside the starts' box


def _bowl_with_well(depth):
    """A bowl at GOAL plus a Gaussian well of ``depth`` at WELL, and its gradient."""
    def potential(X):
        return 0.5 * np.sum(X**2, axis=1) - depth * np.exp(
            -np.sum((X - WELL) ** 2, axis=1) / 0.02)

    def gradient(X):
        D = X - WELL
        return X + depth * np.exp(-np.sum(D**2, axis=1) / 0.02)[:, None] * D / 0.01

    return potential, gradient


def _demos():
    """Straight demonstrations from the left and the right of the well to GOAL."""
    t = np.linspace(0.0, 1.0, 40)[:, None]
    starts = [[-1.0, 0.5], [1.0, 0.5], [-1.0, 1.0], [1.0, 1.0]]
    return [Trajectory(np.array(s) * (1.0 - t), times=t[:, 0]) for s in starts]


def test_runs_from_new_starts_find_a_well_beside_the_paths_that_no_start_leads_to():
    potential, gradient = _bowl_with_well(1.0)
    out = new_start_runs(_demos(), potential, gradient, GOAL, 2.0, 1.0, 0)[0]
    assert out["n_new_starts"] == NEW_STARTS
    assert out["n_new_starts_elsewhere"] > 0 and out["n_new_starts_escaped"] == 0
    (well,) = out["new_start_minima"]
    assert np.allclose(well["point"], WELL, atol=0.02)
    assert well["n_starts"] == out["n_new_starts_elsewhere"]
    assert well["goal_fraction"] == pytest.approx(np.linalg.norm(WELL) / 2.0, rel=0.02)
    assert new_starts_message(out) is not None


def test_a_bowl_leads_every_new_start_to_its_goal_and_no_goal_runs_nothing():
    potential, gradient = _bowl_with_well(0.0)
    out = new_start_runs(_demos(), potential, gradient, GOAL, 2.0, 1.0, 0)[0]
    assert out["n_new_starts_elsewhere"] == 0 and out["new_start_minima"] == []
    assert new_starts_message(out) is None
    none = new_start_runs(_demos(), potential, gradient, None, 2.0, 1.0, 0)[0]
    assert set(none.values()) == {None} and new_starts_message(none) is None


def test_runs_that_reach_the_goal_only_by_crawling_over_a_plateau_count_as_late():
    # A bowl whose slope above the demonstrated paths (y > 1) is a thousandth of its own:
    # every descent stops at the goal, but a run from up there takes minutes, not the
    # demonstrations' second.
    def gradient(X):
        return 3.0 * X * np.where(X[:, 1:] > 1.0, 1e-3, 1.0)

    potential, _ = _bowl_with_well(0.0)
    out, starts, at_goal = new_start_runs(_demos(), potential, gradient, GOAL, 2.0, 1.0, 0)
    assert out["n_new_starts_elsewhere"] == 0 and at_goal.all()
    above = int(np.count_nonzero(starts[:, 1] > 1.0))
    assert above > 0
    assert new_starts_late(_demos(), gradient, GOAL, 2.0, starts) == above
    steep = new_starts_late(_demos(), lambda X: 3.0 * X, GOAL, 2.0, starts)
    assert steep == 0
    assert new_starts_late_message({"n_new_starts": 64, "n_new_starts_late": above})
    assert new_starts_late_message({"n_new_starts": 64, "n_new_starts_late": 0}) is None
    assert new_starts_late(_demos(), gradient, GOAL, 2.0, starts[:0]) == 0


def test_the_new_starts_are_seeded():
    potential, gradient = _bowl_with_well(1.0)
    runs = [new_start_runs(_demos(), potential, gradient, GOAL, 2.0, 1.0, seed)[0]
            for seed in (3, 3, 4)]
    assert runs[0] == runs[1]
    assert runs[0]["n_new_starts_elsewhere"] != runs[2]["n_new_starts_elsewhere"]


def test_a_fit_whose_demonstrations_end_together_reports_its_new_starts():
    # Exact flows of a bowl: the learnt potential is the bowl, every new start reaches.
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 8.0, 80)  # they end together, within 1 % of the extent
    demos = [Trajectory(x0 * np.exp(-t)[:, None], times=t)
             for x0 in rng.uniform(-1.0, 1.0, size=(8, 2))]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        goal = PolicyAlign(random_state=0).fit(demos).fit_summary_["goal"]
    assert goal["n_new_starts"] == NEW_STARTS and goal["n_new_starts_elsewhere"] == 0
    assert goal["n_new_starts_late"] == 0
    assert not caught  # no warning at all, of new starts or else


def test_the_stiffer_residual_keeps_the_direction_weight_and_respects_a_fixed_penalty():
    from policy_align_ros.learning.regressors import TrendKernelRegression
    from policy_align_ros.learning.regressors.trend_kernel.cv import KERNEL_RIDGE_GRID

    largest = max(k for k in KERNEL_RIDGE_GRID if np.isfinite(k))

    class Fitted:
        kernel_ridge_ = largest / 100.0

    template = TrendKernelRegression(random_state=3)
    stiffer = stiffer_residual(template, Fitted(), 1000.0)
    assert stiffer.get_params()["kernel_ridge"] == largest
    assert stiffer.get_params()["direction_weight"] == 1000.0
    assert stiffer.get_params()["random_state"] == 3
    assert template.get_params()["kernel_ridge"] == "cv"  # the template is left alone
    Fitted.kernel_ridge_ = largest
    assert stiffer_residual(template, Fitted(), 1000.0) is None  # already as stiff
    Fitted.kernel_ridge_ = largest / 100.0
    fixed = TrendKernelRegression(kernel_ridge=1e-6)
    assert stiffer_residual(fixed, Fitted(), 1000.0) is None  # the user's choice stands


def test_a_fit_whose_new_starts_stop_off_the_paths_refits_a_stiffer_residual():
    # LASA JShape, all 7 demonstrations: the CV's residual leaves wells beside the paths
    # that 26 of the 64 new starts fall into; the stiffer refit has none and is kept.
    from policy_align_ros.experiments import lasa

    demos = lasa.load_shape("JShape")
    trajs = [Trajectory(d["positions"][::5], d["times"][::5]) for d in demos]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = PolicyAlign(random_state=0).fit(trajs)
    assert model.fit_summary_["anchor"]["kernel_ridge_raised"] is True
    assert model.fit_summary_["goal"]["n_new_starts_elsewhere"] == 0
    assert model.fit_summary_["goal"]["n_starts_elsewhere"] == 0


def test_a_fit_whose_new_starts_crawl_to_the_goal_says_so():
    # LASA PShape without its fifth demonstration: every new start's descent stops at the
    # goal, but two of the runs are still on their way after 3 times the demonstrations'
    # median duration.
    from policy_align_ros.experiments import lasa

    demos = lasa.load_shape("PShape")
    trajs = [Trajectory(d["positions"][::5], d["times"][::5])
             for k, d in enumerate(demos) if k != 4]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        goal = PolicyAlign(random_state=0).fit(trajs).fit_summary_["goal"]
    assert goal["n_new_starts_elsewhere"] == 0 and goal["n_new_starts_late"] > 0
    assert any(issubclass(w.category, UserWarning) for w in caught)
