"""Tests of policy_align_ros.control.stall (stall detection) inside the ArmedController.

A simulated robot tracks the executor's commands through a first-order lag (or does not
move at all: blocked), on an injected clock (tick counts), never on wall time.
"""

import numpy as np
import pytest
from control_rigs import ACC, DT, DT_NS, LOWER, UPPER, VMAX, N, _assert_ramped, _Constant, _Linear

from policy_align_ros.control import (
    ArmedController,
    ControlStep,
    StallDetector,
    ZeroCause,
    arming_status,
)
from policy_align_ros.control.stall import STALL_MIN_SPEED, stall_time_problem
from policy_align_ros.control.status import ERROR, OK

STALL_S = 0.5
NAMES = [f"j{i}" for i in range(N)]


class _Robot:
    """Joint velocities following the last command with time constant ``tau`` (s); joints
    in ``blocked`` (bool (N,)) do not move; positions read with Gaussian ``noise`` (rad)."""

    def __init__(self, q0, tau=0.05, noise=0.0, seed=0):
        self.q = np.asarray(q0, dtype=float).copy()
        self.v = np.zeros(N)
        self.tau, self.noise = tau, noise
        self.blocked = np.zeros(N, dtype=bool)
        self.command = np.zeros(N)
        self.rng = np.random.default_rng(seed)

    def read(self):
        return self.q + self.noise * self.rng.standard_normal(N)

    def run(self, dt, substeps=10):
        h = dt / substeps
        for _ in range(substeps):
            self.v += h * (self.command - self.v) / self.tau if self.tau > 0 else 0.0
            if self.tau == 0:
                self.v = self.command.copy()
            self.v[self.blocked] = 0.0
            self.q += h * self.v


def _controller(policy, stall_s=STALL_S, max_acceleration=ACC):
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=policy)
    return ArmedController(step, max_acceleration, 0.05, joint_names=NAMES,
                           stall=StallDetector(N, stall_s, joint_names=NAMES))


def _drive(control, robot, seconds, *, arm=True, on_tick=None, start_ns=1_000_000_000):
    """Joint state, tick, robot motion, every period for ``seconds`` from ``start_ns``;
    the commands sent, their times (ns) and the time of the stall's disarm (None: none)."""
    now = start_ns
    control.joint_state(robot.read(), now, now)
    if arm:
        assert control.arm(now)[0]
    sent, times, stalled_at = [], [], None
    for k in range(round(seconds / DT)):
        now += DT_NS
        if on_tick is not None:
            on_tick(k, robot)
        control.joint_state(robot.read(), now, now)
        out = control.tick(now)
        if control.stalled and stalled_at is None:
            stalled_at = now
        if out.command is not None:
            robot.command = out.command.copy()
            sent.append(out.command.copy())
            times.append(now)
        robot.run(DT)
    return sent, times, stalled_at


def test_a_blocked_robot_disarms_within_stall_time_of_the_command_exceeding_the_floor():
    control = _controller(_Constant(np.full(N, 0.4)))
    robot = _Robot(np.zeros(N))
    robot.blocked[:] = True
    sent, times, stalled_at = _drive(control, robot, 2.0)
    assert stalled_at is not None and not control.armed and control.faulted
    first = next(t for c, t in zip(sent, times, strict=True)
                 if np.abs(c).max() >= STALL_MIN_SPEED)
    assert stalled_at - first <= round(STALL_S * 1e9) + DT_NS
    # Ramped down within max_acceleration (not cut), to zero, then silent.
    _assert_ramped(sent, ACC * DT, start=np.zeros(N))
    assert not np.any(sent[-1]) and not control.publishing
    assert control.zero_cause == ZeroCause.STALL and control.last_stall.joints == tuple(NAMES)
    level, _, values = arming_status(control, times[-1], model="m", model_state="joints",
                                     constraints="[]", rejected={})
    assert level == ERROR and values["stalled"] == "true"
    assert values["zero_cause"] == "stall" and values["zero_reason"] == control.zero_reason


def test_a_robot_blocked_while_moving_disarms_within_stall_time_naming_the_joint():
    control = _controller(_Constant(np.full(N, 0.4)))
    robot = _Robot(np.full(N, -0.9))
    blocked_at = []

    def block_j3(k, r):
        if k == 100:  # 1 s in: moving at 0.4 rad/s
            r.blocked[3] = True
            blocked_at.append(1_000_000_000 + (k + 1) * DT_NS)

    _, _, stalled_at = _drive(control, robot, 3.0, on_tick=block_j3)
    assert stalled_at is not None
    assert stalled_at - blocked_at[0] <= round(STALL_S * 1e9) + DT_NS
    stall = control.last_stall
    assert control.zero_cause == ZeroCause.STALL
    assert stall.joints == ("j3",)  # only j3 stalled
    assert stall.commanded == pytest.approx(0.4, abs=5e-4) and abs(stall.moved) < 0.1
    assert "j3" in control.zero_reason


@pytest.mark.parametrize("tau", [0.05, 0.1])
@pytest.mark.parametrize("noise", [0.0, 1e-4])
def test_a_lagging_robot_on_a_realistic_run_never_stalls(tau, noise):
    # An attractor with a rotation: the run speeds up, curves, reverses joints and settles
    # at the goal (commands near zero), all through the lag; encoder noise on top.
    center = np.array([0.3, -0.2, 0.1, 0.0, -0.3, 0.2])
    rng = np.random.default_rng(1)
    skew = rng.standard_normal((N, N))
    skew = 2.0 * (skew - skew.T) / np.linalg.norm(skew - skew.T)

    def policy(X):
        return -(X - center) @ (np.eye(N) + skew).T

    control = _controller(policy)
    robot = _Robot(np.array([-0.8, 0.8, -0.7, 0.8, 0.7, -0.8]), tau=tau, noise=noise)
    sent, _, stalled_at = _drive(control, robot, 8.0)
    assert stalled_at is None and control.armed, control.zero_reason
    speeds = np.abs(np.array(sent)).max(axis=1)
    assert speeds.max() > 0.4  # the run really was fast...
    assert np.abs(robot.q - center).max() < 0.05  # ...and reached the goal


