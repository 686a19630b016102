"""The extrapolation guard holding an armed robot at the data's edge, reported
(policy_align_ros.control.guard_hold): which limit binds, the distance in its units and in
rad, the cause on /diagnostics, one log line per hold, and no stall taken for a hold (or a
hold for a stall). ROS-free, on an injected clock; the guard's law is not changed.
"""

import numpy as np
import pytest
from control_rigs import ACC, DT, DT_NS, VMAX, N

from policy_align_ros.control import (
    ArmedController,
    ControlStep,
    ExtrapolationGuard,
    GuardHoldLog,
    StallDetector,
    ZeroCause,
    arming_status,
    guard_hold,
)
from policy_align_ros.control.guard_hold import HOLD_LOG_INTERVAL_NS, HOLD_SCALE
from policy_align_ros.control.status import ERROR, OK, WARN

NAMES = [f"j{i}" for i in range(N)]


class _Data:
    """Toy distance: the demonstrated data is the single state 0, ``spacing`` rad apart."""

    def __init__(self, spacing):
        self.spacing = spacing

    def __call__(self, q):
        r = float(np.linalg.norm(q))
        return r / self.spacing, (q / (r * self.spacing) if r > 0 else None)


def _controller(spacing, push=0.3, stall_s=0.0, max_extrapolation=6.0):
    """Armed controller with a guard on :class:`_Data` and a constant policy along +x."""
    guard = ExtrapolationGuard(_Data(spacing), max_extrapolation, max_extrapolation_rad=0.5)
    policy = lambda X: np.tile(push * np.eye(N)[0], (len(X), 1))  # noqa: E731
    step = ControlStep(-10 * np.ones(N), 10 * np.ones(N), VMAX, DT, policy=policy,
                       guard=guard, max_acceleration=ACC)
    stall = StallDetector(N, stall_s, joint_names=NAMES) if stall_s else None
    return ArmedController(step, ACC, 0.05, joint_names=NAMES, stall=stall)


class _Robot:
    """Follows each command exactly (or not at all when ``blocked``), on tick counts."""

    def __init__(self, control, q0, blocked=False, log_interval_ns=HOLD_LOG_INTERVAL_NS):
        self.control, self.q, self.blocked = control, np.asarray(q0, dtype=float), blocked
        self.now = 1_000_000_000
        self.log = GuardHoldLog(log_interval_ns)
        self.lines: list[str] = []
        control.joint_state(self.q.copy(), self.now, self.now)
        assert control.arm(self.now)[0]

    def run(self, seconds):
        for _ in range(round(seconds / DT)):
            self.now += DT_NS
            self.control.joint_state(self.q.copy(), self.now, self.now)
            out = self.control.tick(self.now)
            self.lines += [text for _, text in self.log.update(self.control, self.now)]
            if out.command is not None and not self.blocked:
                self.q = self.q + out.command * DT

    def status(self):
        level, message, values = arming_status(self.control, self.now, model="m.npz",
                                               model_state="joints", constraints="[]",
                                               rejected={})
        return level, values


def test_a_hold_where_max_extrapolation_rad_binds_names_it_with_the_distance_in_rad():
    # The UR10's case: demonstrations 0.36 rad apart, so 0.5 rad is 1.4 spacings, far
    # inside max_extrapolation 6: the rad cap holds the robot, every output said OK.
    robot = _Robot(_controller(spacing=0.36), np.zeros(N))
    robot.run(12.0)
    control = robot.control
    assert control.armed and control.extrapolation_scale <= HOLD_SCALE
    hold = guard_hold(control)
    assert hold.limit == "max_extrapolation_rad" and hold.value == 0.5
    x = control.last_q[0]  # where the guard measured last
    assert hold.distance == hold.distance_rad == pytest.approx(x, rel=1e-9)
    assert hold.distance == pytest.approx(hold.edge, abs=0.01) and hold.edge == 0.5
    assert hold.distance_spacings == pytest.approx(x / 0.36)
    assert hold.distance_spacings < 6.0
    level, values = robot.status()
    assert level == WARN and values["armed"] == "true"
    assert values["zero_cause"] == ZeroCause.EXTRAPOLATION_HOLD
    assert values["extrapolation_hold"] == "max_extrapolation_rad"
    assert values["zero_reason"] == hold.text and "max_extrapolation_rad" in hold.text
    assert float(values["extrapolation_distance_rad"]) == pytest.approx(x, abs=1e-3)
    assert float(values["extrapolation_distance"]) == pytest.approx(x / 0.36, abs=0.01)
    # Said once when it began, not every cycle.
    assert len(robot.lines) == 1 and "max_extrapolation_rad" in robot.lines[0]


