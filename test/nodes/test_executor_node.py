"""Integration tests of the ``executor`` node: arming, ramps, staleness, parameters, models,
diagnostics, the controller check, sim time and lockstep (own rclpy.Context, domain ids 112,
126, 150-156, 158, 159, 200, 201, 204, 205, 208, 210-214, 219).

Assertions count control ticks and messages, never wall-clock speed: waits are "until a
condition holds, or fail after a generous timeout". The ramp, arming and staleness logic
itself is tested without a graph in test/control/.
"""

import re

import numpy as np
import pytest
from executor_rig import (
    ACC,
    JOINTS,
    PERIOD,
    PLANE,
    Rig,
    _assert_ramped,
    _attractor_policy,
    _fit_model,
)
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.time import Time
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import SetBool

from policy_align_ros.control import ZeroCause
from policy_align_ros.nodes import executor as executor_module


def _refusal_cause(r: Rig) -> ZeroCause | None:
    """Why the controller refuses to arm now (None: it would arm)."""
    return r.node.controller.arm_check(r.node._now_ns())[0]


def test_enable_is_refused_without_a_model_and_with_stale_joint_states(rig):
    r = rig(150)
    response = r.enable(True)
    assert not response.success and _refusal_cause(r) == ZeroCause.NO_MODEL
    # The fixes: set model_path (the command that does it), or run the learner.
    assert "policy-align param set /executor model_path" in response.message
    assert "/learner/model" in response.message
    r.spin(0.2)
    assert r.commands == []  # disarmed: the topic is left alone
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin(0.1, publish_states=False)
    r.stamp = r.node.get_clock().now().to_msg()
    r.publish_state()  # one state, then nothing: stale after state_timeout_s
    r.spin(0.7, publish_states=False)
    response = r.enable(True)
    # The rig goes on publishing the old stamp while ~/enable waits: stale either way.
    assert not response.success
    assert _refusal_cause(r) in (ZeroCause.STALE_STATE, ZeroCause.FROZEN_STAMP)
    # The topic and the parameter that bounds the age.
    assert "/joint_states" in response.message and "state_timeout_s" in response.message
    r.stamp = None
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.commands) >= 5, what="commands")


def test_commands_ramp_follow_the_policy_and_satisfy_the_constraint(rig):
    r = rig(151)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.commands) >= 30, what="30 commands")
    # Every step, starting from zero at enable: the first command too.
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))
    assert np.max(np.abs(r.commands[0])) == pytest.approx(ACC * PERIOD)
    A = r.node.controller.step.constraint_matrix(r.q)
    assert A.shape == (1, len(JOINTS))
    for c in r.commands:
        assert np.abs(A @ c).max() < 1e-9 * max(1.0, np.linalg.norm(c))
        assert np.abs(c).max() <= 0.5 + 1e-12
    # The policy pulls back towards the neutral posture: a descent direction of the potential.
    assert float(r.commands[-1] @ (r.q - r.node.robot.neutral())) < 0


def test_stale_joint_states_stop_at_once_and_disarm(rig):
    r = rig(152, state_timeout_s=0.3)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.commands) >= 20 and np.max(np.abs(r.commands[-1])) > 0.1,
                 what="motion")
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False, what="disarm")
    r.spin(0.1, publish_states=False)
    # Straight to zero (no ramp without a trusted state), then silence.
    assert not np.any(r.commands[-1]) and np.max(np.abs(r.commands[-2])) > 0.1
    assert r.node.controller.zero_cause == ZeroCause.STALE_STATE
    count = len(r.commands)
    r.spin(0.3)  # fresh states again: it stays disarmed
    assert len(r.commands) == count and not r.node.controller.armed


def test_disable_ramps_down_to_zero_then_stays_silent(rig):
    r = rig(153)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.commands) >= 20, what="motion")
    assert np.any(r.commands[-1])
    response = r.enable(False)
    assert response.success and not r.node.controller.armed
    assert r.node.controller.zero_cause == ZeroCause.DISABLED and not r.node.controller.faulted
    r.spin_until(lambda: not r.node.controller.publishing, what="ramp down")
    r.spin(0.1)
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))
    assert not np.any(r.commands[-1])
    count = len(r.commands)
    r.spin(0.3)
    assert len(r.commands) == count