def test_commands_below_the_floor_never_count_and_zero_turns_detection_off():
    control = _controller(_Constant(np.full(N, 0.5 * STALL_MIN_SPEED)))
    robot = _Robot(np.zeros(N))
    robot.blocked[:] = True
    assert _drive(control, robot, 2.0)[2] is None and control.armed
    control = _controller(_Constant(np.full(N, 0.4)), stall_s=0.0)
    robot = _Robot(np.zeros(N))
    robot.blocked[:] = True
    assert _drive(control, robot, 2.0)[2] is None and control.armed


def test_a_blocked_robot_with_encoder_noise_still_stalls_and_rearming_starts_afresh():
    control = _controller(_Constant(np.full(N, 0.4)))
    robot = _Robot(np.zeros(N), noise=1e-4)
    robot.blocked[:] = True
    _, times, stalled_at = _drive(control, robot, 2.0)
    assert stalled_at is not None
    # Free again and enabled: the old window does not count against the new arming.
    robot.blocked[:] = False
    sent, _, stalled_again = _drive(control, robot, 1.5, start_ns=3_000_000_000 + DT_NS)
    assert stalled_again is None and control.armed and not control.stalled
    level, _, values = arming_status(control, times[-1], model="m", model_state="joints",
                                     constraints="[]", rejected={})
    assert values["stalled"] == "false" and values["stall_time_s"] == "0.5"


def test_stall_time_must_be_zero_or_long_enough():
    assert stall_time_problem(0.0) == "" and stall_time_problem(0.1) == ""
    assert "stall_time_s" in stall_time_problem(0.05)
    assert stall_time_problem(float("nan"))
    with pytest.raises(ValueError, match="stall_time_s"):
        StallDetector(N, 0.01)
    detector = StallDetector(N, 0.0)
    assert not detector.enabled and detector.find() is None and detector.check() == ""


def test_the_detector_compares_displacements_over_the_window():
    # Command 0.2 rad/s on joint 0 from t = 0, no lag; a robot at a fifth of that speed.
    detector = StallDetector(2, 0.5, joint_names=["a", "b"], lag_s=0.0)
    for k in range(61):
        t = k * DT_NS
        detector.command(np.array([0.2, 0.0]), t)
        detector.position(np.array([0.04 * k * DT, 0.0]), t)
        if k < 50:
            assert detector.find() is None, k  # the window is not full yet
    stall = detector.find()
    assert stall.joints == ("a",)
    assert stall.commanded == pytest.approx(0.2) and stall.moved == pytest.approx(0.04)
    assert stall.window_s == pytest.approx(0.5)
    assert detector.check() == stall.text  # the same stall in words
    detector.reset()
    assert detector.find() is None and detector.check() == ""
    level = arming_status(_controller(_Linear(np.zeros(N))), 0, model="", model_state="",
                          constraints="", rejected={})[0]
    assert level == OK


def test_a_joint_moving_against_its_command_stalls():
    class _Reversed(_Robot):  # joint 2 wired with the wrong sign
        def run(self, dt, substeps=10):
            self.command[2] = -self.command[2]
            super().run(dt, substeps)
            self.command[2] = -self.command[2]

    control = _controller(_Constant(np.full(N, 0.2)))
    _, _, stalled_at = _drive(control, _Reversed(np.zeros(N)), 2.0)
    # Caught while still ramping up: the window's mean command is below 0.2 rad/s.
    assert stalled_at is not None and control.last_stall.joints == ("j2",)
    assert control.last_stall.moved < 0.0 < control.last_stall.commanded  # moved against it


def test_a_continuous_joint_crossing_the_wrap_is_followed_not_stalled():
    # Joint 0 continuous, commanded 1 rad/s and moving so, read modulo a turn in [-pi, pi)
    # as a driver reports it: it crosses +pi -> -pi within the window.
    def wrapped(angle):
        return (angle + np.pi) % (2 * np.pi) - np.pi

    continuous = StallDetector(2, 0.5, joint_names=["a", "b"], lag_s=0.0,
                               continuous=[True, False])
    plain = StallDetector(2, 0.5, joint_names=["a", "b"], lag_s=0.0)
    plain_stalls = []
    for k in range(120):
        t = k * DT_NS
        q = np.array([wrapped(2.9 + k * DT), 0.0])
        for detector in (continuous, plain):
            detector.command(np.array([1.0, 0.0]), t)
            detector.position(q, t)
        assert continuous.find() is None, k
        plain_stalls.append(plain.find())
    # Read as a plain joint, a window holding the wrap shows a jump of 2 pi against the
    # command: a "stall" of joint a.
    found = [stall for stall in plain_stalls if stall is not None]
    assert found and all(stall.joints == ("a",) and stall.moved < 0 for stall in found)
    # A continuous joint that is blocked still stalls.
    blocked = StallDetector(1, 0.5, lag_s=0.0, continuous=[True])
    for k in range(60):
        blocked.command(np.array([1.0]), k * DT_NS)
        blocked.position(np.array([3.1]), k * DT_NS)
    assert blocked.find() is not None
    with pytest.raises(ValueError, match="continuous"):
        StallDetector(2, 0.5, continuous=[True])
