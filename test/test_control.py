"""Tests of policy_align_ros.kinematics.control (the executor's ROS-free control law).

Arming, ramps and staleness run on an injected clock (tick counts), never on wall time.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from policy_align_ros.kinematics import Robot, constraint_from_spec
from policy_align_ros.kinematics.control import (
    DEFAULT_MAX_EXTRAPOLATION,
    ArmedController,
    ControlStep,
    ExtrapolationGuard,
    SupportDistance,
    constrained_command,
    joint_velocity_bounds,
    limit_locks,
    model_permutation,
    ramp_toward,
    velocity_scale,
)

#: Talos arms and torso (ROS-free test: the nodes' default list is not imported).
TALOS_JOINTS = (
    ["torso_1_joint", "torso_2_joint"]
    + [f"arm_left_{i}_joint" for i in range(1, 8)]
    + [f"arm_right_{i}_joint" for i in range(1, 8)]
)
N = 6
LOWER = -np.ones(N)
UPPER = np.ones(N)
VMAX = np.full(N, 0.5)
DT = 0.01


def test_velocity_scale_respects_speed_and_position_limits():
    q = np.zeros(N)
    v = np.array([2.0, 0.1, 0, 0, 0, 0])
    assert velocity_scale(q, v, DT, LOWER, UPPER, VMAX) == pytest.approx(0.25)
    q_near = np.array([0.999, 0, 0, 0, 0, 0])
    s = velocity_scale(q_near, np.array([0.2, 0, 0, 0, 0, 0]), DT, LOWER, UPPER, VMAX)
    assert s == pytest.approx(0.5)  # 0.001 of room, 0.002 of travel in one period
    assert velocity_scale(q, np.zeros(N), DT, LOWER, UPPER, VMAX) == 1.0


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(0, 3))
def test_command_satisfies_constraints_speed_and_limits(seed, k):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1.0, 1.0, N)
    q[rng.random(N) < 0.3] = 1.0  # some joints sit on a limit
    pi = rng.normal(scale=2.0, size=N)
    A = rng.normal(size=(k, N))
    qdot = constrained_command(q, pi, A, LOWER, UPPER, VMAX, DT)
    np.testing.assert_allclose(A @ qdot, 0.0, atol=1e-10)
    assert np.all(np.abs(qdot) <= VMAX + 1e-12)
    q_next = q + DT * qdot
    assert np.all(q_next <= UPPER + 1e-12) and np.all(q_next >= LOWER - 1e-12)


def test_joint_on_a_limit_is_locked_but_the_others_keep_moving():
    q = np.array([1.0, 0, 0, 0, 0, 0])
    pi = np.array([0.3, 0.2, -0.1, 0, 0, 0])
    assert limit_locks(q, pi, LOWER, UPPER).tolist() == [True] + [False] * 5
    qdot = constrained_command(q, pi, np.zeros((0, N)), LOWER, UPPER, VMAX, DT)
    np.testing.assert_allclose(qdot, [0.0, 0.2, -0.1, 0, 0, 0])


def test_locked_joint_under_a_coupling_constraint_keeps_a_qdot_zero():
    # A couples joints 0 and 1; joint 0 is on its limit, so joint 1 must stop as well.
    q = np.array([1.0, 0, 0, 0, 0, 0])
    A = np.array([[1.0, -1.0, 0, 0, 0, 0]])
    pi = np.array([1.0, 1.0, 0.3, 0, 0, 0])
    qdot = constrained_command(q, pi, A, LOWER, UPPER, VMAX, DT)
    np.testing.assert_allclose(qdot, [0, 0, 0.3, 0, 0, 0], atol=1e-12)


def test_uniform_scaling_keeps_the_direction():
    pi = np.array([4.0, 1.0, 0, 0, 0, 0])
    qdot = constrained_command(np.zeros(N), pi, np.zeros((0, N)), LOWER, UPPER, VMAX, DT)
    np.testing.assert_allclose(qdot, pi / 8.0)


def test_model_permutation_maps_controller_order_to_model_order():
    perm = model_permutation(["b", "c", "a"], ["a", "b", "c"])
    q = np.array([1.0, 2.0, 3.0])  # a, b, c
    np.testing.assert_array_equal(q[perm], [2.0, 3.0, 1.0])
    np.testing.assert_array_equal(model_permutation(None, ["a", "b"]), [0, 1])
    with pytest.raises(ValueError, match=r"model needs \['d'\].*not in the model \['c'\]"):
        model_permutation(["a", "b", "d"], ["a", "b", "c"])


class _Linear:
    """pi(x) = -(x - c) in model order."""

    def __init__(self, center):
        self.center = np.asarray(center, dtype=float)

    def __call__(self, X):
        return -(X - self.center)


def test_control_step_zero_commands_and_reasons():
    step = ControlStep(LOWER, UPPER, VMAX, DT)
    qdot, reason = step(np.zeros(N))
    assert reason == "no model loaded" and not np.any(qdot)
    step.policy = _Linear(np.full(N, 0.1))
    qdot, reason = step(np.full(N, np.nan))
    assert "not finite" in reason and not np.any(qdot)
    step.policy = lambda X: np.full_like(X, np.inf)
    qdot, reason = step(np.zeros(N))
    assert reason == "policy output not finite" and not np.any(qdot)


def test_control_step_applies_the_permutation():
    center_model = np.arange(N) * 0.1  # model joint k has attractor 0.1 k
    perm = np.array([5, 4, 3, 2, 1, 0])  # model joint k is controller joint perm[k]
    step = ControlStep(LOWER, UPPER, np.full(N, 10.0), DT, policy=_Linear(center_model),
                       permutation=perm)
    qdot, reason = step(np.zeros(N))
    assert reason == ""
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
        qdot, reason = step(q)
        assert reason == "" and np.linalg.norm(qdot) > 1e-3
        A = step.constraint_matrix(q)
        assert A.shape == (2, robot.nq)
        np.testing.assert_allclose(A @ qdot, 0.0, atol=1e-9)


class _Constant:
    def __init__(self, v: np.ndarray):
        self.v = v

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return np.tile(self.v, (len(X), 1))


def _lift_that_a_lock_turns_towards_a_floor(robot: Robot, q: np.ndarray):
    """A floor 2 cm below the left hand, acting within 5 cm; a policy ``pi`` that lifts the
    hand; a lock on the joint that lifts it most, which leaves only the part that lowers
    it; and the hand's z Jacobian."""
    frame = "arm_left_7_link"
    p = robot.frame_position(q, frame)
    spec = {"type": "barrier", "frame": frame, "point": [p[0], p[1], p[2] - 0.02],
            "normal": [0.0, 0.0, 1.0], "distance": 0.05}
    jz = robot.frame_jacobian(q, frame)[2]
    up, down = int(np.argmax(jz)), int(np.argmin(jz))
    pi = np.zeros(robot.nq)
    pi[up], pi[down] = 0.3, 0.2
    lock = constraint_from_spec({"type": "joints", "joints": [TALOS_JOINTS[up]]}, robot)
    return constraint_from_spec(spec, robot), lock, pi, jz


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
        qdot, reason = step(q)
        assert reason == ""
        if len(constraints) == 1:
            assert jz @ qdot < -1e-3  # without the barrier the hand would go down
        else:
            assert jz @ qdot > -1e-12
            assert np.linalg.norm(qdot) > 1e-3  # the rest of the command still moves


