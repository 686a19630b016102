"""Tests of policy_align_ros.control.armed (arming, stamps, ramps).

Arming, ramps and staleness run on an injected clock (tick counts), never on wall time.
"""

import re

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
    _Constant,
    _lift_that_a_lock_turns_towards_a_floor,
    _Linear,
    _Row,
    _Run,
    _talos_hold_and_plane,
)

from policy_align_ros.control import (
    IMPLAUSIBLE_POSITION,
    ArmedController,
    ControlStep,
    ZeroCause,
)
from policy_align_ros.kinematics import Robot, constraint_from_spec


def _raises(X):
    raise np.linalg.LinAlgError("SVD did not converge")


def test_an_armed_run_never_lowers_the_hand_onto_a_barrier_it_was_meant_to_leave():
    robot = Robot.load("talos", TALOS_JOINTS)
    q = robot.neutral()
    barrier, lock, pi, _ = _lift_that_a_lock_turns_towards_a_floor(robot, q)
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 0.5), DT,
                       constraints=[lock, barrier], policy=_Constant(pi),
                       min_singular_value=0.0)
    controller = ArmedController(step, 2.0, 0.1)
    floor = robot.frame_position(q, "arm_left_7_link")[2] - 0.02
    t = 1_000_000_000
    controller.joint_state(q, t, t)
    assert controller.arm(t)[0]
    lowest = np.inf
    for _ in range(300):
        t += 10_000_000
        controller.joint_state(q, t, t)
        out = controller.tick(t)
        if out.command is not None:
            q = np.clip(q + DT * out.command, robot.lower, robot.upper)
        lowest = min(lowest, robot.frame_position(q, "arm_left_7_link")[2] - floor)
    assert lowest > 0.0199


def test_every_step_of_a_talos_run_respects_max_acceleration_and_the_constraint():
    joints = [f"arm_left_{i}_joint" for i in range(1, 8)]
    robot = Robot.load("talos", joints)
    plane = constraint_from_spec({"type": "plane", "frame": "arm_left_7_link",
                                  "normal": [0.3, -0.2, 1.0]}, robot)
    center = robot.neutral()
    step = ControlStep(robot.lower, robot.upper, np.full(7, 0.5), DT_NS / 1e9,
                       constraints=[plane], policy=lambda X: -5.0 * (X - center))
    run = _Run(step, center + np.array([-0.3, 0.3, 0.3, -0.3, 0.3, 0.3, 0.3]))
    run.state()
    assert run.arm() == (True, None)
    assert [level for level, _ in run.events] == ["info"]  # the arming is logged
    for _ in range(150):
        out = run.tick()
        assert out.command is not None and out.zero_cause is None
        A = step.constraint_matrix(run.q - out.command * DT_NS / 1e9)
        np.testing.assert_allclose(A @ out.command, 0.0, atol=1e-9)
    max_delta = ACC * DT_NS / 1e9
    # The first command after enable starts from zero, and so does the check.
    _assert_ramped(run.sent, max_delta, start=np.zeros(7))
    assert np.max(np.abs(run.sent[0])) == pytest.approx(max_delta)
    assert np.max(np.abs(run.sent)) == pytest.approx(0.5)  # reached full speed
    assert not [e for e in run.events if e[0] == "warning"]  # no forced change reported
    # Disable: ramp down at the same rate, publishing until exactly zero, then silence.
    out = run.keep(run.control.disarm("disabled by ~/enable"))
    assert [level for level, _ in out.events] == ["info"]  # the disarm is logged
    assert out.zero_cause == ZeroCause.DISABLED and not run.control.faulted
    n_before = len(run.sent)
    for _ in range(60):
        run.tick()
    down = run.sent[n_before - 1:]
    _assert_ramped(down, max_delta)
    assert not np.any(down[-1]) and np.all(np.any(np.array(down[:-1]), axis=1))
    # As fast as allowed: no more steps than the largest joint speed needs.
    assert len(down) - 1 <= np.ceil(np.max(np.abs(down[0])) / max_delta) + 1
    assert run.tick().command is None and not run.control.armed
    assert not [e for e in run.events if e[0] == "warning"]


