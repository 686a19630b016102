"""The real-recording suite cases (policy_align_ros.experiments.recording_cases) and the
re-timing check (policy_align_ros.experiments.retiming) build and run on a tiny size."""

from dataclasses import replace

import numpy as np
import pytest

from policy_align_ros.experiments import recording_cases, suite
from policy_align_ros.experiments.recording_cases import RECORDING_CASES
from policy_align_ros.experiments.retiming import (
    cv_residual,
    retime,
    retiming_shift,
    smoothstep_warp,
)
from policy_align_ros.experiments.suite_cases import CASES
from policy_align_ros.learning import PolicyAlign, Trajectory


@pytest.mark.parametrize("name", sorted(RECORDING_CASES))
def test_each_case_records_demonstrations_with_ground_truth(name):
    rng = np.random.default_rng(0)
    problem = RECORDING_CASES[name].make(rng)
    demos = suite._demos(problem, problem.sample_starts(rng, 2), rng)
    n = RECORDING_CASES[name].n
    for d in demos:
        m = d.trajectory.n_samples
        assert d.trajectory.positions.shape == (m, n) and d.policy.shape == (m, n)
        assert d.projectors.shape == (m, n, n) and np.all(np.isfinite(d.potential))
    # The true minimum is a minimum: the expert's policy vanishes there.
    assert np.linalg.norm(problem.potential.policy(problem.minimum[None])) < 1e-4


def test_the_slow_velocity_loop_passes_the_goal_and_the_fast_one_does_not():
    from policy_align_ros.sim.demonstrations import no_constraint

    passed = {}
    for name in ("lag_joint_7", "lag_slow_7"):
        problem = RECORDING_CASES[name].make(np.random.default_rng(0))
        stiffest = np.linalg.eigh(problem.potential.W)[1][:, -1]
        rng = np.random.default_rng(1)
        x0 = problem.sample_starts(rng, 1)[0]
        demo = problem.record(x0, no_constraint(7), rng, "d")
        along = (demo.trajectory.positions - problem.minimum) @ stiffest
        passed[name] = float(np.min(along * np.sign(along[0])))  # < 0: past the goal
    assert passed["lag_slow_7"] < -1e-3 < 0.0 <= passed["lag_joint_7"]


def test_the_bumps_shift_the_minimum_off_the_attractor():
    problem = RECORDING_CASES["bumps_2"].make(np.random.default_rng(0))
    assert np.linalg.norm(problem.minimum - problem.potential.centre) > 0.05


def test_the_contact_case_slides_on_the_table(monkeypatch):
    problem = RECORDING_CASES["contact_arm_7"].make(np.random.default_rng(1))
    rng = np.random.default_rng(2)
    (demo,) = suite._demos(problem, problem.sample_starts(rng, 1), rng)
    hand = np.array([problem.extras["hand"](q) for q in demo.trajectory.positions])
    assert hand[:, 2].min() >= problem.extras["table"] - 2e-3  # never through the table


def test_the_contact_case_without_the_table_keeps_its_starts_and_goes_through_it():
    with_table = recording_cases.contact_arm(np.random.default_rng(0))
    without = recording_cases.contact_arm(np.random.default_rng(0), table=False)
    np.testing.assert_array_equal(with_table.minimum, without.minimum)
    starts = [p.sample_starts(np.random.default_rng(2), 4) for p in (with_table, without)]
    np.testing.assert_array_equal(*starts)
    height = with_table.extras["table"]
    for problem, through in ((with_table, False), (without, True)):
        demos = suite._demos(problem, starts[0], np.random.default_rng(2))
        hand = np.array([problem.extras["hand"](q) for d in demos
                         for q in d.trajectory.positions])
        assert (hand[:, 2].min() < height - 0.01) == through