class _CountingLock:
    """A constraint that counts how often its rows are asked for."""

    def __init__(self, inner):
        self.inner, self.calls = inner, 0

    def matrix(self, q, qdot=None):
        self.calls += 1
        return self.inner.matrix(q, qdot)


def test_growing_the_active_set_asks_the_other_constraints_for_their_rows_once():
    robot = Robot.load("talos", TALOS_JOINTS)
    q = robot.neutral()
    barrier, lock, pi, jz = _lift_that_a_lock_turns_towards_a_floor(robot, q)
    counting = _CountingLock(lock)
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 1.0), DT,
                       constraints=[counting, barrier], policy=_Constant(pi),
                       min_singular_value=0.0)
    qdot, reason = step(q)
    assert reason == "" and jz @ qdot > -1e-12  # the barrier joined in a second round
    assert counting.calls == 1


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


def test_bad_control_step_arguments():
    with pytest.raises(ValueError, match="max_velocity"):
        ControlStep(LOWER, UPPER, 0.0, DT)
    with pytest.raises(ValueError, match="dt"):
        ControlStep(LOWER, UPPER, VMAX, 0.0)


# -- ramps and arming (ArmedController), driven by an injected clock ---------------------
DT_NS = 10_000_000  # 10 ms period
ACC = 2.0  # rad/s^2
STEP_TOL = 1e-12


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(0, 3),
       max_delta=st.floats(1e-4, 1.0))
