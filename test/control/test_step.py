"""Tests of policy_align_ros.control.step (locks in the step, barriers, drift correction)."""

import numpy as np
import pytest
from control_rigs import (
    ACC,
    DT,
    DT_NS,
    EXECUTOR_JOINTS,
    LEFT_HAND,
    LOWER,
    TALOS_JOINTS,
    UPPER,
    VMAX,
    N,
    _assert_ramped,
    _Constant,
    _lift_that_a_lock_turns_towards_a_floor,
    _Linear,
    _Run,
    _talos_hold_and_plane,
)

from policy_align_ros.control import ControlStep, ZeroCause
from policy_align_ros.kinematics import Robot, constraint_from_spec


class _CountingLock:
    """A constraint that counts how often its rows are asked for."""

    def __init__(self, inner):
        self.inner, self.calls = inner, 0

    def matrix(self, q, qdot=None):
        self.calls += 1
        return self.inner.matrix(q, qdot)


def _held_hand_run(drift_gain, seconds=60.0):
    """Talos (18 joints), left hand held, quadratic potential, 100 Hz, ``seconds`` long.

    The plant integrates each command with explicit Euler (sim.integrate_clamped) after a
    per-joint velocity gain error of 5 % (seeded): the two drift sources of a real
    velocity-controlled robot. Returns the largest distance (m) of the hand from where it
    was at enable, the commands sent and the ArmedController.
    """
    from policy_align_ros.sim.demonstrations import sample_start_states
    from policy_align_ros.sim.experts import QuadraticPotential
    from policy_align_ros.sim.simulator import integrate_clamped

    robot = Robot.load("talos", EXECUTOR_JOINTS)
    rng = np.random.default_rng(0)
    q0 = robot.neutral()
    potential = QuadraticPotential(q0, 0.5)
    hold = constraint_from_spec({"type": "position", "frame": LEFT_HAND}, robot)
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 0.5), DT_NS / 1e9,
                       constraints=[hold], policy=potential.policy, drift_gain=drift_gain)
    run = _Run(step, sample_start_states(rng, q0, 1, 0.1, robot.lower, robot.upper)[0])
    tracking = 1.0 + 0.05 * rng.standard_normal(robot.nq)
    run.state()
    assert run.arm() == (True, None)
    p_ref = hold.hold_position(run.q)
    worst = 0.0
    for _ in range(round(seconds * 1e9 / DT_NS)):
        run.state()
        out = run.keep(run.control.tick(run.now))
        assert out.zero_cause is None
        if out.command is not None:
            run.q, _ = integrate_clamped(run.q, tracking * out.command, DT_NS / 1e9,
                                         robot.lower, robot.upper)
        run.k += 1
        worst = max(worst, float(np.linalg.norm(hold.hold_position(run.q) - p_ref)))
    return worst, run


def test_control_step_zero_commands_and_reasons():
    step = ControlStep(LOWER, UPPER, VMAX, DT)
    qdot, reason, cause = step(np.zeros(N))
    assert cause == ZeroCause.NO_MODEL and reason and not np.any(qdot)
    step.policy = _Linear(np.full(N, 0.1))
    qdot, reason, cause = step(np.full(N, np.nan))
    assert cause == ZeroCause.STATE_INVALID and reason and not np.any(qdot)
    qdot, _, cause = step(np.zeros(N + 1))
    assert cause == ZeroCause.STATE_INVALID and not np.any(qdot)
    step.policy = lambda X: np.full_like(X, np.inf)
    qdot, reason, cause = step(np.zeros(N))
    assert cause == ZeroCause.POLICY_NOT_FINITE and reason and not np.any(qdot)


