"""Potential estimates along single trajectories (policy_align_ros.learning.potential)."""

import numpy as np
import pytest

from policy_align_ros.learning import Trajectory
from policy_align_ros.learning.potential import (
    GAP_RATIO,
    best_timing,
    choose_method,
    estimate_potential,
    euler_potential,
    euler_scale,
    leading_rest,
    position_noise,
    sampling_gaps,
    step_curvatures,
    switch_cuts,
    trapezoid_potential,
    velocity_disagreement,
)


def _quadratic_flow(dt: float, steps: int, x0=(1.5, -1.0), w=0.05):
    """Exact solution of xdot = -grad(w x^T x) = -2 w x, sampled every dt seconds."""
    t = dt * np.arange(steps)
    X = np.asarray(x0)[None, :] * np.exp(-2 * w * t)[:, None]
    return t, X, -2 * w * X, w * np.sum(X**2, axis=1)


def test_euler_rule_is_paper_eq7_in_step_units():
    X = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0]])
    np.testing.assert_allclose(euler_potential(X), [0.0, -1.0, -5.0])


def test_euler_with_times_is_in_per_second_units():
    # The same path sampled twice as fast must give the same potential drop.
    for dt in (0.1, 0.05):
        t, X, _, phi = _quadratic_flow(dt, int(round(10 / dt)) + 1)
        est = estimate_potential(Trajectory(X, times=t))
        drop_true = phi[-1] - phi[0]
        assert est[-1] == pytest.approx(drop_true, rel=0.05)


def test_trapezoid_is_more_accurate_than_euler_with_velocities():
    t, X, V, phi = _quadratic_flow(0.5, 30)
    traj = Trajectory(X, times=t, velocities=V)
    err_euler = np.abs(estimate_potential(traj, "euler") - (phi - phi[0])).max()
    err_trap = np.abs(estimate_potential(traj, "trapezoid") - (phi - phi[0])).max()
    assert err_trap < 0.1 * err_euler
    np.testing.assert_allclose(trapezoid_potential(X, V), phi - phi[0], atol=2e-3)


def test_trapezoid_without_velocities_and_unknown_rule_fail_clearly():
    traj = Trajectory(np.zeros((3, 2)), name="7")
    with pytest.raises(ValueError, match=r"^trajectory 7: .*\bvelocities\b"):
        estimate_potential(traj, "trapezoid")
    with pytest.raises(ValueError, match="'simpson'"):
        estimate_potential(traj, "simpson")


def _held_commands(W, x0, dt, steps):
    """Forward-Euler motion under xdot = -2 W x held over each step (a velocity command per
    control period); returns times, positions, velocities and the potential x'Wx."""
    X = [np.asarray(x0, dtype=float)]
    for _ in range(steps - 1):
        X.append(X[-1] - dt * 2.0 * W @ X[-1])
    X = np.array(X)
    return dt * np.arange(steps), X, -2.0 * X @ W, np.einsum("ij,jk,ik->i", X, W, X)


def test_trapezoid_is_exact_under_held_commands_where_euler_is_biased():
    W = np.diag([0.5, 2.0])
    t, X, V, phi = _held_commands(W, (1.0, -0.5), 0.05, 60)
    traj = Trajectory(X, times=t, velocities=V)
    np.testing.assert_allclose(estimate_potential(traj, "trapezoid"), phi - phi[0],
                               atol=1e-12)
    assert np.abs(estimate_potential(traj, "euler") - (phi - phi[0])).max() > 1e-3


def _switching_commands(W, x0, dt, steps, switch_every, rng):
    """Held commands ``v = N_k (-2 W x)`` under one random row ``A_k``, re-drawn every
    ``switch_every`` samples; returns positions, velocities and the potential x'Wx."""
    X, V = [np.asarray(x0, dtype=float)], []
    for i in range(steps):
        if i % switch_every == 0:
            a = rng.standard_normal(len(x0))
            N = np.eye(len(x0)) - np.outer(a, a) / (a @ a)
        V.append(N @ (-2.0 * W @ X[-1]))
        if i < steps - 1:
            X.append(X[-1] + dt * V[-1])
    X = np.array(X)
    return X, np.array(V), np.einsum("ij,jk,ik->i", X, W, X)