def test_ramp_toward_bounds_every_joint_and_keeps_the_constraints(seed, k, max_delta):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(k, N))
    P = constrained_projector(A)
    previous = P @ rng.normal(size=N)
    target = P @ rng.normal(scale=3.0, size=N)
    command, alpha, forced = ramp_toward(previous, target, P, max_delta)
    assert 0.0 <= alpha <= 1.0
    assert np.max(np.abs(command - previous)) <= max_delta + STEP_TOL
    np.testing.assert_allclose(A @ command, 0.0, atol=1e-10)
    np.testing.assert_allclose(forced, 0.0, atol=1e-12)
    if alpha == 1.0:
        np.testing.assert_array_equal(command, target)
    else:  # as far as allowed: some joint uses its whole budget
        assert np.max(np.abs(command - previous)) == pytest.approx(max_delta)


def test_ramp_toward_lets_a_new_constraint_force_its_change_but_no_more():
    previous = np.array([0.4, 0.4, 0.0, 0.1, 0.0, 0.0])
    A = np.array([[1.0, 0, 0, 0, 0, 0]])  # joint 0 newly locked
    P = constrained_projector(A)
    target = np.array([0.0, 0.5, 0.3, 0.1, 0.0, 0.0])
    command, alpha, forced = ramp_toward(previous, target, P, 0.02)
    np.testing.assert_allclose(forced, [-0.4, 0, 0, 0, 0, 0], atol=1e-15)
    assert command[0] == pytest.approx(0.0, abs=1e-15)  # the constraint wins at once
    change = np.abs(command - previous)
    assert np.all(change[1:] <= 0.02 + STEP_TOL) and 0.0 < alpha < 1.0


def constrained_projector(A):
    from policy_align_ros.kinematics import nullspace_projector

    return nullspace_projector(A, N)


class _Row:
    """A fixed constraint row, switchable on and off."""

    def __init__(self, row, active=True):
        self.row = np.asarray(row, dtype=float)[None, :]
        self.active = active

    def matrix(self, q, qdot=None):
        return self.row if self.active else np.zeros((0, self.row.shape[1]))


class _Run:
    """An ArmedController and a perfect velocity-controlled robot, on a counted clock."""

    def __init__(self, step, q0, max_acceleration=ACC, timeout_s=0.05, skew_s=0.0):
        self.control = ArmedController(step, max_acceleration, timeout_s, skew_s)
        self.q = np.asarray(q0, dtype=float).copy()
        self.k = 1000  # tick count; the clock is k * DT_NS
        self.sent: list[np.ndarray] = []
        self.events: list[tuple[str, str]] = []

    @property
    def now(self):
        return self.k * DT_NS

    def keep(self, out):
        self.events += out.events
        if out.command is not None:
            self.sent.append(out.command)
        return out

    def state(self, stamp_ns=None):
        return self.keep(self.control.joint_state(
            self.q.copy(), self.now if stamp_ns is None else stamp_ns, self.now))

    def tick(self, states=True):
        """One period: a joint state, then the control step; the robot then moves."""
        if states:
            self.state()
        out = self.keep(self.control.tick(self.now))
        if out.command is not None:
            self.q += out.command * DT_NS / 1e9
        self.k += 1
        return out

    def arm(self):
        accepted, reason, out = self.control.arm(self.now)
        self.keep(out)
        return accepted, reason