def test_control_step_applies_the_permutation():
    center_model = np.arange(N) * 0.1  # model joint k has attractor 0.1 k
    perm = np.array([5, 4, 3, 2, 1, 0])  # model joint k is controller joint perm[k]
    step = ControlStep(LOWER, UPPER, np.full(N, 10.0), DT, policy=_Linear(center_model),
                       permutation=perm)
    qdot, _, cause = step(np.zeros(N))
    assert cause is None
    expected = np.empty(N)
    expected[perm] = center_model
    np.testing.assert_allclose(qdot, expected)


def test_talos_hands_on_planes_give_a_qdot_zero():
    robot = Robot.load("talos", TALOS_JOINTS)
    rng = np.random.default_rng(3)
    specs = [{"type": "plane", "frame": f, "normal": rng.normal(size=3).tolist()}
             for f in ("arm_left_7_link", "arm_right_7_link")]
    constraints = [constraint_from_spec(s, robot) for s in specs]
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 1.0), DT,
                       constraints=constraints, policy=_Linear(robot.neutral()))
    for _ in range(5):
        q = robot.random_configuration(rng, std=0.3)
        qdot, _, cause = step(q)
        assert cause is None and np.linalg.norm(qdot) > 1e-3
        A = step.constraint_matrix(q)
        assert A.shape == (2, robot.nq)
        np.testing.assert_allclose(A @ qdot, 0.0, atol=1e-9)


def test_a_barrier_blocks_the_command_when_the_other_constraints_turn_it_towards_it():
    # The policy lifts the hand, but a locked joint leaves only the part that lowers it:
    # the barrier must be judged by the command, not by the policy.
    robot = Robot.load("talos", TALOS_JOINTS)
    q = robot.neutral()
    barrier, lock, pi, jz = _lift_that_a_lock_turns_towards_a_floor(robot, q)
    assert jz @ pi > 0.0
    for constraints in ([lock], [lock, barrier]):
        step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 1.0), DT,
                           constraints=constraints, policy=_Constant(pi),
                           min_singular_value=0.0)
        qdot, _, cause = step(q)
        assert cause is None
        if len(constraints) == 1:
            assert jz @ qdot < -1e-3  # without the barrier the hand would go down
        else:
            assert jz @ qdot > -1e-12
            assert np.linalg.norm(qdot) > 1e-3  # the rest of the command still moves


def test_growing_the_active_set_asks_the_other_constraints_for_their_rows_once():
    robot = Robot.load("talos", TALOS_JOINTS)
    q = robot.neutral()
    barrier, lock, pi, jz = _lift_that_a_lock_turns_towards_a_floor(robot, q)
    counting = _CountingLock(lock)
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 1.0), DT,
                       constraints=[counting, barrier], policy=_Constant(pi),
                       min_singular_value=0.0)
    qdot, _, cause = step(q)
    assert cause is None and jz @ qdot > -1e-12  # the barrier joined in a second round
    assert counting.calls == 1


def test_bad_control_step_arguments():
    with pytest.raises(ValueError, match="max_velocity"):
        ControlStep(LOWER, UPPER, 0.0, DT)
    with pytest.raises(ValueError, match="dt"):
        ControlStep(LOWER, UPPER, VMAX, 0.0)


def test_held_frame_drifts_at_most_1_mm_over_60_s_and_more_without_correction():
    worst, run = _held_hand_run(drift_gain=5.0)
    assert worst <= 1e-3, worst
    moved = np.sum(np.abs(np.diff(np.array(run.sent), axis=0)) > 0, axis=0)
    assert np.count_nonzero(moved) >= 10  # a real motion of most joints, not a stand-still
    # The correction goes through the ramp: every step within max_acceleration * dt.
    _assert_ramped(run.sent, ACC * DT_NS / 1e9 + 1e-6, start=np.zeros(len(EXECUTOR_JOINTS)))
    assert not [e for e in run.events if e[0] == "warning"]  # no forced change reported
    uncorrected, _ = _held_hand_run(drift_gain=0.0)
    assert uncorrected > 1e-3, uncorrected  # the test can fail: drift is real