def test_ticks_faster_than_the_period_still_respect_max_acceleration():
    # One step per joint state of a 1 kHz driver on a 100 Hz controller: ten ticks per
    # period must not ramp ten times as fast.
    step = ControlStep(LOWER * 10, UPPER * 10, VMAX, DT, policy=_Linear(np.zeros(N)))
    run = _Run(step, np.full(N, 0.5))
    run.state()
    run.arm()
    times, sent = [], []
    for k in range(200):
        now = run.now + k * DT_NS // 10
        run.control.joint_state(run.q.copy(), now, now)
        out = run.control.tick(now)
        if out.command is not None:
            times.append(now / 1e9)
            sent.append(out.command)
    rate = np.abs(np.diff(sent, axis=0)).max(axis=1) / np.diff(times)
    assert np.abs(sent[-1]).max() > 0.1  # it did speed up
    assert rate.max() <= ACC * (1 + 1e-9)


def test_a_constraint_added_while_moving_is_blended_in_at_max_acceleration():
    policy = _Linear(np.full(N, 0.9))  # heads towards the upper limits: all joints move
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=policy)
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(40):
        run.tick()
    speed = run.sent[-1][0]
    assert speed > 0.3
    step.constraints = [_Row([1.0, 0, 0, 0, 0, 0])]  # lock joint 0
    for _ in range(100):
        run.tick()
    # Every step within the acceleration bound, the blend included; no warning.
    _assert_ramped(run.sent[-101:], ACC * DT)
    blend = int(np.ceil(speed / (ACC * DT)))
    after = np.array(run.sent[-100:])
    assert after[blend - 2, 0] > 0.0  # the constraint needs the blend ...
    np.testing.assert_allclose(after[blend:, 0], 0.0, atol=1e-12)  # ... and then holds
    assert not [e for e in run.events if e[0] == "warning"]


def test_arming_is_refused_without_a_model_or_fresh_joint_states():
    step = ControlStep(LOWER, UPPER, VMAX, DT)
    run = _Run(step, np.zeros(N), timeout_s=0.05)
    assert run.arm() == (False, ZeroCause.NO_MODEL)
    step.policy = _Linear(np.full(N, 0.5))
    assert run.arm() == (False, ZeroCause.NO_STATE)
    run.state()
    run.k += 6  # 60 ms later: stale by arrival
    assert run.arm() == (False, ZeroCause.STALE_STATE)
    assert not run.control.armed and run.control.zero_cause == ZeroCause.NOT_ENABLED
    assert run.tick(states=False).command is None  # disarmed and silent: nothing sent
    run.state()
    assert run.arm() == (True, None)
    assert run.tick().command is not None


def test_stale_joint_states_stop_at_once_and_the_controller_stays_disarmed():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N), timeout_s=0.05)
    run.state()
    run.arm()
    for _ in range(30):
        run.tick()
    assert np.any(run.sent[-1])
    outs = [run.tick(states=False) for _ in range(6)]
    assert [o.command is None for o in outs[:5]] == [False] * 5
    assert not np.any(outs[5].command) and outs[5].zero_cause == ZeroCause.STALE_STATE
    assert not run.control.armed and run.control.faulted
    for _ in range(20):  # fresh states again: no motion without a new arm
        assert run.tick().command is None
    assert run.arm() == (True, None)
    _assert_ramped([o for o in run.sent[-1:]] + [run.tick().command], ACC * DT)


@pytest.mark.parametrize("stamp, key", [
    (0, "zero_stamp"),
    # Relative to now: 10 s old, and before the last stamp: a restarted clock (a simulator
    # reset), told as such rather than as a late message.
    (-10_000_000_000, "stamp_backwards"),
    (+200_000_000, "stamp_in_future"),   # 0.2 s ahead, skew allowed 0.05 s
    ("back", "stamp_backwards"),
])
def test_untrustworthy_stamps_stop_at_once_and_disarm(stamp, key):
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N), timeout_s=0.05, skew_s=0.05)
    run.state()
    run.arm()
    for _ in range(20):
        run.tick()
    assert np.any(run.sent[-1])
    if stamp == "back":
        stamp_ns = run.now - 3 * DT_NS  # still fresh by age, but before the last stamp
    else:
        stamp_ns = stamp if stamp == 0 else run.now + stamp
    out = run.state(stamp_ns)
    assert out.rejected == key and out.zero_cause == ZeroCause(key)
    assert out.command is not None and not np.any(out.command)
    assert not run.control.armed and run.control.faulted
    assert [level for level, _ in out.events] == ["warning"]
    assert run.tick().command is None  # later good states do not re-arm it