def _assert_ramped(commands, max_delta, start=None):
    """Every consecutive change of every joint within ``max_delta`` (from ``start``)."""
    seq = np.array(([start] if start is not None else []) + list(commands))
    steps = np.abs(np.diff(seq, axis=0))
    assert steps.max() <= max_delta + STEP_TOL, (steps.max(), int(steps.max(axis=1).argmax()))


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
    assert run.arm() == (True, "enabled")
    for _ in range(150):
        out = run.tick()
        assert out.command is not None and out.zero_reason == ""
        A = step.constraint_matrix(run.q - out.command * DT_NS / 1e9)
        np.testing.assert_allclose(A @ out.command, 0.0, atol=1e-9)
    max_delta = ACC * DT_NS / 1e9
    # The first command after enable starts from zero, and so does the check.
    _assert_ramped(run.sent, max_delta, start=np.zeros(7))
    assert np.max(np.abs(run.sent[0])) == pytest.approx(max_delta)
    assert np.max(np.abs(run.sent)) == pytest.approx(0.5)  # reached full speed
    assert not [e for e in run.events if "forces" in e[1]]
    # Disable: ramp down at the same rate, publishing until exactly zero, then silence.
    run.keep(run.control.disarm("disabled by ~/enable"))
    n_before = len(run.sent)
    for _ in range(60):
        run.tick()
    down = run.sent[n_before - 1:]
    _assert_ramped(down, max_delta)
    assert not np.any(down[-1]) and np.all(np.any(np.array(down[:-1]), axis=1))
    # As fast as allowed: no more steps than the largest joint speed needs.
    assert len(down) - 1 <= np.ceil(np.max(np.abs(down[0])) / max_delta) + 1
    assert run.tick().command is None and not run.control.armed
    assert any(level == "info" and text.startswith("armed") for level, text in run.events)
    assert any(text.startswith("disarmed: disabled") for _, text in run.events)


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


def test_a_newly_active_constraint_forcing_a_larger_change_is_logged():
    policy = _Linear(np.full(N, 0.9))  # heads towards the upper limits: all joints move
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=policy)
    run = _Run(step, np.zeros(N))
    run.control.context = "constraints [lock joint 0]"
    run.state()
    run.arm()
    for _ in range(40):
        run.tick()
    assert run.sent[-1][0] > 0.3
    lock = _Row([1.0, 0, 0, 0, 0, 0])
    step.constraints = [lock]
    before = run.sent[-1]
    run.tick()
    after = run.sent[-1]
    assert after[0] == pytest.approx(0.0, abs=1e-12)  # the constraint holds at once
    assert np.all(np.abs(after - before)[1:] <= ACC * DT + STEP_TOL)
    warnings = [text for level, text in run.events if level == "warning"]
    assert len(warnings) == 1 and "forces a command change" in warnings[0]
    assert "joint 0" in warnings[0]
    for _ in range(100):  # further steps are ramped again and not reported again
        run.tick()
    _assert_ramped(run.sent[-101:], ACC * DT)
    assert len([e for e in run.events if e[0] == "warning"]) == 1


def test_arming_is_refused_without_a_model_or_fresh_joint_states():
    step = ControlStep(LOWER, UPPER, VMAX, DT)
    run = _Run(step, np.zeros(N), timeout_s=0.05)
    assert run.arm() == (False, "no model loaded")
    step.policy = _Linear(np.full(N, 0.5))
    accepted, reason = run.arm()
    assert not accepted and "no valid joint state" in reason
    run.state()
    run.k += 6  # 60 ms later: stale by arrival
    accepted, reason = run.arm()
    assert not accepted and "stale" in reason
    assert run.tick(states=False).command is None  # disarmed and silent: nothing sent
    run.state()
    assert run.arm() == (True, "enabled")
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
    assert not np.any(outs[5].command) and "stale" in outs[5].zero_reason
    assert not run.control.armed and run.control.faulted
    for _ in range(20):  # fresh states again: no motion without a new arm
        assert run.tick().command is None
    assert run.arm() == (True, "enabled")
    _assert_ramped([o for o in run.sent[-1:]] + [run.tick().command], ACC * DT)


