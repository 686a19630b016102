"""The PolicyAlign estimator end to end (policy_align_ros.learning.policy_align)."""

import numpy as np
import pytest

import policy_align_ros.learning.estimates as estimates_module
import policy_align_ros.learning.pieces as pieces_module
from policy_align_ros.experiments.evaluation import evaluate_policy_align, holdout_masks
from policy_align_ros.experiments.toy import make_toy_dataset
from policy_align_ros.learning import NotFittedError, PolicyAlign, Trajectory, metrics
from policy_align_ros.learning.anchor import bowl_curvature, goal_curvature
from policy_align_ros.learning.regressors import LocalLinearRegression
from policy_align_ros.sim.demonstrations import rollout
from policy_align_ros.sim.experts import QuadraticPotential


@pytest.fixture(scope="module")
def parabola():
    rng = np.random.default_rng(11)
    data = make_toy_dataset("parabola", 40, 40, rng)
    masks = holdout_masks([40] * 40, rng)
    model = PolicyAlign(sigma="medium", random_state=0).fit(data.trajectories,
                                                            train_mask=masks)
    return data, masks, model


def test_known_potential_is_recovered(parabola):
    data, masks, model = parabola
    scores = evaluate_policy_align(
        model, [t.positions for t in data.trajectories], data.phi, data.pi,
        data.nullspace, masks,
    )
    assert scores["alignment_nmse"] < 0.03
    assert scores["potential_nmse"] < 0.03
    assert scores["nupe"] < 0.1
    assert scores["ncpe"] < 0.1
    assert scores["discarded_pct"] <= 10.0


def test_learnt_attributes_follow_the_contract(parabola):
    data, _, model = parabola
    assert model.sigma2_ > 0
    assert model.offsets_.shape == (40,)
    assert model.inliers_.dtype.kind == "i"
    assert len(model.aligned_potentials_) == 40
    X = data.trajectories[0].positions
    assert model.potential(X).shape == (40,)
    assert model.policy(X).shape == (40, 2)
    assert model.policy(X[0]).shape == (1, 2)


def test_policy_is_the_negative_gradient_of_the_potential(parabola):
    _, _, model = parabola
    X = np.random.default_rng(0).uniform(-1.5, 1.5, size=(20, 2))
    eps = 1e-6
    grad = np.stack([
        (model.potential(X + eps * e) - model.potential(X - eps * e)) / (2 * eps)
        for e in np.eye(2)
    ], axis=1)
    np.testing.assert_allclose(model.policy(X), -grad, rtol=1e-5, atol=1e-8)