def test_the_kinesthetic_case_is_the_arm_expert_guided_freely_to_its_goal():
    problem = RECORDING_CASES["kinesthetic_7"].make(np.random.default_rng(3))
    arm = CASES["arm_task_7"].make(np.random.default_rng(3))
    np.testing.assert_array_equal(problem.minimum, arm.minimum)  # the same expert
    rng = np.random.default_rng(4)
    demos = suite._demos(problem, problem.sample_starts(rng, 3), rng)
    durations = []
    for d in demos:
        X, V = d.trajectory.positions, d.trajectory.velocities
        speed = np.linalg.norm(V, axis=1)
        # At rest at both ends (the rests last >= 10 samples; the encoder's noise is left),
        # a person's timing between, and at the goal in the end.
        assert max(np.median(speed[:10]), np.median(speed[-10:])) < 0.05 * speed.max()
        assert np.linalg.norm(X[-1] - problem.minimum) < 0.01
        np.testing.assert_array_equal(d.projectors, np.broadcast_to(np.eye(7), d.projectors.shape))
        durations.append(d.trajectory.times[-1] - d.trajectory.times[0])
    assert np.ptp(durations) > 0.2


def test_the_capped_servo_is_the_gradient_flow_of_its_potential():
    potential = recording_cases.CappedQuadratic(np.array([0.5, -0.2]), cap=1.0)
    X = np.array([[0.9, -0.1], [3.0, -2.5], [-1.0, 0.7]])
    np.testing.assert_allclose(potential.policy(X[:1]), [[-0.4, -0.1]])
    assert np.abs(potential.policy(X)).max() == 1.0  # capped far away
    h = 1e-6
    grad = np.stack([(potential.value(X + h * e) - potential.value(X - h * e)) / (2 * h)
                     for e in np.eye(2)], axis=1)
    np.testing.assert_allclose(-grad, potential.policy(X), atol=1e-6)


def test_the_physical_arm_presses_on_its_surface_and_creeps_to_its_goal():
    from policy_align_ros.learning.goal import demonstrated_goal

    problem = RECORDING_CASES["dynamics_arm_7"].make(np.random.default_rng(0))
    plane = problem.extras["surface"]
    rng = np.random.default_rng(1)
    demos = suite._demos(problem, problem.sample_starts(rng, 6), rng)
    normal, hand = np.asarray(plane.normal), problem.extras["hand"]
    height = np.array([normal @ hand(q) for d in demos for q in d.trajectory.positions])
    assert height.min() > plane.offset - 5e-3  # a stiff surface
    touched = [bool(np.any(d.n_active > 0)) for d in demos]
    assert 0 < sum(touched)
    # At rest by its speed (below 2 % of the peak) yet short of the goal, still creeping:
    # the limit of the creep is the goal.
    short = []
    for d in demos:
        speed = np.linalg.norm(d.trajectory.velocities, axis=1)
        assert speed[-1] < 0.02 * speed.max()
        short.append(np.linalg.norm(d.trajectory.positions[-1] - problem.minimum))
    assert min(short) > 5e-3
    trajs = [d.trajectory for d in demos]
    assert np.linalg.norm(demonstrated_goal(trajs) - problem.minimum) < 0.2 * min(short)
    # Without the surface: the same starts, and no contact.
    free = recording_cases.dynamics_arm(np.random.default_rng(0), surface=False)
    np.testing.assert_array_equal(free.sample_starts(np.random.default_rng(1), 6),
                                  problem.sample_starts(np.random.default_rng(1), 6))