def test_a_first_stamp_older_than_the_timeout_is_too_old_and_arms_nothing():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N), timeout_s=0.05, skew_s=0.05)
    run.k *= 1000  # a clock past 10 s
    out = run.state(run.now - 10_000_000_000)
    assert out.rejected == "stamp_too_old"
    assert run.arm()[0] is False and run.tick().command is None


def test_a_repeated_stamp_is_no_news_and_goes_stale():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N), timeout_s=0.05)
    run.state()
    stamp = run.now
    run.arm()
    outs = []
    for _ in range(8):
        out = run.state(stamp)
        assert out.rejected == "" and out.command is None
        outs.append(run.tick(states=False))
    assert np.any(outs[3].command)
    # Stale although messages kept coming: their stamp did not advance.
    assert not np.any(outs[-1].command) and outs[-1].zero_cause == ZeroCause.FROZEN_STAMP


def test_a_backwards_clock_jump_disarms_and_needs_fresh_states():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(10):
        run.tick()
    run.k -= 500  # the simulation restarted: /clock 5 s back
    out = run.control.tick(run.now)
    assert not np.any(out.command) and out.zero_cause == ZeroCause.CLOCK_JUMPED_BACK
    assert run.control.clock_jump_s == pytest.approx(4.99)  # 500 periods back, 1 on
    assert run.arm() == (False, ZeroCause.NO_STATE)
    run.state()  # the restarted sim's stamps are accepted again
    assert run.arm() == (True, None)


def test_broken_joint_states_stop_at_once():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(10):
        run.tick()
    out = run.control.reject_state("untrustworthy joint state: duplicate_joints",
                                   ZeroCause.DUPLICATE_JOINTS)
    assert not np.any(out.command) and not run.control.armed and run.control.faulted
    assert out.zero_cause == run.control.zero_cause == ZeroCause.DUPLICATE_JOINTS
    # Already at zero and silent: a second broken message publishes nothing more.
    assert run.control.reject_state("untrustworthy joint state: non_finite",
                                    ZeroCause.NON_FINITE_STATE).command is None
    # Arming is refused for the rejected state until a valid one arrives.
    assert run.arm() == (False, ZeroCause.NON_FINITE_STATE)


def test_after_a_rejected_state_the_state_check_says_it_was_rejected_and_why():
    # Valid states keep arriving at 100 Hz around one broken message: what is reported
    # until the next one is that message's rejection, not that none was ever received.
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N))
    never_cause, never = run.control.state_check(run.now)
    run.state()
    run.arm()
    run.tick()
    why = "untrustworthy joint state: non_finite: joint 3 position nan"
    run.control.reject_state(why, ZeroCause.NON_FINITE_STATE)
    cause, reason = run.control.state_check(run.now)
    assert never_cause == ZeroCause.NO_STATE and cause == ZeroCause.NON_FINITE_STATE
    assert why in reason and "/joint_states" in reason and reason != never
    assert run.control.arm_check(run.now) == (cause, reason)
    run.state()  # the next valid one: fresh again
    assert run.control.state_check(run.now) == (None, "")


def test_messages_lacking_a_controlled_joint_are_named_by_the_refusal_and_the_disarm():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N), timeout_s=0.05)
    lacking = "missing 'joint 5' (the message names 'joint 0'-'joint 4')"
    run.control.unusable_state(lacking)  # the executor words it (test_joint_order.py)
    assert run.arm() == (False, ZeroCause.NO_STATE)
    cause, reason = run.control.arm_check(run.now)
    assert lacking in reason and run.control.state_topic in reason
    assert run.control.state_problem(run.now) == reason  # /diagnostics' joint_states
    # A valid state takes over; while armed such messages stop nothing (other publishers
    # on a shared topic), until the valid ones stop coming.
    run.state()
    assert run.arm() == (True, None)
    for _ in range(10):
        run.tick()
        run.control.unusable_state(lacking)
    assert run.control.armed
    outs = [run.tick(states=False) for _ in range(6)]
    assert outs[-1].zero_cause == ZeroCause.STALE_STATE and not run.control.armed
    assert lacking in run.control.zero_reason and lacking in outs[-1].zero_reason
    assert "state_timeout_s" in run.control.zero_reason
    assert run.control.state_topic in run.control.zero_reason
    # A valid state clears it: a later staleness is only staleness.
    run.state()
    run.k += 6
    assert lacking not in run.control.state_problem(run.now)
    assert "state_timeout_s" in run.control.state_problem(run.now)