def test_shutdown_sends_a_zero_command(rig):
    r = rig(154)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "")
    r.enable(True)
    r.spin_until(lambda: len(r.commands) >= 5 and np.any(r.commands[-1]), what="motion")
    r.executor.remove_node(r.node)
    r.node.destroy_node()
    r.node = None
    r.spin(0.2, publish_states=False)
    assert not np.any(r.commands[-1])


def test_bad_parameters_are_refused_with_a_reason(rig):
    r = rig(155)
    node = r.node
    result = node.set_parameters([Parameter("constraints", value="[{type: plane}]")])[0]
    assert not result.successful and "frame" in result.reason
    result = node.set_parameters([Parameter("constraints",
                                            value="[{type: joints, joints: 3}]")])[0]
    assert not result.successful and "joints" in result.reason
    result = node.set_parameters([Parameter("constraints", value="[]")])[0]
    assert result.successful and node.controller.step.constraints == []
    for name, bad in (("max_velocity", -1.0), ("max_acceleration", 0.0),
                      ("max_acceleration", 1000.0), ("max_acceleration", float("nan")),
                      ("state_timeout_s", 0.0), ("max_clock_skew_s", -0.1)):
        result = node.set_parameters([Parameter(name, value=bad)])[0]
        assert not result.successful and result.reason, (name, bad)
    assert node.set_parameters([Parameter("max_velocity", value=0.2)])[0].successful
    assert np.max(node.controller.step.max_velocity) == 0.2
    assert node.set_parameters([Parameter("max_acceleration", value=3.0)])[0].successful
    assert node.controller.max_acceleration == 3.0
    assert node.set_parameters([Parameter("max_clock_skew_s", value=0.2)])[0].successful
    assert node.controller.max_clock_skew_s == pytest.approx(0.2)
    assert not node.set_parameters([Parameter("rate_hz", value=50.0)])[0].successful
    # The joint-limit margin reaches the control step's braking limits.
    step = node.controller.step
    assert step.joint_limit_margin == 0.05
    for bad in (-0.1, 0.6, float("nan")):
        assert not node.set_parameters([Parameter("joint_limit_margin", value=bad)]
                                       )[0].successful
    assert node.set_parameters([Parameter("joint_limit_margin", value=0.1)])[0].successful
    finite = np.isfinite(step.upper) & (step.upper - step.lower > 0.4)
    np.testing.assert_allclose(step.control_upper[finite], step.upper[finite] - 0.1)
    assert not node.set_parameters([Parameter("max_extrapolation_rad", value=0.0)]
                                   )[0].successful
    # Every numeric parameter documents its range.
    for desc in node.describe_parameters(["max_velocity", "max_acceleration",
                                          "state_timeout_s", "max_clock_skew_s", "rate_hz",
                                          "joint_limit_margin", "max_extrapolation_rad"]):
        assert desc.description and len(desc.floating_point_range) == 1, desc.name


def test_more_constraint_rows_than_joints_refuse_the_enable_naming_the_fix(rig):
    # A plane (1 row) and the seven joints held (7 rows) and a second plane: 9 rows.
    specs = (f"[{PLANE[1:-1]}, {{type: joints, joints: [{', '.join(JOINTS)}]}}, "
             "{type: plane, frame: arm_left_7_link, normal: [1, 0, 0]}]")
    r = rig(126, constraints=specs)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    response = r.enable(True)
    assert not response.success and not r.node.controller.armed
    assert _refusal_cause(r) == ZeroCause.CONSTRAINTS_NEAR_SINGULAR
    # The rows and the joints counted, and the parameter to remove one from; the
    # singular-value threshold is no fix here.
    assert re.search(r"\b9\b.*\b7 joints\b", response.message), response.message
    assert "constraints" in response.message and "min_singular_value" not in response.message
    assert r.node.set_parameters([Parameter("constraints", value=PLANE)])[0].successful
    assert r.enable(True).success


