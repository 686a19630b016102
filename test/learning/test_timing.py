"""Tests of each demonstration's time unit (policy_align_ros.learning.timing)."""

import warnings

import numpy as np
import pytest
from flows import quadratic_flow

from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.learning.timing import timed_is_better, timing_scales

A = np.array([[1.0, 0.4], [0.4, 0.6]])
CENTRE = np.array([0.3, -0.2])
DT = 0.05


def _policy(X):
    return -(X - CENTRE) @ A.T


def _flows(seed, k=8, steps=120):
    """Unconstrained Euler flows of xdot = -A (x - c) from random starts."""
    rng = np.random.default_rng(seed)
    return [quadratic_flow(A, CENTRE, rng.uniform(-2.0, 2.0, 2), steps, DT)
            for _ in range(k)]


def _on_another_clock(traj, factor):
    """The same path, each step taking ``factor`` times as long."""
    return Trajectory(traj.positions, times=traj.times[0] + factor * (traj.times
                                                                       - traj.times[0]))


def _policy_error(model, demos):
    X = np.concatenate([d.positions for d in demos])
    true = _policy(X)
    return float(np.sqrt(np.mean(np.sum((model.policy(X) - true) ** 2, axis=1))
                         / np.mean(np.sum(true**2, axis=1))))


def test_factors_are_the_slopes_of_the_model_on_each_demonstrations_estimates():
    rng = np.random.default_rng(0)
    f = [rng.normal(size=50) for _ in range(4)]
    # Demonstration 1 (two pieces) ran twice as fast: its estimates are twice the drop.
    values = [f[0] + 3.0, 2.0 * f[1] - 1.0, 2.0 * f[2] + 5.0, 0.5 * f[3]]
    scales = timing_scales(f, values, np.array([0, 1, 1, 2]), 3)
    np.testing.assert_allclose(scales[1] / scales[0], 0.5, rtol=1e-12)
    np.testing.assert_allclose(scales[2] / scales[0], 2.0, rtol=1e-12)
    np.testing.assert_allclose(np.prod(scales), 1.0, rtol=1e-12)


def test_a_demonstration_that_says_nothing_of_its_speed_keeps_one():
    rng = np.random.default_rng(1)
    f = [rng.normal(size=30) for _ in range(4)]
    values = [f[0], np.full(30, 2.0), -f[2], 2.0 * f[3]]  # flat; against the model
    scales = timing_scales(f, values, np.arange(4), 5)  # demonstration 4 has no piece
    assert scales[1] == scales[2] == scales[4] == 1.0
    np.testing.assert_allclose(scales[3] / scales[0], 0.5, rtol=1e-12)


def test_mismatched_pieces_are_a_value_error():
    with pytest.raises(ValueError, match="1, 2 and 2"):
        timing_scales([np.zeros(3)], [np.zeros(3), np.zeros(3)], np.array([0, 1]), 2)
    with pytest.raises(ValueError, match="demonstration 0"):
        timing_scales([np.zeros(3)], [np.zeros(4)], np.array([0]), 1)


def test_flows_of_one_potential_on_one_clock_keep_the_papers_estimate():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean fit warns about nothing
        model = PolicyAlign(random_state=0).fit(_flows(0))
    np.testing.assert_array_equal(model.timing_scales_, np.ones(8))
    assert model.fit_summary_["timing_scales"] == [1.0] * 8


