"""Tests of policy_align_ros.control.guard (the extrapolation guard)."""

import numpy as np
import pytest
from control_rigs import (
    ACC,
    DT,
    DT_NS,
    LOWER,
    TALOS_JOINTS,
    UPPER,
    VMAX,
    N,
    _assert_ramped,
    _Row,
    _Run,
)
from hypothesis import given, settings
from hypothesis import strategies as st

from policy_align_ros.control import (
    DEFAULT_MAX_EXTRAPOLATION,
    ControlStep,
    ExtrapolationGuard,
    SupportDistance,
    ZeroCause,
    model_permutation,
)
from policy_align_ros.kinematics import Robot

# -- extrapolation guard ---------------------------------------------------------------
SPACING = 0.1  # state units per spacing of the toy support


class _PointSupport:
    """Toy distance: the demonstrated data is the single state ``c``, spacing 0.1."""

    def __init__(self, center):
        self.center = np.asarray(center, dtype=float)
        self.calls = 0

    def __call__(self, q):
        self.calls += 1
        diff = q - self.center
        r = float(np.linalg.norm(diff))
        return r / SPACING, (diff / (r * SPACING) if r > 0 else None)


def _guarded_step(policy, max_extrapolation=3.0, constraints=(), acc=None):
    guard = ExtrapolationGuard(_PointSupport(np.zeros(N)), max_extrapolation)
    return ControlStep(-10 * np.ones(N), 10 * np.ones(N), VMAX, DT, constraints=constraints,
                       policy=policy, guard=guard, max_acceleration=acc)


def _outward(scale=1.0):
    """A constant policy along +x (model order = controller order)."""
    return lambda X: np.tile(scale * np.eye(N)[0], (len(X), 1))


def test_guard_leaves_commands_inside_the_region_alone():
    step = _guarded_step(_outward(0.3))
    plain = ControlStep(-10 * np.ones(N), 10 * np.ones(N), VMAX, DT, policy=_outward(0.3))
    for x in (0.0, 0.1, 0.29999):  # d = 0, 1, ~3 spacings <= max_extrapolation = 3
        q = np.zeros(N)
        q[0] = x
        np.testing.assert_array_equal(step(q)[0], plain(q)[0])
        assert step.extrapolation_scale == 1.0
        assert step.extrapolation_distance == pytest.approx(x / SPACING)


def test_guard_stops_outward_motion_beyond_the_band_and_never_scales_inward_motion():
    step = _guarded_step(_outward(0.3))
    band = step.guard.band(1.0 / SPACING, VMAX, None)
    assert band == 1.0  # no acceleration limit: the minimum band
    q = np.zeros(N)
    q[0] = SPACING * (3.0 + band + 0.01)  # beyond the band
    qdot, _, cause = step(q)
    assert cause is None and not np.any(qdot) and step.extrapolation_scale == 0.0
    # The same state with the policy pointing back in: unscaled, and so is sideways motion.
    step.policy = _outward(-0.3)
    qdot = step(q)[0]
    np.testing.assert_allclose(qdot, -0.3 * np.eye(N)[0])
    assert step.extrapolation_scale == 1.0
    step.policy = lambda X: np.tile(0.3 * np.eye(N)[1], (len(X), 1))
    np.testing.assert_allclose(step(q)[0], 0.3 * np.eye(N)[1])


def test_guard_scale_is_continuous_and_linear_across_the_band():
    step = _guarded_step(_outward(0.3), acc=ACC)
    b = step.guard.band(1.0 / SPACING, VMAX, ACC)
    ds = np.linspace(2.0, 3.0 + b + 1.0, 2001)
    scales = []
    for d in ds:
        q = np.zeros(N)
        q[0] = d * SPACING
        step(q)
        scales.append(step.extrapolation_scale)
    scales = np.array(scales)
    np.testing.assert_allclose(scales, np.clip(1.0 - (ds - 3.0) / b, 0.0, 1.0), atol=1e-12)
    assert np.abs(np.diff(scales)).max() <= (ds[1] - ds[0]) / b + 1e-12