@pytest.mark.parametrize("stamp, key", [
    (0, "zero_stamp"),
    (-10_000_000_000, "stamp_too_old"),  # relative to now: 10 s old
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
    assert out.rejected == key
    assert out.command is not None and not np.any(out.command)
    assert not run.control.armed
    assert any(level == "warning" and "zero command at once" in text
               for level, text in out.events)
    assert run.tick().command is None  # later good states do not re-arm it


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
    assert not np.any(outs[-1].command) and "stale" in outs[-1].zero_reason


def test_a_backwards_clock_jump_disarms_and_needs_fresh_states():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(10):
        run.tick()
    run.k -= 500  # the simulation restarted: /clock 5 s back
    out = run.control.tick(run.now)
    assert not np.any(out.command) and "clock jumped back by 4.99" in out.zero_reason
    accepted, reason = run.arm()
    assert not accepted and "no valid joint state" in reason
    run.state()  # the restarted sim's stamps are accepted again
    assert run.arm() == (True, "enabled")


def test_broken_joint_states_stop_at_once():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(10):
        run.tick()
    out = run.control.reject_state("untrustworthy joint state: duplicate_joints")
    assert not np.any(out.command) and not run.control.armed
    assert "duplicate_joints" in run.control.zero_reason
    # Already at zero and silent: a second broken message publishes nothing more.
    assert run.control.reject_state("untrustworthy joint state: non_finite").command is None


def test_model_swap_ramps_down_and_stays_disarmed():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.full(N, 0.9)))
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(40):
        run.tick()
    n_before = len(run.sent)
    run.keep(run.control.set_policy(_Linear(np.full(N, -0.9)), reason="model swap to b"))
    assert not run.control.armed and run.control.zero_reason == "model swap to b"
    for _ in range(60):
        run.tick()
    down = run.sent[n_before - 1:]
    _assert_ramped(down, ACC * DT)
    assert not np.any(down[-1]) and len(down) > 20
    # The new model never moved the robot: every command kept the old direction.
    assert np.all(np.array(down) >= 0.0)
    assert run.tick().command is None and not run.control.faulted


def _raises(X):
    raise np.linalg.LinAlgError("SVD did not converge")


@pytest.mark.parametrize(("bad_policy", "reason"), [
    (lambda X: np.full_like(X, np.nan), "policy output not finite"),
    # Any exception of the policy is "no safe command" too: before, it left the control
    # step, and the node's timer callback with it, with the controller armed and holding
    # its last command.
    (_raises, "policy failed: LinAlgError: SVD did not converge"),
])
def test_a_policy_fault_ramps_down(bad_policy, reason):
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
    assert run.control.zero_reason == reason


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
    assert not any("forces a command change" in text for _, text in run.events)


def test_constraints_that_cannot_be_enforced_refuse_the_enable():
    # A plane on a frame that none of the controlled joints moves has a zero row: before,
    # ~/enable answered "enabled" and the first step disarmed.
    robot = Robot.load("talos", [f"arm_left_{i}_joint" for i in range(1, 8)])
    plane = constraint_from_spec({"type": "plane", "frame": "arm_right_7_link",
                                  "normal": [0.0, 0.0, 1.0]}, robot)
    q0 = robot.neutral() + 0.2
    step = ControlStep(robot.lower, robot.upper, np.full(7, 0.5), DT, constraints=[plane],
                       policy=lambda X: -(X - q0))
    run = _Run(step, q0)
    run.state()
    accepted, reason = run.arm()
    assert not accepted and reason.startswith("constraint matrix near-singular")
    step.constraints = []
    assert run.arm() == (True, "enabled")


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
    assert run.q[0] > 0.99 and not [e for e in run.events if "forces" in e[1]]