def test_policy_is_invariant_to_constants_added_to_trajectory_potentials(monkeypatch):
    data = make_toy_dataset("parabola", 25, 30, np.random.default_rng(4))
    reference = PolicyAlign(sigma="medium").fit(data.trajectories)
    shifts = iter(np.random.default_rng(9).normal(scale=50.0, size=25))
    original = estimates_module.estimate_potential
    monkeypatch.setattr(estimates_module, "estimate_potential",
                        lambda traj, *args: original(traj, *args) + next(shifts))
    shifted = PolicyAlign(sigma="medium").fit(data.trajectories)
    X = np.random.default_rng(1).uniform(-1.5, 1.5, size=(50, 2))
    np.testing.assert_allclose(shifted.policy(X), reference.policy(X), rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(shifted.inliers_, reference.inliers_)


class _RecordingRegressor(LocalLinearRegression):
    """Remembers what PolicyAlign passes to ``fit``."""

    def fit(self, X, y, groups=None):
        self.seen_ = (np.array(X), np.array(groups))
        return super().fit(X, y, groups)


def test_regressor_sees_only_training_samples_of_kept_demonstrations():
    data = make_toy_dataset("parabola", 12, 30, np.random.default_rng(6))
    masks = holdout_masks([30] * 12, np.random.default_rng(7))
    model = PolicyAlign(sigma="medium", regressor=_RecordingRegressor(bandwidth=0.5))
    model.fit(data.trajectories, train_mask=masks)
    X, groups = model.regressor_.seen_
    expected = np.concatenate([data.trajectories[k].positions[masks[k]]
                               for k in model.inliers_])
    np.testing.assert_array_equal(X, expected)
    assert set(np.unique(groups)) == set(model.inliers_)


def test_a_trajectory_the_alignment_cannot_level_is_levelled_by_the_global_model():
    # Eight demonstrations meet at the attractor; a ninth runs far from all of them, so the
    # alignment cannot find its offset (paper: an outlier). Its shape is still data.
    pot = QuadraticPotential(np.zeros(2), 0.5)
    starts = [2.0 * np.array([np.cos(a), np.sin(a)]) for a in np.linspace(0.0, 2.0, 8)]
    demos = [rollout(x0, pot, lambda x, t, pi: np.zeros((0, 2)), 40, 0.2).trajectory
             for x0 in starts]
    # Held on the line x1 = -3 (a wall), it slides down x2 only.
    wall = rollout(np.array([-3.0, 2.5]), pot, lambda x, t, pi: np.array([[1.0, 0.0]]),
                   30, 0.2)
    demos.append(wall.trajectory)
    far = wall.trajectory.positions
    model = PolicyAlign(sigma="narrow", random_state=0).fit(demos)
    assert model.groups_[8] != 0 and np.all(model.groups_[:8] == 0)
    assert 8 in model.inliers_ and metrics.percent_discarded(model) == 0.0
    assert metrics.percent_unaligned(model) == pytest.approx(100.0 / 9)
    assert model.fit_summary_["n_levelled_by_model"] == 1
    # Levelled by the model: its aligned potential matches the truth's level there.
    e = model.aligned_potentials_[8] - pot.value(far)
    ref = model.aligned_potentials_[0] - pot.value(demos[0].positions)
    assert abs(e.mean() - ref.mean()) < 0.05 * np.ptp(pot.value(far))
    # A regressor that cannot re-fit offsets freely is given the aligned set only.
    local = PolicyAlign(sigma="narrow", random_state=0,
                        regressor=LocalLinearRegression()).fit(demos)
    np.testing.assert_array_equal(local.inliers_, np.arange(8))
    assert metrics.percent_discarded(local) == pytest.approx(100.0 / 9)


def test_timed_trajectories_give_a_policy_per_second():
    # Unconstrained exact flow of phi = 0.5 ||x||^2 (pi = -x), sampled at 20 Hz.
    rng = np.random.default_rng(2)
    t = np.arange(0, 3.0, 0.05)
    trajs = [Trajectory(x0[None, :] * np.exp(-t)[:, None], times=t)
             for x0 in rng.uniform(-2, 2, size=(30, 2))]
    model = PolicyAlign(sigma="medium").fit(trajs)
    X = np.concatenate([tr.positions[5:40:5] for tr in trajs])
    pi_hat = model.policy(X)
    rel = np.linalg.norm(pi_hat + X, axis=1).mean() / np.linalg.norm(X, axis=1).mean()
    assert rel < 0.15  # per second: ~20x smaller than per-sample units would give


def test_demonstrations_that_never_move_are_refused():
    still = [Trajectory(np.tile([0.1 * k, 0.0], (20, 1)), 0.01 * np.arange(20))
             for k in range(3)]
    with pytest.raises(ValueError, match="^trajectories: "):
        PolicyAlign().fit(still)


def test_sigma_is_the_one_positional_argument():
    # DESIGN: PolicyAlign(sigma) and "other constructor arguments are keyword-only".
    assert PolicyAlign("narrow").sigma == "narrow"
    with pytest.raises(TypeError):
        PolicyAlign("narrow", "euler")


def test_errors_are_clear():
    with pytest.raises(NotFittedError):
        PolicyAlign().policy(np.zeros((1, 2)))
    with pytest.raises(ValueError, match=r"\b2\b"):  # the number of trajectories needed
        PolicyAlign().fit([np.zeros((3, 2))])
    with pytest.raises(ValueError, match="integration.*'rk4'"):
        PolicyAlign(integration="rk4").fit([np.zeros((3, 2)), np.ones((3, 2))])
    data = make_toy_dataset("parabola", 6, 10, np.random.default_rng(0))
    with pytest.raises(ValueError, match="train_mask 1"):
        PolicyAlign().fit(data.trajectories, train_mask=[np.ones(10, bool), np.ones(3, bool)]
                          + [np.ones(10, bool)] * 4)
    model = PolicyAlign().fit(data.trajectories)
    with pytest.raises(ValueError, match=r"shape \(m, 2\)"):
        model.policy(np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"^X\b.*\brow 1\b"):
        model.policy(np.array([[0.0, 0.0], [np.nan, 0.0]]))
    # A single state is one query, as for the regressors themselves.
    assert model.policy(np.zeros(2)).shape == (1, 2)


def _switching_demos(pot, rng, n_demos, n_samples, dt, switch_t):
    """Held-command demonstrations of ``pot`` in 3-D from uniform starts, each under one
    random constraint row re-drawn once at ``switch_t`` seconds."""
    demos = []
    for k in range(n_demos):
        rows = rng.standard_normal((2, 3))
        demos.append(rollout(rng.uniform(-1, 1, 3), pot,
                             lambda x, t, pi, r=rows: r[:1] if t < switch_t else r[1:],
                             n_samples, dt, name=str(k)).trajectory)
    return demos


def test_default_integration_uses_recorded_velocities_that_explain_the_motion():
    # Held velocity commands (Euler steps at 50 Hz) of a 3-D quadratic, one constraint row
    # per demonstration re-drawn once: the trapezoid rule is exact on such data, the Euler
    # rule biased at order dt, and "auto" must see that the velocities can be trusted.
    rng = np.random.default_rng(5)
    pot = QuadraticPotential([0.3, -0.2, 0.1], np.diag([0.5, 1.0, 2.0]))
    demos = _switching_demos(pot, rng, 12, 60, 0.02, switch_t=0.6)
    X = rng.uniform(-1, 1, (200, 3))
    auto = PolicyAlign(random_state=0).fit(demos)
    euler = PolicyAlign(integration="euler", random_state=0).fit(demos)
    assert auto.integration_ == auto.fit_summary_["integration"] == "trapezoid"
    # Both rules were fitted and the regressor's CV chose: the biased Euler potentials
    # are the ones no single smooth function explains across held-out demonstrations.
    cv = auto.fit_summary_["integration_cv"]
    assert set(cv) == {"euler", "trapezoid"} and cv["trapezoid"] < 0.5 * cv["euler"]
    # A regressor without CV scores cannot choose: the paper's Euler rule.
    local = PolicyAlign(regressor=LocalLinearRegression(), random_state=0).fit(demos)
    assert local.integration_ == "euler"
    assert metrics.nupe(pot.policy(X), auto.policy(X)) < 0.01 * metrics.nupe(
        pot.policy(X), euler.policy(X))
    # A driver that leaves the velocity field at zero: the velocities are not used.
    zeroed = [Trajectory(d.positions, d.times, np.zeros_like(d.velocities)) for d in demos]
    assert PolicyAlign(random_state=0).fit(zeroed).integration_ == "euler"


def test_noisy_recordings_without_velocities_still_give_the_policy(monkeypatch):
    # Position noise as large as the median step (100 Hz): every squared step gains
    # 2 s^2 on average, which the fit estimates and removes.
    rng = np.random.default_rng(6)
    pot = QuadraticPotential([0.3, -0.2, 0.1], np.diag([0.5, 1.0, 2.0]))
    clean = _switching_demos(pot, rng, 16, 200, 0.01, switch_t=1.0)
    steps = np.concatenate([np.linalg.norm(np.diff(d.positions, axis=0), axis=1)
                            for d in clean])
    sd = np.median(steps) / np.sqrt(3)
    noisy = [Trajectory(d.positions + sd * rng.standard_normal(d.positions.shape), d.times)
             for d in clean]
    model = PolicyAlign(random_state=0).fit(noisy)
    assert model.position_noise_ == pytest.approx(3 * sd**2, rel=0.15)
    assert 0.1 < model.fit_summary_["noise_to_step"] < 2.0
    X = rng.uniform(-1, 1, (200, 3))
    corrected = metrics.nupe(pot.policy(X), model.policy(X))
    assert corrected < 0.01
    # The same fit without the correction: the noise's drift swamps the potential.
    monkeypatch.setattr(estimates_module, "position_noise", lambda positions: 0.0)
    uncorrected = PolicyAlign(random_state=0).fit(noisy)
    assert metrics.nupe(pot.policy(X), uncorrected.policy(X)) > 5 * corrected


def test_auto_removes_the_euler_rescaling_of_an_isotropic_potential():
    # With H a multiple of the identity the Euler potentials are the true ones times a
    # constant, invisible to the CV; trusted velocities measure it.
    rng = np.random.default_rng(8)
    w, dt = 0.5, 0.05
    pot = QuadraticPotential([0.3, -0.2, 0.1], w * np.eye(3))
    demos = _switching_demos(pot, rng, 12, 60, dt, switch_t=1.0)
    auto = PolicyAlign(random_state=0).fit(demos)
    euler = PolicyAlign(integration="euler", random_state=0).fit(demos)
    assert auto.euler_scale_ == pytest.approx(1.0 - w * dt, rel=1e-6)
    assert auto.fit_summary_["euler_scale"] == auto.euler_scale_ and euler.euler_scale_ == 1.0
    X = rng.uniform(-1, 1, (200, 3))
    assert metrics.nupe(pot.policy(X), auto.policy(X)) < 1e-4
    assert metrics.nupe(pot.policy(X), euler.policy(X)) > 1e-4


def test_demonstrations_are_split_where_the_constraint_switches_inside_a_period(monkeypatch):
    # Continuous-time recordings: the constraint changes twice per demonstration at random
    # times inside sample periods, where no rule gets the step's potential drop right.
    from test_potential import _continuous_demo

    rng = np.random.default_rng(8)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    W, c = q @ np.diag([1.0, 3.0, 9.0]) @ q.T, np.array([0.1, -0.2, 0.3])

    def demos(k):
        return [_continuous_demo(W, c, c + rng.uniform(-1, 1, 3), 50,
                                 np.sort(rng.uniform(0, 4, 2)), rng) for _ in range(k)]

    train, test = demos(20), demos(5)
    X = np.concatenate([t.positions for t in test])
    pi = -(X - c) @ W

    def nupe(model):
        return metrics.nupe(pi, model.policy(X))

    model = PolicyAlign(random_state=0).fit(train)
    assert model.fit_summary_["n_pieces"] >= 20 + 30  # most of the 40 switches found
    assert [len(p) for p in model.aligned_potentials_] == [t.n_samples for t in train]
    assert len(model.offsets_) == 20 and set(model.inliers_) == set(range(20))
    # The pieces of a demonstration are tied across its switches by the midpoint drop:
    # the aligned potential follows the true one along each demonstration (left to the
    # alignment, the pieces' levels were off by 0.83 of the potential's spread).
    true = [0.5 * np.einsum("ij,jk,ik->i", t.positions - c, W, t.positions - c)
            for t in train]
    spread = np.concatenate(true).std()
    assert max(np.ptp(p - y) for p, y in zip(model.aligned_potentials_, true,
                                             strict=True)) < 0.15 * spread
    monkeypatch.setattr(pieces_module, "switch_cuts", lambda t: np.zeros(0, dtype=np.int64))
    whole = PolicyAlign(random_state=0).fit(train)
    assert whole.fit_summary_["n_pieces"] == 20
    assert nupe(model) < 1e-6 and nupe(model) < 1e-2 * nupe(whole)


def test_rest_before_noisy_demonstrations_costs_nothing():
    # A recorder started a second before the motion and stopped a second after it: the
    # robot is held still, its states repeat with their noise. The motion starts inside a
    # sample period, where every rule misses the step's drop to first order; as many
    # samples of rest beside that step put their whole cluster at the wrong level (nUPE
    # 12 times the same data's without the rests, before the leading rest was trimmed).
    from test_potential import _continuous_demo

    rng = np.random.default_rng(21)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    W, c = q @ np.diag([0.5, 1.5, 3.0]) @ q.T, np.array([0.1, -0.2, 0.3])
    sd, hold = 2e-3, 50

    def demo(start):
        t = _continuous_demo(W, c, c + rng.uniform(-1, 1, 3), 50,
                             np.sort(rng.uniform(1.5, 4.5, 2)), rng, dur=6.0,
                             held=(1.0 + rng.uniform(0.001, 0.019), 5.0))
        return Trajectory(t.positions + sd * rng.standard_normal(t.positions.shape),
                          t.times, t.velocities)

    held = [demo(k) for k in range(24)]
    moving = [Trajectory(t.positions[hold:-hold], t.times[hold:-hold],
                         t.velocities[hold:-hold]) for t in held]
    test = [_continuous_demo(W, c, c + rng.uniform(-1, 1, 3), 50, np.array([]), rng)
            for _ in range(5)]
    X = np.concatenate([t.positions for t in test])
    pi = -(X - c) @ W
    with_rest = PolicyAlign(random_state=0).fit(held)
    without = PolicyAlign(random_state=0).fit(moving)
    assert with_rest.fit_summary_["n_samples_left_out"] >= 24 * (hold - 1)
    assert [len(p) for p in with_rest.aligned_potentials_] == [t.n_samples for t in held]
    # The rest keeps the level of the motion beside it.
    for p in with_rest.aligned_potentials_:
        assert np.ptp(p[:hold - 1]) < 0.01 * np.ptp(p)
    nupe = metrics.nupe(pi, with_rest.policy(X))
    assert nupe < 1e-3 and nupe < 2.0 * metrics.nupe(pi, without.policy(X))


def test_demonstrations_are_split_where_samples_were_lost(monkeypatch):
    # A recorder lost the sample at each of the two constraint switches (10 Hz, 5-D, two
    # random rows): the steps over the gaps mix two constraints' motion, which no rule
    # integrates; cut there, the alignment levels the pieces.
    rng = np.random.default_rng(9)
    n, dt, n_samples = 5, 0.1, 40
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    pot = QuadraticPotential(rng.uniform(-0.3, 0.3, n),
                             q @ np.diag(np.linspace(0.5, 2.5, n)) @ q.T)
    demos = []
    for k in range(30):
        rows = rng.standard_normal((3, 2, n))
        d = rollout(rng.uniform(-1, 1, n), pot,
                    lambda x, t, pi, r=rows: r[min(int(t / 1.3), 2)], n_samples, dt,
                    name=str(k)).trajectory
        keep = np.ones(n_samples, dtype=bool)
        keep[[13, 26]] = False
        demos.append(Trajectory(d.positions[keep], d.times[keep], d.velocities[keep],
                                name=d.name))
    X = rng.uniform(-1, 1, (200, n))
    model = PolicyAlign(random_state=0).fit(demos)
    assert model.fit_summary_["n_pieces"] == 90
    assert [len(p) for p in model.aligned_potentials_] == [t.n_samples for t in demos]
    monkeypatch.setattr(pieces_module, "sampling_gaps", lambda t: np.zeros(0, dtype=np.int64))
    whole = PolicyAlign(random_state=0).fit(demos)
    split_error = metrics.nupe(pot.policy(X), model.policy(X))
    assert split_error < 1e-8
    assert metrics.nupe(pot.policy(X), whole.policy(X)) > 1e3 * split_error


def test_a_switch_in_the_first_steps_leaves_those_samples_out_of_the_fit():
    # Every demonstration switches inside its first or second step, where a piece would
    # keep one or two samples, and once more later.
    from test_potential import _continuous_demo

    rng = np.random.default_rng(11)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    W, c = q @ np.diag([1.0, 3.0, 9.0]) @ q.T, np.array([0.1, -0.2, 0.3])

    def demos(k):
        return [_continuous_demo(W, c, c + rng.uniform(-1, 1, 3), 50,
                                 np.array([rng.uniform(0.002, 0.038), rng.uniform(1, 3)]), rng)
                for _ in range(k)]

    train, test = demos(16), demos(5)
    model = PolicyAlign(random_state=0).fit(train)
    assert model.fit_summary_["n_samples_left_out"] >= 16
    assert [len(p) for p in model.aligned_potentials_] == [t.n_samples for t in train]
    assert all(np.all(np.isfinite(p)) for p in model.aligned_potentials_)
    X = np.concatenate([t.positions for t in test])
    assert metrics.nupe(-(X - c) @ W, model.policy(X)) < 1e-6


def _offset_demos(offset, seed=0, n_demos=6, n_samples=40, dt=0.05):
    """Exact Euler steps of ``phi = x' A x / 2`` around ``offset``, with velocities."""
    rng = np.random.default_rng(seed)
    A = np.diag([1.0, 2.0])
    demos = []
    for k in range(n_demos):
        x = rng.normal(size=2)
        xs = [x]
        for _ in range(n_samples - 1):
            xs.append(xs[-1] - dt * A @ xs[-1])
        xs = np.array(xs)
        demos.append(Trajectory(xs + offset, dt * np.arange(n_samples), -xs @ A,
                                name=str(k)))
    return demos


def test_kernel_width_and_groups_do_not_depend_on_where_the_states_lie():
    # Closest approaches expanded on uncentred states cancelled at 1e7: sigma^2 fell to
    # a sixteenth and half the demonstrations became outliers.
    X = np.array([[0.5, 0.5], [1.0, -1.0]])
    near = PolicyAlign(random_state=0).fit(_offset_demos(0.0))
    for offset in (1e6, 1e7):
        far = PolicyAlign(random_state=0).fit(_offset_demos(offset))
        assert far.sigma2_ == pytest.approx(near.sigma2_, rel=1e-5)
        np.testing.assert_array_equal(far.groups_, near.groups_)
        np.testing.assert_array_equal(far.inliers_, near.inliers_)
        np.testing.assert_allclose(far.policy(X + offset), near.policy(X), atol=1e-3)


def test_unnamed_trajectories_are_named_by_their_index_in_errors():
    demos = [Trajectory(t.positions, t.times) for t in _offset_demos(0.0)]
    with pytest.raises(ValueError, match="^trajectory 0: ") as err:
        PolicyAlign(integration="trapezoid").fit(demos)
    assert "None" not in str(err.value)
    assert all(t.name is None for t in demos)


def test_summary_counts_trajectories_when_demonstrations_are_split(monkeypatch):
    # Demonstrations split at a constraint switch, and a copy far from all of them that
    # the global model levels: the counts are of trajectories, not of pieces.
    from test_potential import _continuous_demo

    rng = np.random.default_rng(3)
    W, c = np.diag([1.0, 3.0, 9.0]), np.array([0.1, -0.2, 0.3])
    demos = [_continuous_demo(W, c, c + rng.uniform(-1, 1, 3), 25,
                              np.array([rng.uniform(0.5, 1.5)]), rng, sub=20, dur=2.0)
             for _ in range(6)]
    far = demos[0]
    demos.append(Trajectory(far.positions + 50.0, far.times, far.velocities))
    model = PolicyAlign(random_state=0).fit(demos)
    summary = model.fit_summary_
    assert summary["n_pieces"] > summary["n_trajectories"] == 7
    assert model.groups_[6] != 0 and np.all(model.groups_[:6] == 0)
    assert summary["n_inliers"] == len(model.inliers_) == 7
    assert summary["n_levelled_by_model"] == 1
    assert summary["n_groups"] == len(np.unique(model.groups_)) == 2


def test_a_piece_left_out_of_a_kept_trajectory_is_levelled_from_its_kept_neighbour():
    # Trajectory 0's second piece fell into a group of its own, at an arbitrary level:
    # merged, it continues the kept first piece by the rule's own drop across the cut.
    model = PolicyAlign()
    model.groups_ = np.array([0, 1, 0])
    model.inliers_ = np.array([0, 2])
    model.offsets_ = np.zeros(3)
    model.aligned_potentials_ = [np.array([5.0, 4.9, 4.8]), np.array([100.0, 99.9, 99.8]),
                                 np.zeros(4)]
    model.integration_, model.position_noise_, model.euler_scale_ = "trapezoid", 0.0, 1.0
    x = np.column_stack([0.1 * np.arange(6), np.zeros(6)])
    line = Trajectory(x, 0.1 * np.arange(6), np.tile([1.0, 0.0], (6, 1)))
    parents = [line, Trajectory(np.zeros((4, 2)))]
    model._merge_pieces(np.array([(0, 0, 3), (0, 3, 6), (1, 0, 4)]), parents)
    np.testing.assert_allclose(model.aligned_potentials_[0],
                               [5.0, 4.9, 4.8, 4.7, 4.6, 4.5], atol=1e-12)
    np.testing.assert_array_equal(model.groups_, [0, 0])
    np.testing.assert_array_equal(model.inliers_, [0, 1])


def test_merged_pieces_get_contiguous_groups():
    # Trajectory 0's pieces lie in groups 0 and 1, trajectory 1's in group 2: merged,
    # trajectory 1 is in the second of two groups, which must be numbered 1.
    model = PolicyAlign()
    model.groups_ = np.array([0, 1, 2, 0])
    model.inliers_ = np.array([0, 1, 3])
    model.offsets_ = np.array([0.5, 1.0, 2.0, 3.0])
    model.aligned_potentials_ = [np.zeros(3), np.ones(3), np.ones(4), np.ones(5)]
    parents = [Trajectory(np.zeros((6, 2))), Trajectory(np.zeros((4, 2))),
               Trajectory(np.zeros((5, 2)))]
    spans = np.array([(0, 0, 3), (0, 3, 6), (1, 0, 4), (2, 0, 5)])
    model._merge_pieces(spans, parents)
    np.testing.assert_array_equal(model.groups_, [0, 1, 0])
    np.testing.assert_array_equal(model.inliers_, [0, 2])
    np.testing.assert_array_equal(model.offsets_, [0.5, 2.0, 3.0])


def _human_timed_demos(goal, n_demos=7, seed=0):
    # Paths of the flow of a skewed bowl, walked with a teacher's timing: at rest at the
    # start, bell-shaped speed, durations differing by a factor of two, cut at the goal.
    rng = np.random.default_rng(seed)
    H = np.array([[3.0, 1.0], [1.0, 1.0]])
    demos = []
    for _ in range(n_demos):
        x = goal + rng.uniform(-2.0, 2.0, 2)
        path = [x.copy()]
        while np.linalg.norm(x - goal) > 1e-3:
            x = x - 0.01 * H @ (x - goal)
            path.append(x.copy())
        path = np.array(path)
        arc = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0),
                                                              axis=1))))
        s = np.linspace(0.0, 1.0, 120)
        done = s**3 * (10 - 15 * s + 6 * s**2)  # minimum jerk: rest at both ends
        positions = np.stack([np.interp(done * arc[-1], arc, path[:, d]) for d in range(2)],
                             axis=1)
        demos.append(Trajectory(positions=positions, times=s * rng.uniform(1.0, 2.0)))
    return demos