def test_model_announced_on_learner_topic_is_loaded_and_checked(rig, tmp_path):
    r = rig(156)
    center = np.zeros(len(JOINTS))
    # Fitted first: a fit blocks this thread, and the joint states with it.
    good = _fit_model(tmp_path / "good.npz", JOINTS, center)
    wrong = _fit_model(tmp_path / "wrong.npz", [j.replace("left", "right") for j in JOINTS],
                       center)
    r.models.publish(String(data=str(good)))
    r.spin_until(lambda: r.node.model_path == str(good), what="model loaded")
    assert r.node.controller.step.policy is not None
    assert r.node.get_parameter("model_path").value == str(good)
    assert r.enable(True).success
    r.spin_until(lambda: r.commands and np.linalg.norm(r.commands[-1]) > 1e-6,
                 what="motion")
    r.models.publish(String(data=str(wrong)))
    r.spin(0.3)
    assert r.node.model_path == str(good)  # refused: trained on other joints
    assert r.node.get_parameter("model_path").value == str(good)
    assert r.node.controller.armed  # a refused model changes nothing


def test_model_path_set_at_run_time_loads_the_model_or_is_refused(rig, tmp_path):
    r = rig(158)
    center = np.zeros(len(JOINTS))
    # Fitted first: a fit blocks this thread, and the joint states with it.
    other = _fit_model(tmp_path / "other.npz", JOINTS, center)
    result = r.node.set_parameters([Parameter("model_path", value=str(tmp_path / "no.npz"))])
    assert not result[0].successful and "no.npz" in result[0].reason
    assert r.node.controller.step.policy is None and r.node.model_path == ""
    wrong = _fit_model(tmp_path / "wrong.npz", [j.replace("left", "right") for j in JOINTS],
                       center)
    result = r.node.set_parameters([Parameter("model_path", value=str(wrong))])[0]
    assert not result.successful and "joints" in result.reason
    good = _fit_model(tmp_path / "good.npz", JOINTS, center)
    assert r.node.set_parameters([Parameter("model_path", value=str(good))])[0].successful
    assert r.node.model_path == str(good) and r.node.controller.step.policy is not None
    result = r.node.set_parameters([Parameter("model_path", value="")])[0]
    assert not result.successful and r.node.model_path == str(good)
    # A swap while armed ramps down and leaves the executor disarmed.
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.commands) >= 15, what="motion")
    assert r.node.set_parameters([Parameter("model_path", value=str(other))])[0].successful
    assert not r.node.controller.armed
    assert r.node.controller.zero_cause == ZeroCause.MODEL_SWAP
    r.spin_until(lambda: not r.node.controller.publishing, what="ramp down")
    r.spin(0.2)
    assert not np.any(r.commands[-1]) and not r.node.controller.armed
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))