def test_velocity_scale_brakes_for_limits_when_given_an_acceleration():
    q = np.array([0.9, 0, 0, 0, 0, 0])  # 0.1 rad from the upper limit
    v = np.array([0.5, 0, 0, 0, 0, 0])
    assert velocity_scale(q, v, DT, LOWER, UPPER, VMAX) == 1.0
    s = velocity_scale(q, v, DT, LOWER, UPPER, VMAX, max_acceleration=2.0)
    assert s * 0.5 == pytest.approx(np.sqrt(2.0 * 0.1))


def test_bad_armed_controller_settings():
    step = ControlStep(LOWER, UPPER, VMAX, DT)
    with pytest.raises(ValueError, match="max_acceleration"):
        ArmedController(step, 0.0, 0.1)
    with pytest.raises(ValueError, match="state_timeout_s"):
        ArmedController(step, 1.0, float("nan"))
    with pytest.raises(ValueError, match="max_clock_skew_s"):
        ArmedController(step, 1.0, 0.1, -1.0)


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
    qdot, reason = step(q)
    assert reason == "" and not np.any(qdot) and step.extrapolation_scale == 0.0
    # The same state with the policy pointing back in: unscaled, and so is sideways motion.
    step.policy = _outward(-0.3)
    qdot, _ = step(q)
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
    qdot, reason = step(q)
    assert reason == ""
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
    assert run.arm() == (True, "enabled")
    scales = []
    for _ in range(300):
        out = run.tick()
        assert out.command is not None and out.zero_reason == ""
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
    qdot, reason = step(np.zeros(N))
    assert not np.any(qdot) and reason.startswith("extrapolation guard: ")
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


# -- drift correction of held frames and near-singular constraints ----------------------
EXECUTOR_JOINTS = TALOS_JOINTS + ["head_1_joint", "head_2_joint"]
LEFT_HAND = "arm_left_7_link"


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
    assert run.arm() == (True, "enabled")
    p_ref = hold.hold_position(run.q)
    worst = 0.0
    for _ in range(round(seconds * 1e9 / DT_NS)):
        run.state()
        out = run.keep(run.control.tick(run.now))
        assert out.zero_reason == ""
        if out.command is not None:
            run.q, _ = integrate_clamped(run.q, tracking * out.command, DT_NS / 1e9,
                                         robot.lower, robot.upper)
        run.k += 1
        worst = max(worst, float(np.linalg.norm(hold.hold_position(run.q) - p_ref)))
    return worst, run


def test_held_frame_drifts_at_most_1_mm_over_60_s_and_more_without_correction():
    worst, run = _held_hand_run(drift_gain=5.0)
    assert worst <= 1e-3, worst
    moved = np.sum(np.abs(np.diff(np.array(run.sent), axis=0)) > 0, axis=0)
    assert np.count_nonzero(moved) >= 10  # a real motion of most joints, not a stand-still
    # The correction goes through the ramp: every step within max_acceleration * dt.
    _assert_ramped(run.sent, ACC * DT_NS / 1e9 + 1e-6, start=np.zeros(len(EXECUTOR_JOINTS)))
    assert not [e for e in run.events if "forces" in e[1]]
    uncorrected, _ = _held_hand_run(drift_gain=0.0)
    assert uncorrected > 1e-3, uncorrected  # the test can fail: drift is real


def _talos_hold_and_plane():
    robot = Robot.load("talos", EXECUTOR_JOINTS)
    hold = constraint_from_spec({"type": "position", "frame": LEFT_HAND}, robot)
    plane = constraint_from_spec({"type": "plane", "frame": "arm_right_7_link",
                                  "normal": [0.2, 0.5, 1.0]}, robot)
    return robot, hold, plane


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
        qdot, reason = step(q)
        assert reason == ""
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
    qdot, reason = step(q)
    assert reason == "" and qdot[j] == 0.0 and np.linalg.norm(qdot) > 1e-3
    # The other joints still correct: the held frame moves back towards its reference.
    e = step.hold_errors(q)
    assert float(e @ (hold.matrix(q) @ qdot)) < 0.0


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