def _bundles(seed, starts=3, per=3, steps=120):
    """``per`` flows from each of ``starts`` places, their starts 0.05 apart: repeated
    demonstrations of one task, as a teacher gives them."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(starts):
        start = rng.uniform(-2.0, 2.0, 2)
        out += [quadratic_flow(A, CENTRE, start + rng.normal(scale=0.05, size=2), steps, DT)
                for _ in range(per)]
    return out


def _direction_error(model, demos):
    """The policy's error from the true one along the demonstrations, its overall speed
    factor left out (the demonstrations' clocks fix no common time unit)."""
    X = np.concatenate([d.positions for d in demos])
    learnt, true = model.policy(X), _policy(X)
    factor = np.sum(learnt * true) / np.sum(learnt * learnt)
    return float(np.sqrt(np.mean(np.sum((factor * learnt - true) ** 2, axis=1))
                         / np.mean(np.sum(true**2, axis=1))))


def test_repeated_demonstrations_at_different_speeds_teach_one_policy():
    demos = _bundles(2)
    factors = np.tile([0.7, 1.0, 1.4], 3)  # slow, as demonstrated, fast in every bundle
    timed = [_on_another_clock(d, f) for d, f in zip(demos, factors, strict=True)]
    own = PolicyAlign(random_state=0).fit(timed)
    shared = PolicyAlign(random_state=0, time_units="shared").fit(timed)
    # Each demonstration's factor is its clock's (up to the common unit).
    recovered = own.timing_scales_ / factors
    np.testing.assert_allclose(recovered / np.exp(np.mean(np.log(recovered))), 1.0,
                               atol=0.05)
    heldout = own.fit_summary_["timing_heldout"]
    assert heldout["per_demonstration"] < 0.8 * heldout["shared"], heldout
    np.testing.assert_array_equal(shared.timing_scales_, np.ones(9))
    assert shared.fit_summary_["timing_heldout"] is None
    # One policy: its directions within 1 % of the true one's. The rows across and along
    # the motion set the directions under either clock (0.005 with the clocks, 0.003
    # without); the clocks' gain is in the held-out motion above.
    assert _direction_error(own, demos) < 0.01


def _checked(elsewhere, fold_ratios):
    return {"goal": {"n_starts_elsewhere": elsewhere},
            "heldout_vs_zero": {"fold_ratios": fold_ratios}}


def test_the_clocks_are_kept_when_they_strand_fewer_starts_or_predict_clearly_better():
    better = [0.10, 0.12, 0.09, 0.11, 0.10]
    worse = [0.20, 0.21, 0.19, 0.22, 0.20]
    # Fewer stranded starts decide first, whatever the held-out error.
    assert timed_is_better(_checked(0, worse), _checked(1, better))
    assert not timed_is_better(_checked(2, better), _checked(1, worse))
    # As many: lower on the same folds by more than two standard errors of the paired
    # differences.
    assert timed_is_better(_checked(0, better), _checked(0, worse))
    assert not timed_is_better(_checked(0, worse), _checked(0, better))
    noisy = [0.10, 0.30, 0.05, 0.25, 0.10]  # lower on average, not consistently
    assert not timed_is_better(_checked(0, noisy), _checked(0, [0.2] * 5))
    # Nothing held out to compare: the paper's shared clock.
    assert not timed_is_better(_checked(0, []), _checked(0, []))


def test_time_units_round_trip_and_bad_values_are_refused(tmp_path):
    demos = _flows(0)
    model = PolicyAlign(random_state=0).fit([_on_another_clock(demos[0], 2.0), *demos[1:]])
    loaded = PolicyAlign.load(model.save(tmp_path / "m.npz"))
    np.testing.assert_array_equal(loaded.timing_scales_, model.timing_scales_)
    with pytest.raises(ValueError, match="time_units"):
        PolicyAlign(time_units="fast").fit(demos)


@pytest.mark.parametrize("factors", [[0.7, 1.0, 1.4], [0.97, 1.0, 1.03]])
def test_the_goal_report_holds_the_new_starts_of_the_fit_kept(factors, monkeypatch):
    # Both clocks' fits run their new starts before one is kept (the per-demonstration
    # clocks with the first factors, the shared clock with the second): the report must be
    # the kept fit's runs, whichever fit ran last.
    from policy_align_ros.learning import fit_stages

    real = fit_stages.new_start_runs

    def tagged(trajs, potential, gradient, *args):
        report, starts, at_goal = real(trajs, potential, gradient, *args)
        return {**report, "regressor_id": id(potential.__self__)}, starts, at_goal

    monkeypatch.setattr(fit_stages, "new_start_runs", tagged)
    demos = [_on_another_clock(d, f)
             for d, f in zip(_bundles(2), np.tile(factors, 3), strict=True)]
    model = PolicyAlign(random_state=0).fit(demos)
    assert model.fit_summary_["timing_heldout"] is not None  # both fits were made
    assert model.fit_summary_["goal"]["regressor_id"] == id(model.regressor_)