def test_a_hold_where_max_extrapolation_binds_is_given_in_spacings():
    # Demonstrations 0.01 rad apart: 6 spacings plus the stopping band end well inside
    # 0.5 rad, so the limit in spacings holds the robot.
    robot = _Robot(_controller(spacing=0.01, push=0.1), np.zeros(N))
    robot.run(12.0)
    hold = guard_hold(robot.control)
    x = robot.control.last_q[0]
    assert hold.limit == "max_extrapolation" and hold.value == 6.0
    assert hold.distance == hold.distance_spacings == pytest.approx(x / 0.01)
    assert hold.distance == pytest.approx(hold.edge, abs=0.2) and hold.edge > 6.0
    assert hold.distance_rad == pytest.approx(x) and hold.distance_rad < 0.5
    level, values = robot.status()
    assert values["zero_cause"] == ZeroCause.EXTRAPOLATION_HOLD
    assert values["extrapolation_hold"] == "max_extrapolation"


def test_a_hold_ends_when_the_policy_leads_back_and_a_new_one_is_logged_once_per_interval():
    interval_s = 30.0
    robot = _Robot(_controller(spacing=0.36), np.zeros(N), log_interval_ns=interval_s * 1e9)
    robot.run(12.0)
    assert guard_hold(robot.control) is not None and len(robot.lines) == 1
    step = robot.control.step
    outward = step.policy
    step.policy = lambda X: -outward(X)  # back towards the data: never scaled
    robot.run(0.5)
    level, values = robot.status()
    assert guard_hold(robot.control) is None and level == OK
    assert values["zero_cause"] == "none" and values["extrapolation_hold"] == "none"
    # Out again at once: held again, but within the interval nothing more is said...
    step.policy = outward
    robot.run(5.0)
    assert guard_hold(robot.control) is not None and len(robot.lines) == 1
    # ...while a hold that begins after it is said again.
    step.policy = lambda X: -outward(X)
    robot.run(0.5)
    step.policy = lambda X: 0.0 * outward(X)  # at rest inside the edge: no hold
    robot.run(interval_s)
    assert guard_hold(robot.control) is None
    step.policy = outward
    robot.run(5.0)
    assert guard_hold(robot.control) is not None and len(robot.lines) == 2


def test_the_distance_to_the_data_is_not_applicable_before_the_first_step():
    # Armed, nothing sent yet: nothing has been measured, which is not a number.
    robot = _Robot(_controller(spacing=0.1), 0.5 * np.eye(N)[0])
    values = robot.status()[1]
    assert values["extrapolation_distance"] == values["extrapolation_distance_rad"] == "n/a"
    robot.run(DT)
    assert float(robot.status()[1]["extrapolation_distance_rad"]) == pytest.approx(0.5, abs=0.01)


def test_no_hold_is_reported_while_disarmed():
    robot = _Robot(_controller(spacing=0.36), np.zeros(N))
    robot.run(12.0)
    robot.control.disarm("disabled by ~/enable")
    robot.run(1.0)
    assert guard_hold(robot.control) is None
    level, values = robot.status()
    assert values["zero_cause"] == ZeroCause.DISABLED and values["extrapolation_hold"] == "none"


def test_a_robot_held_at_the_edge_is_not_taken_for_a_stalled_one():
    # Stall detection on: standing still for many stall windows at the edge is a hold.
    robot = _Robot(_controller(spacing=0.36, stall_s=0.5), np.zeros(N))
    robot.run(15.0)
    control = robot.control
    assert control.armed and not control.stalled
    level, values = robot.status()
    assert values["zero_cause"] == ZeroCause.EXTRAPOLATION_HOLD and values["stalled"] == "false"
    # Blocked right at the edge, the command is held at zero: still no stall.
    blocked = _Robot(_controller(spacing=0.36, stall_s=0.5), control.last_q, blocked=True)
    blocked.run(3.0)
    assert blocked.control.armed and not blocked.control.stalled
    assert guard_hold(blocked.control) is not None


def test_a_robot_blocked_while_the_guard_scales_it_is_a_stall_not_a_hold():
    # Inside the band (scale about a half, command 0.15 rad/s >= the stall floor), a
    # blocked robot stalls; the report is the stall's alone.
    robot = _Robot(_controller(spacing=0.36, stall_s=0.5), np.eye(N)[0] * 0.32,
                   blocked=True)
    robot.run(2.0)
    control = robot.control
    assert control.stalled and not control.armed
    assert guard_hold(control) is None
    level, values = robot.status()
    assert level == ERROR and values["zero_cause"] == ZeroCause.STALL
    assert values["stalled"] == "true" and values["extrapolation_hold"] == "none"