def test_guard_band_is_at_least_the_stopping_distance_at_max_velocity():
    guard = ExtrapolationGuard(_PointSupport(np.zeros(N)), 3.0)
    vmax = np.full(N, 0.5)
    # |grad d| = 10 spacings per rad; full speed on all joints (2-norm 1.22 rad/s) braked
    # at 2 rad/s^2 per joint stops within 0.25 s and 1.22 * 0.5 / 4 = 0.153 rad.
    stop = 10.0 * np.linalg.norm(vmax) * 0.5 / (2 * 2.0)
    assert guard.band(10.0, vmax, 2.0) == pytest.approx(stop)
    assert stop > 1.0
    assert guard.band(0.1, vmax, 2.0) == 1.0  # never below min_band
    # One joint, one spacing per rad: v^2 / (2 a) exactly.
    assert ExtrapolationGuard(lambda q: (0.0, None), 1.0, min_band=0.01).band(
        1.0, np.array([0.5]), 2.0) == pytest.approx(0.5**2 / (2 * 2.0))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 3))
def test_guard_scaling_keeps_a_qdot_zero(seed, k):
    rng = np.random.default_rng(seed)
    rows = rng.normal(size=(k, N))
    pi = rng.normal(size=N)
    step = _guarded_step(lambda X: np.tile(pi, (len(X), 1)),
                         constraints=[_Row(r) for r in rows])
    q = rng.normal(size=N)
    q *= SPACING * rng.uniform(3.0, 4.0) / np.linalg.norm(q)  # inside the band
    qdot, _, cause = step(q)
    assert cause is None
    np.testing.assert_allclose(rows @ qdot, 0.0, atol=1e-10)
    unguarded = ControlStep(-10 * np.ones(N), 10 * np.ones(N), VMAX, DT,
                            constraints=[_Row(r) for r in rows], policy=step.policy)(q)[0]
    if step.extrapolation_scale < 1.0:
        assert float(q @ unguarded) > 0.0  # only motion leading further out is scaled
    np.testing.assert_allclose(qdot, step.extrapolation_scale * unguarded, atol=1e-12)


def test_guard_acts_before_the_ramp_and_stops_within_the_band():
    step = _guarded_step(_outward(5.0), acc=ACC)  # pushes out at full speed (0.5 rad/s)
    band = step.guard.band(1.0 / SPACING, VMAX, ACC)
    run = _Run(step, np.zeros(N))
    run.state()
    assert run.arm() == (True, None)
    scales = []
    for _ in range(300):
        out = run.tick()
        assert out.command is not None and out.zero_cause is None
        scales.append(out.extrapolation_scale)
        assert run.q[0] / SPACING <= 3.0 + band + 1e-9  # never beyond the band
    max_delta = ACC * DT_NS / 1e9
    _assert_ramped(run.sent, max_delta, start=np.zeros(N))  # ramp after the guard
    assert np.max(np.abs(run.sent)) == pytest.approx(0.5)  # full speed inside
    assert scales[0] == 1.0 and scales[-1] < 0.01
    assert np.abs(run.sent[-1]).max() < 0.01  # nearly stopped, still armed
    assert run.control.armed and run.control.extrapolation_scale == scales[-1]
    # Motion back in is allowed at once (and ramped).
    step.policy = _outward(-5.0)
    for _ in range(10):
        assert run.tick().extrapolation_scale == 1.0
    assert run.sent[-1][0] < -0.1


def test_guard_distance_failure_gives_zero_with_a_reason():
    guard = ExtrapolationGuard(lambda q: (float("nan"), None), 3.0)
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_outward(0.3), guard=guard)
    qdot, reason, cause = step(np.zeros(N))
    assert not np.any(qdot) and cause == ZeroCause.EXTRAPOLATION_GUARD and reason
    with pytest.raises(ValueError, match="max_extrapolation"):
        ExtrapolationGuard(guard.distance, 0.0)
    with pytest.raises(ValueError, match="max_extrapolation"):
        guard.max_extrapolation = float("inf")