def test_correction_respects_the_other_constraints_the_gain_clamp_and_speed_limits():
    robot, hold, plane = _talos_hold_and_plane()
    still = lambda X: np.zeros_like(X)  # noqa: E731  (the command is the correction alone)
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 0.5), 0.01,
                       constraints=[plane, hold], policy=still, drift_gain=5.0,
                       drift_clamp_m=0.01)
    rng = np.random.default_rng(2)
    q_ref = robot.neutral()
    step.latch(q_ref)
    for size in (0.02, 0.1):  # rad of joint offset: a few mm, then beyond the clamp
        q = q_ref + size * rng.standard_normal(robot.nq)
        e = step.hold_errors(q)
        qdot, _, cause = step(q)
        assert cause is None
        np.testing.assert_allclose(plane.matrix(q) @ qdot, 0.0, atol=1e-10)
        task = hold.matrix(q) @ qdot
        clamped = e * min(1.0, 0.01 / np.linalg.norm(e))
        # -k clamp(e), up to the damping of the pseudo-inverse (l = 0.01 m/rad)
        np.testing.assert_allclose(task, -5.0 * clamped, rtol=0.05, atol=1e-4)
        assert np.all(np.abs(qdot) <= 0.5 + 1e-12)
    assert np.linalg.norm(e) > 0.01  # the second case was clamped


def test_a_joint_on_its_limit_stays_there_under_the_correction():
    robot, hold, _ = _talos_hold_and_plane()
    still = lambda X: np.zeros_like(X)  # noqa: E731
    q_ref = robot.neutral()
    j = EXECUTOR_JOINTS.index("arm_left_4_joint")
    wide = ControlStep(np.full(robot.nq, -10.0), np.full(robot.nq, 10.0),
                       np.full(robot.nq, 0.5), 0.01, constraints=[hold], policy=still)
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 0.5), 0.01,
                       constraints=[hold], policy=still)
    wide.latch(q_ref)
    step.latch(q_ref)
    rng = np.random.default_rng(3)
    # A state with the elbow on a limit that the unlimited correction pushes it out of.
    for _ in range(50):
        q = robot.clip(q_ref + 0.05 * rng.standard_normal(robot.nq))
        q[j] = robot.upper[j]
        if wide(q)[0][j] > 1e-3:
            break
        q[j] = robot.lower[j]
        if wide(q)[0][j] < -1e-3:
            break
    else:
        pytest.fail("no state found")
    qdot, _, cause = step(q)
    assert cause is None and qdot[j] == 0.0 and np.linalg.norm(qdot) > 1e-3
    # The other joints still correct: the held frame moves back towards its reference.
    e = step.hold_errors(q)
    assert float(e @ (hold.matrix(q) @ qdot)) < 0.0


def test_bad_drift_and_singularity_settings():
    for kwargs, match in (({"drift_gain": -1.0}, "drift_gain"),
                          ({"drift_clamp_m": 0.0}, "drift_clamp_m"),
                          ({"min_singular_value": float("nan")}, "min_singular_value")):
        with pytest.raises(ValueError, match=match):
            ControlStep(LOWER, UPPER, VMAX, DT, **kwargs)


def test_velocity_bounds_are_the_speed_limit_and_brake_before_the_control_limits():
    step = ControlStep(LOWER, UPPER, VMAX, DT, max_acceleration=2.0, joint_limit_margin=0.1)
    lo, hi = step.velocity_bounds(np.zeros(N))  # mid-range: the speed limit both ways
    np.testing.assert_allclose(hi, VMAX)
    np.testing.assert_allclose(lo, -VMAX)
    q = np.zeros(N)
    q[0] = step.control_upper[0] - 0.01  # 0.01 rad from where joint 0 must rest
    lo, hi = step.velocity_bounds(q)
    assert 0.0 <= hi[0] < 0.25 * VMAX[0] and lo[0] == pytest.approx(-VMAX[0])
    np.testing.assert_allclose(hi[1:], VMAX[1:])