def _descend(model, x, steps=3000):
    for _ in range(steps):
        x = x + 0.002 * model.policy(x[None])[0]
    return x


def test_learnt_minimum_is_the_demonstrated_goal_and_does_not_move_when_retimed():
    goal = np.array([0.5, -1.0])
    demos = _human_timed_demos(goal)
    extent = np.ptp(np.concatenate([d.positions for d in demos]), axis=0).max()
    model = PolicyAlign().fit(demos)
    anchor = model.fit_summary_["anchor"]
    assert anchor["anchored"] and np.allclose(anchor["goal"], goal, atol=1e-3 * extent)
    # The direction weight kept is one whose policy takes every start to the goal.
    assert anchor["direction_weight"] == model.regressor_.direction_weight
    assert model.fit_summary_["goal"]["n_starts_elsewhere"] == 0
    # ... and at whose goal the potential is a strict minimum, not a saddle.
    assert anchor["goal_is_minimum"]
    assert goal_curvature(model.regressor_.gradient, np.asarray(anchor["goal"]), extent) > 0
    # Its bowl is no flatter than the demonstrations' durations allow.
    assert anchor["min_curvature"] == pytest.approx(bowl_curvature(demos))
    assert model.regressor_.min_curvature_ == anchor["min_curvature"]
    first = _descend(model, demos[0].positions[0])
    assert np.linalg.norm(first - goal) < 0.01 * extent
    # The same path walked with another timing: slow in the middle, fast at the ends.
    d0 = demos[0]
    s = np.linspace(0.0, 1.0, len(d0.times))
    warped = np.stack([np.interp(s, (s**3 * (10 - 15 * s + 6 * s**2)), d0.positions[:, k])
                       for k in range(2)], axis=1)
    retimed = [Trajectory(positions=warped, times=d0.times * 1.7), *demos[1:]]
    again = _descend(PolicyAlign().fit(retimed), demos[0].positions[0])
    assert np.linalg.norm(again - first) < 0.01 * extent