def test_broken_or_badly_stamped_joint_states_stop_at_once_and_are_counted(rig):
    r = rig(159)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))

    def moving():
        r.enable_when_fresh()
        r.spin_until(lambda: len(r.commands) >= 15 and np.max(np.abs(r.commands[-1])) > 0.04,
                     what="motion")

    # The same joint twice, the second with another value.
    moving()
    msg = JointState(name=[*JOINTS, JOINTS[0]], position=[*r.q.tolist(), 1.0])
    msg.header.stamp = r.node.get_clock().now().to_msg()
    r.states.publish(msg)
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False, what="disarm")
    r.spin(0.1, publish_states=False)
    assert not np.any(r.commands[-1])
    assert r.node.controller.zero_cause == ZeroCause.DUPLICATE_JOINTS
    assert r.node.rejected_states["duplicate_joints"] == 1
    # NaN, then a stamp 10 s old (before the last one: a restarted clock), then a zero
    # stamp: each one stops it.
    for bad, key in ((dict(position=[np.nan] * len(JOINTS)), "non_finite"),
                     (dict(stamp_age_s=10.0), "stamp_backwards"),
                     (dict(stamp_age_s=None), "zero_stamp")):
        moving()
        msg = JointState(name=JOINTS, position=bad.get("position", r.q.tolist()))
        if "stamp_age_s" not in bad:
            msg.header.stamp = r.node.get_clock().now().to_msg()
        elif bad["stamp_age_s"] is not None:
            msg.header.stamp = (r.node.get_clock().now()
                                - Duration(seconds=bad["stamp_age_s"])).to_msg()
        r.states.publish(msg)
        r.spin_until(lambda: not r.node.controller.armed, publish_states=False,
                     what=f"disarm on {key}")
        r.spin(0.1, publish_states=False)
        assert not np.any(r.commands[-1]), key
        assert r.node.controller.zero_cause == ZeroCause(key)
        assert r.node.rejected_states[key] == 1, r.node.rejected_states


def test_sim_time_drives_the_ticks_and_a_backwards_clock_disarms(rig):
    r = rig(200, use_sim_time=True)
    clock_pub = r.probe.create_publisher(Clock, "/clock", 10)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    sim_ns = 1000 * 1_000_000_000

    def advance(periods: int) -> None:
        """Step /clock by whole periods, one joint state each (stamped with sim time).

        While the executor publishes, each step waits for that period's command, so a
        slow machine delays the test instead of merging ticks.
        """
        nonlocal sim_ns
        for _ in range(periods):
            sim_ns += int(PERIOD * 1e9)
            stamp = Time(nanoseconds=sim_ns).to_msg()
            clock_pub.publish(Clock(clock=stamp))
            r.stamp = stamp
            r.spin_until(lambda t=sim_ns: r.node._now_ns() == t, publish_states=False,
                         what="the node clock to follow /clock")
            r.publish_state()
            count = len(r.commands)
            if r.node.controller.publishing:
                r.spin_until(lambda c=count: len(r.commands) > c, publish_states=False,
                             what="this period's command")
            else:
                for _ in range(3):
                    r.executor.spin_once(timeout_sec=0.002)

    advance(5)
    assert r.node._now_ns() == sim_ns  # the node clock is the simulation's
    assert r.enable(True).success
    r.commands.clear()
    advance(40)
    r.spin(0.2, publish_states=False)  # wall time passes, sim time does not: no ticks
    # One command per simulated period, and none while only wall time passed.
    assert len(r.commands) == 40
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))
    count = len(r.commands)
    sim_ns -= 5_000_000_000  # the simulation restarts: /clock jumps back 5 s
    advance(3)
    r.spin(0.1, publish_states=False)
    assert not r.node.controller.armed
    assert r.node.controller.zero_cause == ZeroCause.CLOCK_JUMPED_BACK
    assert 4.9 < r.node.controller.clock_jump_s <= 5.0  # 5 s back, one period on
    assert not np.any(r.commands[-1]) and len(r.commands) > count
    count = len(r.commands)
    advance(10)
    assert len(r.commands) == count  # stays disarmed

    # A paused simulation: wall time passes, the node clock does not. /diagnostics, on the
    # steady clock, goes on and says so.
    def paused() -> bool:
        values = {kv.key: kv.value for kv in r.diagnostics[-1].status[0].values}
        return values.get("node_clock", "advancing") != "advancing"

    r.spin_until(lambda: bool(r.diagnostics) and paused(), publish_states=False,
                 what="/diagnostics saying the clock stands still")