def test_support_distance_of_a_joint_model_in_controller_order():
    from policy_align_ros.learning import PolicyAlign

    rng = np.random.default_rng(4)
    s = np.linspace(0.0, 1.0, 40)[:, None]
    trajs = [x0 * np.exp(-2.0 * s) for x0 in rng.normal(size=(5, 3))]
    model = PolicyAlign(random_state=0).fit(trajs, joint_names=["a", "b", "c"])
    perm = model_permutation(["a", "b", "c"], ["c", "a", "b"])  # controller order c, a, b
    dist = SupportDistance(model, perm)
    q = np.array([0.7, -0.4, 1.5])  # c, a, b
    d, grad = dist(q)
    d_model, _ = model.support_query(q[perm][None])
    assert d == pytest.approx(d_model[0]) and d > 1.0
    eps = 1e-6
    numeric = [(dist(q + eps * e)[0] - dist(q - eps * e)[0]) / (2 * eps) for e in np.eye(3)]
    np.testing.assert_allclose(grad, numeric, rtol=1e-5)
    assert np.linalg.norm(grad) == pytest.approx(1.0 / model.support_spacing_)
    on_support = np.empty(3)
    on_support[perm] = model.support_states_[7]
    assert dist(on_support) == (0.0, None)


def test_default_max_extrapolation_leaves_runs_from_the_start_distribution_unscaled():
    # The demonstrations' own start distribution on the executor's 18 Talos joints:
    # quadratic potential about the neutral posture, starts ~ N(q_0, 0.1 I). The model's
    # support is built by the same functions PolicyAlign.fit uses (fitting 18-D models
    # takes too long for a unit test).
    from scipy.spatial import cKDTree

    from policy_align_ros.learning.support import support_spacing, support_states
    from policy_align_ros.sim.demonstrations import (
        generate_demonstrations,
        no_constraint,
        sample_start_states,
    )
    from policy_align_ros.sim.experts import QuadraticPotential

    joints = TALOS_JOINTS + ["head_1_joint", "head_2_joint"]
    robot = Robot.load("talos", joints)
    q0 = robot.neutral()
    potential = QuadraticPotential(q0, 0.05)
    worst = []
    for seed, k in ((0, 3), (1, 10), (2, 40)):
        rng = np.random.default_rng(seed)
        starts = sample_start_states(rng, q0, k, 0.1, robot.lower, robot.upper)
        free = lambda i, r: no_constraint(robot.nq)  # noqa: E731
        demos = generate_demonstrations(potential, starts, free, 100, 1.0, rng)
        S, groups = support_states([d.trajectory.positions for d in demos])
        spacing = support_spacing(S, groups)
        tree = cKDTree(S)
        new = sample_start_states(rng, q0, 100, 0.1, robot.lower, robot.upper)
        runs = generate_demonstrations(potential, new, free, 100, 1.0, rng)
        worst += [tree.query(r.trajectory.positions)[0].max() / spacing for r in runs]
    assert max(worst) < DEFAULT_MAX_EXTRAPOLATION
    assert max(worst) > 0.5 * DEFAULT_MAX_EXTRAPOLATION  # the default is not arbitrary


class _Support:
    """The support part of a model (``support_query``), built as PolicyAlign.fit does."""

    def __init__(self, trajectories):
        from scipy.spatial import cKDTree

        from policy_align_ros.learning.support import support_spacing, support_states

        self.support_states_, groups = support_states(trajectories)
        self.support_spacing_ = support_spacing(self.support_states_, groups)
        self.n_features_in_ = self.support_states_.shape[1]
        self._tree = cKDTree(self.support_states_)

    def support_query(self, X):
        from policy_align_ros.learning.support import query_support

        return query_support(self._tree, self.support_states_, self.support_spacing_, X)


def _quadratic_demonstrations(robot, rng, k, n_samples=100):
    from policy_align_ros.sim.demonstrations import (
        generate_demonstrations,
        no_constraint,
        sample_start_states,
    )
    from policy_align_ros.sim.experts import QuadraticPotential

    q0 = robot.neutral()
    starts = sample_start_states(rng, q0, k, 0.1, robot.lower, robot.upper)
    free = lambda i, r: no_constraint(robot.nq)  # noqa: E731
    return generate_demonstrations(QuadraticPotential(q0, 0.05), starts, free, n_samples,
                                   1.0, rng)