def test_trapezoid_stays_accurate_across_constraint_switches():
    # A switch between two samples puts a velocity of one constraint along a step of the
    # other into the plain trapezoid; that step is then wrong by a first-order amount.
    rng = np.random.default_rng(3)
    W = np.diag([0.5, 1.0, 2.0])
    X, V, phi = _switching_commands(W, (1.0, -0.8, 0.6), 0.05, 90, 30, rng)
    steps = np.diff(X, axis=0)
    plain = -np.concatenate(([0.0], np.cumsum(0.5 * np.einsum(
        "ij,ij->i", V[:-1] + V[1:], steps))))
    truth = phi - phi[0]
    plain_error = np.abs(plain - truth).max()
    assert plain_error > 1e-4 * np.ptp(truth)
    # What is left is the third-order error of the one-sided estimate at the two switches.
    assert np.abs(trapezoid_potential(X, V) - truth).max() < 0.02 * plain_error


def _assert_trapezoid_curvatures_kept(X, V):
    """No step taken for a switch: every curvature term is the trapezoid's own."""
    steps = np.diff(X, axis=0)
    np.testing.assert_array_equal(step_curvatures(steps, V),
                                  np.einsum("ij,ij->i", V[:-1] - V[1:], steps))


def test_switch_detection_leaves_a_turning_constraint_to_the_trapezoid():
    # A constraint that turns a little with every step (a hand plane seen in joint space)
    # is no switch: the curvature estimates must be the trapezoid's own.
    W = np.diag([0.5, 2.0])
    X, V = [np.array([1.0, -0.5])], []
    for i in range(80):
        a = np.array([np.cos(0.02 * i), np.sin(0.02 * i)])
        V.append((np.eye(2) - np.outer(a, a)) @ (-2.0 * W @ X[-1]) + 0.1 * a)
        X.append(X[-1] + 0.05 * V[-1])
    X, V = np.array(X[:-1]), np.array(V)
    _assert_trapezoid_curvatures_kept(X, V)


def test_a_start_from_rest_is_not_taken_for_a_switch():
    # Recordings begin with the robot at rest (a first step of zero length, a first
    # velocity of zero): a step that does not move says nothing about the curvature, and
    # once it counted as perfect agreement, which sent the next step to the one-sided
    # estimate -v_1' dx_1 (the sign of the whole drop wrong).
    W = np.diag([0.5, 2.0])
    _, X, V, _ = _held_commands(W, (1.0, -0.5), 0.05, 40)
    X = np.vstack([X[:1], X])
    V = np.vstack([np.zeros((1, 2)), V])
    _assert_trapezoid_curvatures_kept(X, V)


def test_auto_trusts_velocities_only_where_they_explain_the_positions():
    W = np.diag([0.5, 2.0])
    t, X, V, phi = _held_commands(W, (1.0, -0.5), 0.05, 60)
    dt = np.diff(t)
    assert velocity_disagreement(X, V, dt, "ahead") < 1e-12
    assert velocity_disagreement(X, V, dt) < 0.1
    assert velocity_disagreement(X, np.zeros_like(V), dt) == pytest.approx(1.0)
    assert velocity_disagreement(X, -V, dt) == pytest.approx(2.0, rel=0.05)
    good = Trajectory(X, times=t, velocities=V)
    zeros = Trajectory(X, times=t, velocities=np.zeros_like(V))  # a driver's empty field
    assert choose_method([good, good]) == "trapezoid"
    assert choose_method([good, zeros]) == "euler"
    assert choose_method([good, Trajectory(X, times=t)]) == "euler"
    resting = Trajectory(np.zeros((5, 2)), velocities=np.zeros((5, 2)))
    assert choose_method([resting]) == "euler"
    np.testing.assert_allclose(estimate_potential(good, "auto"), phi - phi[0], atol=1e-12)
    np.testing.assert_array_equal(estimate_potential(zeros, "auto"),
                                  estimate_potential(zeros, "euler"))


def test_velocities_reported_one_sample_late_are_detected_and_shifted():
    # A simulator or driver that reports at each sample the velocity of the step that
    # ended there: taken as they are, the trapezoid doubles the Euler bias.
    W = np.diag([0.5, 2.0])
    t, X, V, phi = _held_commands(W, (1.0, -0.5), 0.05, 60)
    late = np.vstack([V[:1], V[:-1]])  # v_{i+1} moved x_i -> x_{i+1}
    traj = Trajectory(X, times=t, velocities=late)
    assert velocity_disagreement(X, late, np.diff(t), "late") < 1e-12
    assert choose_method([traj]) == "trapezoid_late"
    truth = phi - phi[0]
    err = {m: np.abs(estimate_potential(traj, m) - truth).max()
           for m in ("euler", "trapezoid", "trapezoid_late")}
    assert err["trapezoid"] > 1.5 * err["euler"]
    # Exact but for the last step, where the shifted velocities run out.
    np.testing.assert_allclose(estimate_potential(traj, "auto")[:-1], truth[:-1],
                               atol=1e-12)
    assert err["trapezoid_late"] < 0.05 * err["euler"]