def test_diagnostics_report_arming_model_zero_reason_and_ramp(rig, tmp_path):
    good = _fit_model(tmp_path / "good.npz", JOINTS, np.zeros(len(JOINTS)))
    r = rig(201, model_path=str(good))

    def latest():
        status = r.diagnostics[-1].status[0]
        return status, {kv.key: kv.value for kv in status.values}

    r.spin_until(lambda: r.diagnostics, what="diagnostics")
    status, values = latest()
    assert values["armed"] == "false" and values["model"] == str(good)
    assert values["zero_cause"] == ZeroCause.NOT_ENABLED and "ramp_scale" in values
    assert values["zero_reason"] == r.node.controller.zero_reason
    r.enable_when_fresh()
    r.spin_until(lambda: latest()[1]["armed"] == "true", what="armed diagnostics")
    status, values = latest()
    assert status.level == status.OK
    assert values["zero_cause"] == "none" and values["zero_reason"] == ""
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False, what="stale")
    r.diagnostics.clear()
    r.spin_until(lambda: r.diagnostics, publish_states=False, what="diagnostics")
    status, values = latest()
    assert status.level == status.WARN and values["armed"] == "false"
    assert values["zero_cause"] == ZeroCause.STALE_STATE and values["joint_states"] != "fresh"
    assert float(values["ramp_scale"]) == 1.0


def test_every_arming_change_is_reported_at_once(rig, monkeypatch):
    # The periodic status out of reach: every status seen here is an arming change's.
    monkeypatch.setattr(executor_module, "DIAGNOSTICS_PERIOD_S", 1e6)
    r = rig(112, state_timeout_s=0.3)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))

    def armed_flags():
        return [{kv.key: kv.value for kv in a.status[0].values}["armed"]
                for a in r.diagnostics]

    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    assert r.diagnostics == []
    assert r.enable(True).success
    r.spin_until(lambda: armed_flags() == ["true"], what="the arming's status")
    # A disarm by stale states, which no service call announces.
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False,
                 what="the stale-state disarm")
    r.spin_until(lambda: len(r.diagnostics) == 2, publish_states=False,
                 what="the disarm's status")
    values = {kv.key: kv.value for kv in r.diagnostics[-1].status[0].values}
    assert values["armed"] == "false" and values["zero_cause"] == ZeroCause.STALE_STATE
    assert r.diagnostics[-1].status[0].level == r.diagnostics[-1].status[0].WARN
    # Armed again and disabled: one status per change, none while nothing changes.
    r.enable_when_fresh()
    assert r.enable(False).success
    r.enable(False)  # already disarmed: no change, so no status
    r.spin(0.2)
    assert armed_flags() == ["true", "false", "true", "false"]


def test_enable_checks_the_controllers_joint_order(rig):
    """~/enable reads the controller's ``joints`` (same single-threaded executor: no deadlock)."""
    r = rig(204, controller="/velocity_controller")
    controller = Node("velocity_controller", context=r.context)
    try:
        controller.declare_parameter("joints", JOINTS[::-1])
        r.executor.add_node(controller)
        r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
        r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                     what="fresh joint states")
        response = r.enable(True)
        assert not response.success and not r.node.controller.armed
        # The controller and the joints of the first slot that differs, both ways, and
        # the fix: the executor's joints in the controller's order, or the robot config.
        assert "/velocity_controller" in response.message
        assert "'arm_left_7_joint'" in response.message
        assert "'arm_left_1_joint'" in response.message
        assert f"-p joints:=[{','.join(JOINTS[::-1])}]" in response.message
        assert "robot_config" in response.message
        controller.set_parameters([Parameter("joints", value=[*JOINTS[:-1], "head_1_joint"])])
        response = r.enable(True)
        assert not response.success and not r.node.controller.armed
        # The joints only one side has.
        assert "['arm_left_7_joint']" in response.message
        assert "['head_1_joint']" in response.message
        # Only one side has extra joints: the other, empty, is left out.
        controller.set_parameters([Parameter("joints", value=JOINTS[:-1])])
        response = r.enable(True)
        assert not response.success and "['arm_left_7_joint']" in response.message
        assert "[]" not in response.message
        r.spin(0.1)
        assert r.commands == []  # refused: nothing was ever published
        controller.set_parameters([Parameter("joints", value=JOINTS)])
        response = r.enable(True)
        assert response.success and r.node.controller.armed, response.message
        r.spin_until(lambda: len(r.commands) >= 3, what="commands")
    finally:
        r.executor.remove_node(controller)
        controller.destroy_node()