def test_model_swap_ramps_down_and_stays_disarmed():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(40):
        run.tick()
    n_before = len(run.sent)
    run.keep(run.control.set_policy(_Linear(np.full(N, -0.9)), reason="model swap to b"))
    assert not run.control.armed and run.control.zero_cause == ZeroCause.MODEL_SWAP
    for _ in range(60):
        run.tick()
    down = run.sent[n_before - 1:]
    _assert_ramped(down, ACC * DT)
    assert not np.any(down[-1]) and len(down) > 20
    # The new model never moved the robot: every command kept the old direction.
    assert np.all(np.array(down) >= 0.0)
    assert run.tick().command is None and not run.control.faulted


@pytest.mark.parametrize(("bad_policy", "cause"), [
    (lambda X: np.full_like(X, np.nan), ZeroCause.POLICY_NOT_FINITE),
    # Any exception of the policy is "no safe command" too: it must not leave the control
    # step with the controller armed and holding its last command.
    (_raises, ZeroCause.POLICY_FAILED),
])
def test_a_policy_fault_ramps_down(bad_policy, cause):
    policy = _Linear(np.full(N, 0.9))
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=policy)
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(40):
        run.tick()
    step.policy = bad_policy
    for _ in range(60):
        run.tick()
    _assert_ramped(run.sent, ACC * DT, start=np.zeros(N))
    assert not np.any(run.sent[-1]) and not run.control.armed and run.control.faulted
    assert run.control.zero_cause == cause
    if cause == ZeroCause.POLICY_FAILED:  # the exception is named
        assert "LinAlgError" in run.control.zero_reason


def test_a_speed_limit_lowered_while_armed_is_reached_by_the_ramp():
    # An operator lowers max_velocity from 0.5 to 0.01 rad/s while the robot cruises at
    # 0.5: the command slows at max_acceleration (before: 0.5 -> 0.01 in one period, 49
    # rad/s^2 against 2) and then stays within the new limit.
    step = ControlStep(-10 * np.ones(N), 10 * np.ones(N), VMAX, DT,
                       policy=lambda X: np.full_like(X, 0.9))
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(50):
        run.tick()
    cruising = run.sent[-1].copy()
    np.testing.assert_allclose(cruising, 0.5)
    step.max_velocity = np.full(N, 0.01)
    for _ in range(40):
        run.tick()
    after = run.sent[50:]
    _assert_ramped(after, ACC * DT, start=cruising)
    np.testing.assert_allclose(after[-1], 0.01)
    assert not [e for e in run.events if e[0] == "warning"]  # no forced change reported


def test_constraints_that_cannot_be_enforced_refuse_the_enable():
    # A plane on a frame that none of the controlled joints moves has a zero row: refused
    # at enable rather than disarmed by the first step.
    robot = Robot.load("talos", [f"arm_left_{i}_joint" for i in range(1, 8)])
    plane = constraint_from_spec({"type": "plane", "frame": "arm_right_7_link",
                                  "normal": [0.0, 0.0, 1.0]}, robot)
    q0 = robot.neutral() + 0.2
    step = ControlStep(robot.lower, robot.upper, np.full(7, 0.5), DT, constraints=[plane],
                       policy=lambda X: -(X - q0))
    run = _Run(step, q0)
    run.state()
    assert run.arm() == (False, ZeroCause.CONSTRAINTS_NEAR_SINGULAR)
    step.constraints = []
    assert run.arm() == (True, None)


def test_joints_brake_before_their_limits_within_the_ramp():
    # Joint 0 runs into its upper limit at full speed: the braking cap slows it in time,
    # so no step needs more than the ramp allows and the limit is never crossed.
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.array([5.0, 0, 0, 0, 0, 0])))
    run = _Run(step, np.array([0.5, 0, 0, 0, 0, 0]))
    run.state()
    run.arm()
    for _ in range(300):
        run.tick()
        assert run.q[0] <= UPPER[0] + 1e-12
    _assert_ramped(run.sent, ACC * DT, start=np.zeros(N))
    assert run.q[0] > 0.99 and not [e for e in run.events if e[0] == "warning"]