def test_a_case_runs_in_the_suite_and_reports_the_learnt_goal(monkeypatch):
    make = RECORDING_CASES["human_timing_2"].make
    small = replace(RECORDING_CASES["human_timing_2"],
                    make=lambda rng: replace(make(rng), n_train=6))
    monkeypatch.setitem(suite.ALL_CASES, "human_timing_2", small)
    monkeypatch.setattr(suite, "N_TEST_DEMOS", 3)
    monkeypatch.setattr(suite, "N_ROLLOUTS", 2)
    result = suite.run_case(("human_timing_2", 0))
    for label in ("previous", "new"):
        model = result["models"][label]
        assert model["min_error"] >= 0 and np.isfinite(model["free_rel_median"])
    # Every guarded run of the new model has one outcome: reached, held at the data's
    # edge, flagged by its fold-stop check, or silent.
    new = result["models"]["new"]
    assert sum(new["free_outcomes"]) == sum(new["unseen_outcomes"]) == 2
    for where in ("free", "unseen"):  # where each silent run ended
        assert len(new[f"{where}_silent_rel"]) == new[f"{where}_outcomes"][3]
        assert 0 <= new[f"{where}_reached_flagged"] <= new[f"{where}_outcomes"][0]
        assert len(new[f"{where}_guarded_rel"]) == len(new[f"{where}_stop_spread"]) == 2
        assert sum(new[f"{where}_guarded_held"]) >= new[f"{where}_outcomes"][1]
    # How close the training data came to the true minimum, as the suite measures it.
    rng = np.random.default_rng(0)  # the data set run_case drew
    problem = small.make(rng)
    train, _, _ = suite.draw_data_set(problem, rng)
    assert 0.0 <= result["models"]["new"]["data_gap"] <= min(
        np.linalg.norm(d.trajectory.positions[-1] - problem.minimum) for d in train)
    table = suite.format_table([result])
    assert "| human_timing_2 | new |" in table  # the learnt-goal table's row


def test_retime_keeps_the_path_and_the_stamps_and_rests_where_the_warp_is_flat():
    t = np.linspace(0.0, 2.0, 401)
    X = np.stack([np.sin(t), t], axis=1)
    V = np.stack([np.cos(t), np.ones_like(t)], axis=1)
    out = retime(Trajectory(X, t, V), smoothstep_warp)
    assert np.array_equal(out.times, t)
    assert np.allclose(out.positions[[0, -1]], X[[0, -1]])
    # On the same path: the second coordinate is the path parameter.
    assert np.allclose(out.positions[:, 0], np.sin(out.positions[:, 1]), atol=1e-4)
    speed = np.linalg.norm(out.velocities, axis=1)
    assert speed[0] < 0.02 and speed[-1] < 0.02  # at rest at both ends (typical 1.4)
    assert speed[200] > 1.4 * np.linalg.norm(V[200])  # 1.5 times faster half-way
    fd = np.gradient(out.positions, out.times, axis=0)
    assert np.allclose(out.velocities[5:-5], fd[5:-5], rtol=0.02, atol=0.01)
    with pytest.raises(ValueError, match="warp"):
        retime(Trajectory(X, t, V), lambda s: 1.0 - s)


def test_retiming_shift_is_zero_for_the_identity_and_measured_otherwise():
    rng = np.random.default_rng(0)
    problem = recording_cases.RECORDING_CASES["bumps_2"].make(rng)
    demos = suite._demos(problem, problem.sample_starts(rng, 5), rng)
    trajs = [d.trajectory for d in demos]

    def factory():
        return PolicyAlign(random_state=0)

    assert retiming_shift(factory, trajs, 0, lambda s: s) == pytest.approx(0.0, abs=1e-9)
    shift = retiming_shift(factory, trajs, 0, smoothstep_warp)
    assert np.isfinite(shift) and shift >= 0
    with pytest.raises(ValueError, match="k"):
        retiming_shift(factory, trajs, 9, smoothstep_warp)


def test_cv_residual_reads_the_length_scale_the_cv_chose_or_none_for_the_trend_alone():
    rng = np.random.default_rng(1)
    problem = recording_cases.RECORDING_CASES["bumps_2"].make(rng)
    demos = suite._demos(problem, problem.sample_starts(rng, 6), rng)
    model = PolicyAlign(random_state=0).fit([d.trajectory for d in demos])
    form, _, length, kernel_ridge, _ = model.regressor_.cv_best_
    expected = float(length) if np.isfinite(kernel_ridge) else None
    assert cv_residual(model) == expected
    # The trend alone, and a regressor without a CV choice.
    model.regressor_.cv_best_ = (form, 1e-6, np.nan, np.inf, 0.0)
    assert cv_residual(model) is None
    model.regressor_.cv_best_ = None
    assert np.isnan(cv_residual(model))