def test_a_fit_in_metres_is_the_fit_in_millimetres_rescaled():
    # The same teacher recorded in mm and in m: no threshold of the fit may depend on the
    # unit (LASA's 26 shapes give the same rollouts in both, `docs/design/lasa.md`).
    goal = np.array([0.5, -1.0])
    mm = _human_timed_demos(goal, n_demos=5)
    metres = [Trajectory(positions=d.positions * 1e-3, times=d.times) for d in mm]
    in_mm, in_m = PolicyAlign().fit(mm), PolicyAlign().fit(metres)
    X = np.concatenate([d.positions[::10] for d in mm])
    expected = in_mm.policy(X)
    np.testing.assert_allclose(in_m.policy(X * 1e-3) * 1e3, expected,
                               atol=1e-6 * np.abs(expected).max())
    assert (in_m.fit_summary_["anchor"]["direction_weight"]
            == in_mm.fit_summary_["anchor"]["direction_weight"])


def test_a_fit_moved_rotated_and_stamped_from_the_epoch_is_the_fit_moved_and_rotated():
    # A user's goal is rarely the origin, their axes are their robot's, and their recorder
    # stamps in seconds since 1970: no step of the fit may depend on where, in which
    # orientation or from which instant the same motion was recorded.
    goal = np.array([0.5, -1.0])
    demos = _human_timed_demos(goal, n_demos=5)
    angle = 0.7
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    shift = np.array([40.0, -25.0])
    moved = [Trajectory(positions=d.positions @ R.T + shift, times=d.times + 1.7e9)
             for d in demos]
    base, other = PolicyAlign().fit(demos), PolicyAlign().fit(moved)
    X = np.concatenate([d.positions[::10] for d in demos])
    expected = base.policy(X)
    np.testing.assert_allclose(other.policy(X @ R.T + shift) @ R, expected,
                               atol=1e-5 * np.abs(expected).max())
    assert other.fit_summary_["anchor"]["anchored"] == base.fit_summary_["anchor"]["anchored"]
    np.testing.assert_allclose(other.timing_scales_, base.timing_scales_, rtol=1e-6)