def _noisy(X, sd, seed):
    return X + sd * np.random.default_rng(seed).standard_normal(X.shape)


def test_position_noise_is_measured_and_smooth_motion_is_not_taken_for_noise():
    W = np.diag([0.5, 2.0])
    runs = [_held_commands(W, x0, 0.01, 400) for x0 in ((1.0, -0.5), (-0.8, 0.9))]
    clean = [X for _, X, _, _ in runs]
    steps = np.concatenate([np.sum(np.diff(X, axis=0) ** 2, axis=1) for X in clean])
    assert position_noise(clean) < 1e-6 * steps.mean()
    sd = 2e-3  # per coordinate; the total variance is 2 sd^2
    noisy = [_noisy(X, sd, k) for k, X in enumerate(clean)]
    assert position_noise(noisy) == pytest.approx(2 * sd**2, rel=0.1)
    assert position_noise([np.zeros((4, 2))]) == 0.0  # too short to tell


def test_euler_rule_corrected_for_noise_is_unbiased():
    # Noise as large as the steps adds 2 s^2 to every squared step: uncorrected, the
    # potential drifts with time far beyond its true drop.
    W = np.diag([0.5, 2.0])
    t, X, _, phi = _held_commands(W, (1.0, -0.5), 0.01, 400)
    truth = phi[-1] - phi[0]
    drift, corrected = [], []
    for seed in range(20):
        Y = _noisy(X, 2e-3, seed)
        noise = position_noise([Y])
        drift.append(euler_potential(Y, 0.01)[-1])
        corrected.append(euler_potential(Y, 0.01, noise)[-1])
    assert abs(np.mean(drift) - truth) > 0.5 * abs(truth)
    assert np.mean(corrected) == pytest.approx(truth, rel=0.1)


def test_noisy_positions_do_not_hide_velocities_that_explain_them():
    W = np.diag([0.5, 2.0])
    t, X, V, _ = _held_commands(W, (1.0, -0.5), 0.01, 400)
    Y = _noisy(X, 2e-3, 0)
    traj = Trajectory(Y, times=t, velocities=V)
    assert velocity_disagreement(Y, V, np.diff(t), "ahead") > 0.5
    noise = position_noise([Y])
    assert velocity_disagreement(Y, V, np.diff(t), "ahead", noise) < 0.3
    assert choose_method([traj]) == "euler"
    assert choose_method([traj], noise) == "trapezoid"
    zeros = Trajectory(Y, times=t, velocities=np.zeros_like(V))
    assert choose_method([zeros], noise) == "euler"


def test_euler_scale_measures_the_euler_bias_of_an_isotropic_potential():
    # phi = w |x|^2 under held commands: every Euler drop is the true one over (1 - w dt).
    w, dt = 0.5, 0.05
    trajs = []
    for x0 in ((1.0, -0.5), (-0.3, 0.8)):
        t, X, V, phi = _held_commands(w * np.eye(2), x0, dt, 60)
        trajs.append(Trajectory(X, times=t, velocities=V))
    c = euler_scale([estimate_potential(t, "euler") for t in trajs],
                    [estimate_potential(t, "trapezoid") for t in trajs])
    assert c == pytest.approx(1.0 - w * dt, rel=1e-9)
    t, X, V, phi = _held_commands(w * np.eye(2), (1.0, -0.5), dt, 60)
    np.testing.assert_allclose(c * euler_potential(X, dt), phi - phi[0], atol=1e-12)
    resting = Trajectory(np.zeros((5, 2)), velocities=np.zeros((5, 2)))
    assert euler_scale([estimate_potential(resting, "euler")],
                       [estimate_potential(resting, "trapezoid")]) == 1.0


def _continuous_demo(W, c, x0, hz, switch_times, rng, sub=50, dur=4.0, held=None):
    """A constrained gradient flow integrated in fine substeps; the constraint (one random
    row) changes at ``switch_times`` (s), inside sample periods; instantaneous velocities
    are recorded at the samples (timing "mid"). ``held``: ``(start, stop)`` (s) outside
    which the robot is held still (a recorder running before and after the motion)."""
    n = len(x0)
    projectors = [np.eye(n) - np.linalg.pinv(A) @ A
                  for A in rng.standard_normal((len(switch_times) + 1, 1, n))]
    if held is not None:
        switch_times = np.concatenate([[held[0]], switch_times, [held[1]]])
        projectors = [np.zeros((n, n)), *projectors, np.zeros((n, n))]
    dt, h = 1.0 / hz, 1.0 / hz / sub
    X, V = [], []
    x, t = np.array(x0, dtype=float), 0.0
    for _ in range(int(dur * hz)):
        N = projectors[int(np.searchsorted(switch_times, t))]
        X.append(x.copy())
        V.append(N @ (-W @ (x - c)))
        for _ in range(sub):
            N = projectors[int(np.searchsorted(switch_times, t))]
            x = x + h * N @ (-W @ (x - c))
            t += h
    return Trajectory(np.array(X), dt * np.arange(len(X)), np.array(V))