def test_default_rad_cap_leaves_runs_from_the_start_distribution_unscaled():
    # Runs from new starts begin up to 1.8 rad from the data (beyond the 0.5 rad cap) but
    # only approach it: the guard, with the executor's limits, never scales them.
    robot = Robot.load("talos", TALOS_JOINTS + ["head_1_joint", "head_2_joint"])
    vmax = np.full(robot.nq, 0.5)
    farthest = 0.0
    for seed, k in ((0, 3), (1, 10), (2, 40)):
        rng = np.random.default_rng(seed)
        demos = _quadratic_demonstrations(robot, rng, k)
        support = _Support([d.trajectory.positions for d in demos])
        guard = ExtrapolationGuard(SupportDistance(support))
        assert guard.max_extrapolation_rad == 0.5
        for run in _quadratic_demonstrations(robot, rng, 100):
            for q, qdot in zip(run.trajectory.positions, run.trajectory.velocities,
                               strict=True):
                g, d = guard.scale(q, qdot, vmax, ACC)
                assert g == 1.0
                farthest = max(farthest, d * support.support_spacing_)
    assert farthest > 1.0  # runs that do start far beyond the cap


def test_a_model_pushing_away_from_the_data_stops_within_half_a_radian_of_it():
    from scipy.spatial import cKDTree

    from policy_align_ros.learning import PolicyAlign

    joints = TALOS_JOINTS + ["head_1_joint", "head_2_joint"]
    robot = Robot.load("talos", joints)
    rng = np.random.default_rng(0)
    demos = [d.trajectory.positions for d in _quadratic_demonstrations(robot, rng, 3)]
    model = PolicyAlign(random_state=0).fit(demos, joint_names=joints)
    samples = cKDTree(np.vstack(demos))
    away = rng.normal(size=robot.nq)

    def wrong(X):
        """Straight away from the nearest support state, at 5 rad/s."""
        _, nearest = model.support_query(X)
        diff = X[0] - nearest[0]
        size = float(np.linalg.norm(diff))
        u = diff / size if size > 1e-9 else away / np.linalg.norm(away)
        return 5.0 * u[None]

    def run_from(q0, **guard_options):
        guard = ExtrapolationGuard(SupportDistance(model), **guard_options)
        step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 0.5), DT,
                           policy=wrong, guard=guard, max_acceleration=ACC,
                           joint_limit_margin=0.05)
        run = _Run(step, q0)
        run.state()
        assert run.arm() == (True, None)
        beyond = []
        for _ in range(500):
            run.tick()
            beyond.append(float(samples.query(run.q)[0]))
        return run, np.array(beyond)

    q0 = demos[0][50]
    run, beyond = run_from(q0)
    assert beyond.max() <= 0.5 + 1e-3
    assert beyond.max() > 0.3  # it did leave the data, up to the edge
    assert np.abs(run.sent[-1]).max() < 0.01 and run.control.armed
    _assert_ramped(run.sent, ACC * DT, start=np.zeros(robot.nq))
    # Measured in spacings alone (the cap off), the same model goes much further.
    _, uncapped = run_from(q0, max_extrapolation_rad=None)
    assert uncapped.max() > 1.5


def test_guard_without_a_finite_stopping_distance_gives_zero_with_a_reason():
    guard = ExtrapolationGuard(_PointSupport(np.zeros(N)), 3.0)
    step = ControlStep(-10 * np.ones(N), 10 * np.ones(N), np.full(N, np.inf), DT,
                       policy=_outward(0.3), guard=guard, max_acceleration=ACC)
    q = np.zeros(N)
    assert step(q)[2] is None  # inside: nothing to scale, no band needed
    q[0] = 0.35  # 3.5 spacings, leading out
    qdot, reason, cause = step(q)
    assert not np.any(qdot) and cause == ZeroCause.EXTRAPOLATION_GUARD
    assert "max_velocity" in reason  # the setting that has no stopping distance