def test_enable_without_an_answering_controller_refuses_and_names_the_fix(rig):
    r = rig(205)
    assert r.node.set_parameters([Parameter("controller", value="/velocity_controller")]
                                 )[0].successful
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    ticks = []
    r.node.create_timer(PERIOD, lambda: ticks.append(1))
    response = r.enable(True)
    assert not response.success and not r.node.controller.armed
    # The controller that did not answer, and the parameter that opts out of the check.
    assert "/velocity_controller" in response.message
    assert "-p controller:=none" in response.message
    assert ticks  # the node kept running while it waited for the controller
    r.spin(0.1)
    assert r.commands == []  # refused: nothing was ever published
    for bad in ("has space", "/trailing/", "1starts_with_digit"):
        result = r.node.set_parameters([Parameter("controller", value=bad)])[0]
        assert not result.successful and result.reason.startswith("controller")
        assert repr(bad) in result.reason
    # The explicit opt-outs: "none" (typed on the command line) and "" (a parameter file).
    for off in ("none", ""):
        assert r.node.set_parameters([Parameter("controller", value=off)])[0].successful
        assert r.node._order_client.client is None
        response = r.enable(True)
        assert response.success and r.node.controller.armed, response.message
        assert repr(off) in response.message  # the answer names the check's opt-out
        assert r.enable(False).success
    desc = r.node.describe_parameters(["controller"])[0]
    assert "joints" in desc.description and "none" in desc.description


def test_a_controller_without_a_joints_parameter_refuses_the_enable(rig):
    r = rig(212, controller="/velocity_controller")
    controller = Node("velocity_controller", context=r.context)
    try:
        r.executor.add_node(controller)
        r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
        r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                     what="fresh joint states")
        response = r.enable(True)
        assert not response.success and not r.node.controller.armed
        assert "/velocity_controller" in response.message and "joints" in response.message
        assert "-p controller:=none" in response.message
    finally:
        r.executor.remove_node(controller)
        controller.destroy_node()


def test_controller_none_parses_on_the_command_line(ros_context):
    context = ros_context(213)
    node = executor_module.Executor(
        context=context, cli_args=["--ros-args", "-p", "controller:=none"],
        parameter_overrides=[Parameter("joints", value=JOINTS)])
    try:
        assert node.get_parameter("controller").value == "none"
        assert node._order_client.client is None  # nothing to wait for at ~/enable
    finally:
        node.destroy_node()


def test_implausible_joint_states_disarm_at_once_naming_the_joint_and_value(rig):
    r = rig(214)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.commands) >= 5, what="commands")
    good = r.q.copy()
    r.q[3] = 1e6
    r.spin_until(lambda: not r.node.controller.armed, what="the disarm")
    r.spin_until(lambda: not np.any(r.commands[-1]), what="the zero command")
    assert r.node.controller.zero_cause == ZeroCause.POSITION_OUTSIDE_LIMITS
    assert "arm_left_4_joint" in r.node.controller.zero_reason
    assert r.node.rejected_states["position_outside_limits"] >= 1
    response = r.enable(True)
    assert not response.success and "arm_left_4_joint" in response.message
    assert _refusal_cause(r) == ZeroCause.POSITION_OUTSIDE_LIMITS
    # Within the margin: accepted as before (arm_left_1_joint's upper limit is 0.5236).
    r.q = good
    r.q[0] = 0.5236 + 0.05
    r.enable_when_fresh()
    r.spin(0.1)
    assert r.node.controller.armed
    # A margin set at run time applies to the next state.
    assert r.node.set_parameters([Parameter("state_limit_margin", value=0.01)]
                                 )[0].successful
    r.spin_until(lambda: not r.node.controller.armed, what="the disarm")
    assert r.node.controller.zero_cause == ZeroCause.POSITION_OUTSIDE_LIMITS
    assert "arm_left_1_joint" in r.node.controller.zero_reason


