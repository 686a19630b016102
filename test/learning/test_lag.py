"""Tests of the tracking-lag estimate (policy_align_ros.learning.lag) and its choice."""

import math

import numpy as np
import pytest

from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.learning.lag import (
    choose_lag,
    kinetic_term,
    lagged_potentials,
    refine_minimum,
)
from policy_align_ros.learning.potential import euler_potential
from policy_align_ros.sim.recording import track_velocity


def test_kinetic_term_uses_recorded_velocities_else_differences():
    t = np.linspace(0.0, 1.0, 101)
    X = np.stack([t**2, 3.0 * t], axis=1)  # v = (2t, 3)
    V = np.stack([2.0 * t, np.full_like(t, 3.0)], axis=1)
    from_velocities = kinetic_term(Trajectory(positions=X, times=t, velocities=V))
    np.testing.assert_allclose(from_velocities, 2.0 * t**2, atol=1e-12)
    from_positions = kinetic_term(Trajectory(positions=X, times=t))
    # Central differences are exact here; the one-sided end only shifts the level, which
    # the alignment's offsets absorb.
    np.testing.assert_allclose(np.diff(from_positions[1:-1]), np.diff(2.0 * t[1:-1] ** 2),
                               atol=1e-9)


def test_lagged_potential_is_the_policy_dot_velocity_integral():
    # A first-order lag v' = (u - v) / tau of a constant command u from rest: the exact
    # potential drop is -u.v dt, which the lag correction recovers from v alone.
    tau, dt, u = 0.1, 1e-3, np.array([1.0, -0.5])
    t = np.arange(0.0, 1.0, dt)
    v = u * (1.0 - np.exp(-t / tau))[:, None]
    X = np.concatenate([[np.zeros(2)], np.cumsum(v[:-1] * dt, axis=0)])
    traj = Trajectory(positions=X, times=t)
    lagged = lagged_potentials([euler_potential(X, traj.dt)], [kinetic_term(traj)], tau)[0]
    exact = -np.concatenate([[0.0], np.cumsum(v[:-1] @ u * dt)])
    assert np.max(np.abs(lagged - exact)) < 0.01 * np.max(np.abs(exact))
    assert lagged_potentials([exact], [kinetic_term(traj)], 0.0)[0] is exact


def test_refine_minimum_finds_the_vertex_of_a_quadratic_score():
    taus = [0.0, 0.02, 0.04, 0.08, 0.16]
    scores = [0.1 + 50.0 * (t - 0.07) ** 2 for t in taus]
    assert refine_minimum(taus, scores) == pytest.approx(0.07, rel=1e-9)
    assert refine_minimum([0.0, 0.02], [1.0, 2.0]) == 0.0


def test_choose_lag_keeps_zero_unless_better_by_a_standard_error():
    calls = []

    def rising(tau):
        calls.append(tau)
        return 1.0 + tau, 0.1

    assert choose_lag(rising)[0] == 0.0
    assert calls == [0.0, 0.02]  # stops as soon as the score rises

    def dip(tau):  # best at 0.08, by much more than two standard errors
        return 0.01 + 100.0 * (tau - 0.08) ** 2, 0.05

    tau, scores = choose_lag(dip)
    assert tau == pytest.approx(0.08, rel=0.05)
    assert 0.0 in scores

    def marginal(tau):  # better, but within two standard errors
        return (1.0 if tau == 0 else 0.98), 0.05

    assert choose_lag(marginal)[0] == 0.0
    assert choose_lag(lambda tau: (None, math.nan)) == (0.0, {})


def _lagged_demos(lag: float, seed: int = 3, n_demos: int = 12):
    """A 3-D quadratic expert under random one-row constraints, tracked with ``lag`` (s),
    or followed exactly (explicit Euler steps of the constrained policy) for ``lag`` 0."""
    rng = np.random.default_rng(seed)
    centre = np.array([0.3, -0.2, 0.1])
    W = np.diag([1.0, 0.6, 0.35])
    demos = []
    for k in range(n_demos):
        a = rng.normal(size=3)
        a /= np.linalg.norm(a)
        N = np.eye(3) - np.outer(a, a) if k % 3 else np.eye(3)
        x0 = centre + rng.uniform(-1.0, 1.0, size=3)
        def command(x, t, N=N):
            return N @ (-W @ (x - centre))

        if lag > 0.0:
            X, _, t = track_velocity(x0, command, 200, 0.02, tau=lag)
        else:
            t = 0.02 * np.arange(200)
            X = [x0]
            for _ in range(199):
                X.append(X[-1] + 0.02 * command(X[-1], 0.0))
            X = np.array(X)
        demos.append(Trajectory(positions=X, times=t))
    return demos, centre


def _minimum(model, start):
    from scipy.optimize import minimize
    res = minimize(lambda x: float(model.potential(x[None])[0]), start,
                   jac=lambda x: -model.policy(x[None])[0], method="L-BFGS-B")
    return res.x


def test_a_tracking_lag_is_found_and_moves_the_minimum_back_to_the_goal():
    demos, centre = _lagged_demos(0.08)
    auto = PolicyAlign().fit(demos)
    assert 0.06 <= auto.tracking_lag_ <= 0.11
    assert auto.fit_summary_["tracking_lag"] == auto.tracking_lag_
    paper = PolicyAlign(tracking_lag=0.0).fit(demos)
    err_auto = np.linalg.norm(_minimum(auto, demos[0].positions[-1]) - centre)
    err_paper = np.linalg.norm(_minimum(paper, demos[0].positions[-1]) - centre)
    assert err_auto < 0.5 * err_paper


def test_exact_gradient_flows_keep_the_papers_estimate():
    demos, _ = _lagged_demos(0.0)
    model = PolicyAlign().fit(demos)
    assert model.tracking_lag_ == 0.0


def test_a_slow_loops_lag_is_bracketed_and_refined_not_stopped_at_a_grid_point():
    # A compliant arm's 250 ms velocity loop: the score falls up to 0.32 s and rises after.
    def slow(tau):
        return 0.01 + (tau - 0.25) ** 2, 1e-4

    tau, scores = choose_lag(slow)
    assert max(scores) > 0.32 and tau == pytest.approx(0.25, rel=0.02)
    # A score still falling at the grid's last lag measures no lag there: that lag only
    # brackets, and the best below it stands.
    tau, scores = choose_lag(lambda t: (1.0 - t, 1e-4))
    assert max(scores) > 0.32 and tau == 0.32


def test_tracking_lag_is_validated():
    demos, _ = _lagged_demos(0.08, n_demos=3)
    with pytest.raises(ValueError, match="tracking_lag"):
        PolicyAlign(tracking_lag=-0.1).fit(demos)


def test_no_lag_below_one_sample_period_is_scored():
    scored = []

    def score(tau):
        scored.append(tau)
        return 0.01 + 100.0 * (tau - 0.01) ** 2, 1e-4

    tau, _ = choose_lag(score, period=0.03)
    assert min(t for t in scored if t > 0) >= 0.03
    assert tau == 0.0 or tau >= 0.03


def test_the_lag_is_saved_with_the_model(tmp_path):
    demos, _ = _lagged_demos(0.08)
    model = PolicyAlign().fit(demos)
    path = tmp_path / "lagged.npz"
    model.save(path)
    loaded = PolicyAlign.load(path)
    assert loaded.tracking_lag_ == model.tracking_lag_ > 0.0
    X = demos[1].positions
    np.testing.assert_allclose(loaded.policy(X), model.policy(X), rtol=1e-12, atol=1e-12)