def test_bad_armed_controller_settings():
    step = ControlStep(LOWER, UPPER, VMAX, DT)
    with pytest.raises(ValueError, match="max_acceleration"):
        ArmedController(step, 0.0, 0.1)
    with pytest.raises(ValueError, match="state_timeout_s"):
        ArmedController(step, 1.0, float("nan"))
    with pytest.raises(ValueError, match="max_clock_skew_s"):
        ArmedController(step, 1.0, 0.1, -1.0)
    with pytest.raises(ValueError, match="state_limit_margin"):
        ArmedController(step, 1.0, 0.1, state_limit_margin=-0.1)
    with pytest.raises(ValueError, match="state_limit_margin"):
        ArmedController(step, 1.0, 0.1, state_limit_margin=float("inf"))


def test_held_frames_latch_at_enable_and_when_the_constraints_change():
    robot, hold, plane = _talos_hold_and_plane()
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 0.5), DT_NS / 1e9,
                       constraints=[hold + plane], policy=lambda X: np.zeros_like(X))
    assert step.holding
    q1 = robot.neutral()
    run = _Run(step, q1 + 0.05)
    step.latch(q1)  # a stale reference from some earlier run ...
    assert np.linalg.norm(step.hold_errors(run.q)) > 1e-3
    run.state()
    run.arm()  # ... is replaced at enable: the frame is held where it is now
    np.testing.assert_allclose(step.hold_errors(run.q), 0.0)
    assert not np.any(run.tick().command)  # nothing to correct, the policy is still
    step.constraints = [hold]  # new constraints: latched at their first step
    run.q += 0.01
    run.tick()
    np.testing.assert_allclose(step.hold_errors(run.q - run.sent[-1] * DT_NS / 1e9), 0.0,
                               atol=1e-12)


@pytest.mark.parametrize("setting", [("drift_gain", 5.0), ("drift_clamp_m", 0.05)])
def test_new_drift_settings_on_a_drifted_frame_do_not_step_the_command(setting):
    # The correction bypasses the ramp, so a new gain (or a larger clamp) on a frame that
    # drifted while the old one held would jump the command: the frame is re-latched.
    name, value = setting
    robot, hold, _ = _talos_hold_and_plane()
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 0.5), DT_NS / 1e9,
                       constraints=[hold], policy=lambda X: np.zeros_like(X),
                       drift_gain=0.0 if name == "drift_gain" else 5.0, drift_clamp_m=0.001)
    run = _Run(step, robot.neutral())
    run.state()
    run.arm()
    run.tick()
    run.q[TALOS_JOINTS.index("arm_left_4_joint")] += 0.1  # pushed: about 26 mm
    assert np.linalg.norm(step.hold_errors(run.q)) > 0.02
    before = run.tick().command.copy()
    setattr(step, name, value)
    after = run.tick().command
    assert np.abs(after - before).max() <= run.control.max_delta + 1e-12
    np.testing.assert_allclose(step.hold_errors(run.q), 0.0, atol=1e-12)


def test_a_near_singular_constraint_matrix_ramps_down_and_says_why():
    first = _Row([1.0, 0, 0, 0, 0, 0])
    second = _Row([0.0, 1.0, 0, 0, 0, 0])
    step = ControlStep(LOWER, UPPER, VMAX, DT_NS / 1e9, constraints=[first, second],
                       policy=_Linear(np.full(N, 0.9)), min_singular_value=0.01)
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(40):
        assert run.tick().zero_cause is None
    assert np.abs(run.sent[-1]).max() > 0.3
    second.row = np.array([[1.0, 0.005, 0, 0, 0, 0]])  # nearly the first row again
    smallest = np.linalg.svd(step.constraint_matrix(run.q), compute_uv=False)[-1]
    assert 0.0 < smallest < step.min_singular_value  # rank 2 still, but nearly 1
    out = run.tick()
    assert out.zero_cause == ZeroCause.CONSTRAINTS_NEAR_SINGULAR
    assert any(out.zero_reason in text for _, text in out.events), out.events  # logged
    n_before = len(run.sent)
    for _ in range(40):
        run.tick()
    _assert_ramped(run.sent[n_before - 1:], ACC * DT_NS / 1e9)
    assert not np.any(run.sent[-1]) and not run.control.armed and run.control.faulted
    # Rows more than joints can never be independent: the reason counts rows and joints
    # and names the parameter to remove a constraint from, not the threshold (no
    # min_singular_value would help).
    step.constraints = [_Row(r) for r in np.eye(N + 2, N)]
    _, reason, cause = step(np.zeros(N))
    assert cause == ZeroCause.CONSTRAINTS_NEAR_SINGULAR
    assert re.search(rf"\b{N + 2}\b.*\b{N} joints\b", reason), reason
    assert "constraints" in reason and "min_singular_value" not in reason