def test_ramp_toward_applies_a_correction_outside_the_null_space_at_once():
    rng = np.random.default_rng(11)
    A = rng.normal(size=(2, N))
    P = constrained_projector(A)
    correction = A.T @ rng.normal(size=2)  # in the row space of A
    target = P @ rng.normal(size=N) + correction
    previous = P @ rng.normal(size=N)
    command, alpha, _ = ramp_toward(previous, target, P, 0.01)
    assert alpha < 1.0
    np.testing.assert_allclose(A @ command, A @ target, atol=1e-12)


def test_a_near_singular_constraint_matrix_ramps_down_and_says_why():
    first = _Row([1.0, 0, 0, 0, 0, 0])
    second = _Row([0.0, 1.0, 0, 0, 0, 0])
    step = ControlStep(LOWER, UPPER, VMAX, DT_NS / 1e9, constraints=[first, second],
                       policy=_Linear(np.full(N, 0.9)), min_singular_value=0.01)
    run = _Run(step, np.zeros(N))
    run.state()
    run.arm()
    for _ in range(40):
        assert run.tick().zero_reason == ""
    assert np.abs(run.sent[-1]).max() > 0.3
    second.row = np.array([[1.0, 0.005, 0, 0, 0, 0]])  # nearly the first row again
    out = run.tick()
    assert out.zero_reason.startswith("constraint matrix near-singular: smallest singular "
                                      "value 0.00354 < min_singular_value 0.01")
    assert any(text.startswith("disarmed: constraint matrix near-singular")
               for _, text in out.events), out.events
    n_before = len(run.sent)
    for _ in range(40):
        run.tick()
    _assert_ramped(run.sent[n_before - 1:], ACC * DT_NS / 1e9)
    assert not np.any(run.sent[-1]) and not run.control.armed and run.control.faulted
    # Rows more than joints can never be independent.
    step.constraints = [_Row(r) for r in np.eye(N + 1, N)]
    assert "near-singular" in step(np.zeros(N))[1]


def test_bad_drift_and_singularity_settings():
    for kwargs, match in (({"drift_gain": -1.0}, "drift_gain"),
                          ({"drift_clamp_m": 0.0}, "drift_clamp_m"),
                          ({"min_singular_value": float("nan")}, "min_singular_value")):
        with pytest.raises(ValueError, match=match):
            ControlStep(LOWER, UPPER, VMAX, DT, **kwargs)


def test_guard_without_a_finite_stopping_distance_gives_zero_with_a_reason():
    guard = ExtrapolationGuard(_PointSupport(np.zeros(N)), 3.0)
    step = ControlStep(-10 * np.ones(N), 10 * np.ones(N), np.full(N, np.inf), DT,
                       policy=_outward(0.3), guard=guard, max_acceleration=ACC)
    q = np.zeros(N)
    assert step(q)[1] == ""  # inside: nothing to scale, no band needed
    q[0] = 0.35  # 3.5 spacings, leading out
    qdot, reason = step(q)
    assert not np.any(qdot) and "band needs finite max_velocity" in reason


def test_joint_velocity_bounds_from_position_and_speed_limits() -> None:
    lower, upper = np.array([-1.0, -1.0, -np.inf]), np.array([1.0, 1.0, np.inf])
    q = np.array([1.0, 0.99, 5.0])
    lo, hi = joint_velocity_bounds(q, lower, upper)
    np.testing.assert_array_equal(hi, [0.0, np.inf, np.inf])
    np.testing.assert_array_equal(lo, [-np.inf] * 3)
    lo, hi = joint_velocity_bounds(q, lower, upper, max_velocity=2.0, dt=0.01)
    np.testing.assert_allclose(hi, [0.0, 1.0, 2.0])  # 0.01 rad of room over 10 ms
    np.testing.assert_allclose(lo, [-2.0, -2.0, -2.0])