def test_start_enabled_goes_through_the_controller_check(rig, tmp_path):
    good = _fit_model(tmp_path / "good.npz", JOINTS, np.zeros(len(JOINTS)))
    r = rig(208, model_path=str(good), start_enabled=True, controller="/velocity_controller")
    controller = Node("velocity_controller", context=r.context)
    try:
        controller.declare_parameter("joints", JOINTS[::-1])
        r.executor.add_node(controller)
        calls = []
        check = r.node._check_controller

        async def counted(client):
            calls.append(await check(client))
            return calls[-1]

        r.node._check_controller = counted
        r.spin_until(lambda: calls, what="the controller check at start")
        r.spin(0.3)
        refusal, _ = calls[0]
        assert refusal and "'arm_left_7_joint'" in refusal  # slot 0 differs
        assert not r.node.controller.armed and r.commands == []
    finally:
        r.executor.remove_node(controller)
        controller.destroy_node()


def _enable_waiting_for_an_absent_controller(r: Rig):
    """An ~/enable request that is waiting (up to 1 s) for /absent_controller's answer.

    The check then reports the joint order as matching, so only what happens while it
    waits (a later request, another controller) can refuse the enable.
    """
    check = r.node._check_controller

    async def matching(client):
        await check(client)  # polls the absent controller until its timeout
        return "", ""

    r.node._check_controller = matching
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.spin_until(lambda: r.node.controller.state_problem(r.node._now_ns()) == "",
                 what="fresh joint states")
    assert r.enable_client.wait_for_service(timeout_sec=5.0)
    enable = r.enable_client.call_async(SetBool.Request(data=True))
    r.spin(0.2)
    assert not enable.done()
    return enable


def test_a_disable_while_enable_waits_for_the_controller_wins(rig):
    r = rig(210, controller="/absent_controller")
    enable = _enable_waiting_for_an_absent_controller(r)
    disable = r.enable_client.call_async(SetBool.Request(data=False))
    r.spin_until(lambda: enable.done() and disable.done(), what="both answers")
    assert disable.result().success
    assert not enable.result().success  # the check passed, but a later request came
    r.spin(0.2)
    assert not r.node.controller.armed and r.commands == []


def test_a_controller_changed_while_enable_waits_for_it_refuses_the_enable(rig):
    # Setting ``controller`` must not destroy the client that the pending enable polls:
    # the old client lives until the check ends, and the enable is refused (the new
    # controller's joint order was never compared).
    r = rig(219, controller="/absent_controller")
    enable = _enable_waiting_for_an_absent_controller(r)
    assert r.node.set_parameters([Parameter("controller", value="/other_controller")]
                                 )[0].successful
    r.spin_until(enable.done, what="the ~/enable answer")
    assert not enable.result().success  # the check passed, but for the old controller
    r.spin(0.2)
    assert not r.node.controller.armed and r.commands == []
    assert r.node._order_client.retired == []  # the old client is gone once the check ended


def test_lockstep_steps_once_per_joint_state_and_still_stops_on_stale_states(rig):
    r = rig(211, step_on_joint_state=True)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.enable_when_fresh()
    r.spin(0.05, publish_states=False)
    r.commands.clear()
    for i in range(20):
        r.publish_state()
        r.spin_until(lambda i=i: len(r.commands) >= i + 1, publish_states=False,
                     what=f"command {i + 1}")
    # While the states are fresh the timer adds no step of its own: one command per state.
    r.spin(0.2, publish_states=False)
    assert len(r.commands) == 20
    _assert_ramped(r.commands)
    assert np.max(np.abs(r.commands[-1])) > 0.0
    # States that stop coming still stop the robot at once (the timer's job in lockstep).
    r.spin_until(lambda: not r.node.controller.armed, publish_states=False,
                 what="the stale-state disarm")
    r.spin(0.05, publish_states=False)
    assert np.all(r.commands[-1] == 0.0)