@pytest.mark.parametrize("joint, value", [
    (0, 1e6),
    (3, 3.0),    # the limit is 1.57
    (5, -1.8),
])
def test_implausible_positions_are_refused_and_disarm_naming_joint_and_value(joint, value):
    lower, upper = np.full(N, -1.57), np.full(N, 1.57)
    step = ControlStep(lower, upper, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(20):
        run.tick()
    assert np.any(run.sent[-1])
    run.q[joint] = value
    out = run.state()
    assert out.rejected == IMPLAUSIBLE_POSITION
    assert out.command is not None and not np.any(out.command)  # zero at once
    assert not run.control.armed and run.control.faulted
    assert run.control.zero_cause == ZeroCause.POSITION_OUTSIDE_LIMITS
    name = run.control.joint_names[joint]
    assert name in run.control.zero_reason and f"{value:g}" in run.control.zero_reason
    # The refusal to arm again says why there is no state to arm on.
    assert run.arm() == (False, ZeroCause.POSITION_OUTSIDE_LIMITS)
    assert name in run.control.arm_check(run.now)[1]
    assert run.tick().command is None  # still implausible: nothing moves
    run.q[joint] = 0.0
    run.state()
    assert run.arm() == (True, None)


def test_positions_just_outside_the_limits_within_the_margin_are_accepted():
    lower, upper = np.full(N, -1.57), np.full(N, 1.57)
    step = ControlStep(lower, upper, VMAX, DT, policy=_Linear(np.zeros(N)))
    run = _Run(step, np.array([1.65, -1.65, 0.0, 0.0, 0.0, 0.0]))
    assert run.state().rejected == ""
    assert run.arm() == (True, None)
    for _ in range(20):
        run.tick()
    assert run.control.armed and np.any(run.sent[-1])
    # A wider margin set at run time accepts what the default refuses, and back.
    run.control.state_limit_margin = 0.5
    run.q[2] = 1.9
    assert run.state().rejected == "" and run.control.armed
    run.k += 1
    run.control.state_limit_margin = 0.1
    assert run.state().rejected == IMPLAUSIBLE_POSITION and not run.control.armed


def test_only_real_forced_changes_are_reported():
    # Full speed towards a limit, then max_acceleration cut to a rate that cannot brake in
    # the room left: the position limit wins and says so; blends and round-off do not.
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Constant(np.eye(N)[0]))
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    while run.q[0] < 0.7:
        run.tick()
    assert not [e for e in run.events if e[0] == "warning"]
    run.control.max_acceleration = 0.05
    for _ in range(100):
        run.tick()
    assert run.q[0] <= UPPER[0] + 1e-12 and run.control.armed  # no fault: a report only
    forced = [text for level, text in run.events if level == "warning"]
    assert len(forced) == 1 and run.control.joint_names[0] in forced[0]


def test_a_disarm_nobody_asked_for_is_logged_as_a_warning():
    step = ControlStep(-np.ones(2), np.ones(2), np.full(2, 0.5), DT_NS / 1e9,
                       policy=lambda X: -X)
    for cause, level in ((ZeroCause.DISABLED, "info"), (ZeroCause.MODEL_SWAP, "info"),
                         (ZeroCause.CONSTRAINTS_NEAR_SINGULAR, "warning")):
        run = _Run(step, np.array([0.3, -0.2]))
        run.state()
        assert run.arm() == (True, None)
        out = run.control.disarm("why", cause)
        assert [lv for lv, _ in out.events] == [level], cause