def test_demonstrations_that_stop_apart_still_show_one_goal_the_runs_reach():
    # A teacher never stops twice at the same point: the same human-timed paths, each
    # ending 1-2.5 % of the extent from the goal, blended in so that each still ends at
    # rest. The goal they show is the mean of their ends, and runs from their starts must
    # stop there rather than wherever the paper's potential has its minimum.
    goal = np.array([0.5, -1.0])
    demos = _human_timed_demos(goal, n_demos=6)
    extent = np.ptp(np.concatenate([d.positions for d in demos]), axis=0).max()
    angles = np.linspace(0.0, 2 * np.pi, 6, endpoint=False)
    offsets = extent * np.linspace(0.01, 0.025, 6)[:, None] * np.stack(
        [np.cos(angles), np.sin(angles)], axis=1)
    stopped = []
    for d, offset in zip(demos, offsets, strict=True):
        u = (d.times - d.times[0]) / (d.times[-1] - d.times[0])
        stopped.append(Trajectory(positions=d.positions + (u * u * (3 - 2 * u))[:, None]
                                  * offset, times=d.times))
    model = PolicyAlign().fit(stopped)
    shown = goal + offsets.mean(axis=0)
    anchor = model.fit_summary_["anchor"]
    assert anchor["anchored"] and np.allclose(anchor["goal"], shown, atol=1e-3 * extent)
    for d in stopped:
        assert np.linalg.norm(_descend(model, d.positions[0]) - shown) < 0.01 * extent