def test_switch_cuts_find_switches_inside_a_period_and_nothing_else():
    rng = np.random.default_rng(5)
    W, c = np.diag([1.0, 3.0, 8.0]), np.array([0.2, -0.1, 0.3])
    switched = _continuous_demo(W, c, [1.0, -0.8, 0.6], 50, np.array([1.013, 2.517]), rng)
    # Sample i is at i / 50 s: the switches fall inside steps 50 and 125.
    np.testing.assert_array_equal(switch_cuts(switched), [50, 125])
    smooth = _continuous_demo(W, c, [1.0, -0.8, 0.6], 50, np.array([]), rng)
    assert switch_cuts(smooth).size == 0
    # In the first steps, where the stiff motion's miss falls fast, in the last one, and
    # in two steps in a row, where the larger neighbour of either step is the other.
    for times, steps in (([0.013], [0]), ([0.021], [1]), ([3.971], [198]),
                         ([2.011, 2.031], [100, 101])):
        demo = _continuous_demo(W, c, [1.0, -0.8, 0.6], 50, np.array(times), rng)
        np.testing.assert_array_equal(switch_cuts(demo), steps)
    assert best_timing([switched, smooth]) == "mid"


def test_leading_rest_ends_where_the_motion_leaves_the_noise():
    rng = np.random.default_rng(12)
    W, c = np.diag([0.5, 1.0, 2.0]), np.array([0.2, -0.1, 0.3])
    # Held for the first second, starting inside the period after sample 50.
    demo = _continuous_demo(W, c, [1.0, -0.8, 0.6], 50, np.array([2.5]), rng, dur=6.0,
                            held=(1.013, 5.0))
    assert leading_rest(demo.positions, 0.0) == 50  # exact repeats: samples 0..50
    # A longer rest at the end does not hide the one at the start.
    short = _continuous_demo(W, c, [1.0, -0.8, 0.6], 50, np.array([]), rng, dur=6.0,
                             held=(1.013, 1.6))
    assert leading_rest(short.positions, 0.0) == 50
    sd = 2e-3
    noisy = demo.positions + sd * rng.standard_normal(demo.positions.shape)
    assert 49 <= leading_rest(noisy, 3 * sd**2) <= 51
    assert leading_rest(noisy[51:], 3 * sd**2) <= 1  # moving from the start
    # Noise the size of a step: the first samples of motion stay in the neighbourhood of
    # the first; the median step shows them moving.
    step = np.median(np.linalg.norm(np.diff(demo.positions[51:], axis=0), axis=1))
    sd_big = step / np.sqrt(3)
    blurred = demo.positions[51:] + sd_big * rng.standard_normal((len(noisy) - 51, 3))
    assert leading_rest(blurred, 3 * sd_big**2) == 0
    still = demo.positions[0] + sd * rng.standard_normal((40, 3))
    assert leading_rest(still, 3 * sd**2) == 0  # nothing but rest: nothing to trim
    assert leading_rest(noisy, 0.0) == 0  # noise taken for motion when none is known


def test_sampling_gaps_are_lost_samples_not_jittered_stamps():
    rng = np.random.default_rng(4)
    times = 0.01 * np.arange(100) + rng.uniform(-0.002, 0.002, 100)  # a fifth of a step
    X = rng.standard_normal((100, 2))
    assert sampling_gaps(Trajectory(X, times)).size == 0
    keep = np.ones(100, dtype=bool)
    keep[[30, 61, 62]] = False  # one sample lost, then two in a row
    gaps = sampling_gaps(Trajectory(X[keep], times[keep]))
    np.testing.assert_array_equal(gaps, [29, 59])
    assert np.all(np.diff(times[keep])[gaps] > GAP_RATIO * 0.01 * 0.8)
    assert sampling_gaps(Trajectory(X)).size == 0  # no times: steps of 1, no gaps
    # Stamps jittered by up to 0.3 of a step: single steps reach 1.6 of the median, but a
    # long step's neighbours are short by as much.
    wide = 0.01 * np.arange(100) + rng.uniform(-0.003, 0.003, 100)
    assert np.max(np.diff(wide)) > GAP_RATIO * np.median(np.diff(wide))
    assert sampling_gaps(Trajectory(X, wide)).size == 0
    np.testing.assert_array_equal(sampling_gaps(Trajectory(X[keep], wide[keep])), [29, 59])
