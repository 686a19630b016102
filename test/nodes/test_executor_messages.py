"""The ``executor`` node: stall detection, model precedence and the messages about joint
states that cannot be used (sim-time stamps, a frozen stamp, controlled joints missing)
(own rclpy.Context, domain ids 224, 225, 119, 121 and 124).

Assertions count control ticks and messages, never wall-clock speed: waits are "until a
condition holds, or fail after a generous timeout". The logic itself is tested without a
graph in test/control/test_stall.py and test/control/test_stamp_messages.py.
"""

import numpy as np
from executor_rig import JOINTS, PERIOD, _assert_ramped, _attractor_policy, _fit_model
from rclpy.parameter import Parameter
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import SetBool

from policy_align_ros.control import ZeroCause
from policy_align_ros.control.stall import STALL_MIN_SPEED
from policy_align_ros.nodes.executor import Executor


def test_a_robot_that_does_not_move_stalls_ramps_down_and_reports_an_error(rig):
    stall_s = 0.3
    r = rig(224)  # the rig's robot never moves; no stall detection in the rig by default
    result = r.node.set_parameters([Parameter("stall_time_s", value=0.05)])[0]
    assert not result.successful and "stall_time_s" in result.reason  # shorter than a lag
    assert r.node.set_parameters([Parameter("stall_time_s", value=stall_s)])[0].successful
    assert r.node.controller.stall.stall_time_s == stall_s
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.enable_when_fresh()
    r.spin_until(lambda: not r.node.controller.armed, what="the stall's disarm")
    r.spin_until(lambda: not r.node.controller.publishing, what="the ramp down")
    r.spin(0.1)
    control = r.node.controller
    assert control.stalled and control.zero_cause == ZeroCause.STALL
    assert control.last_stall.joints and set(control.last_stall.joints) <= set(JOINTS)
    # Ramped down within max_acceleration to zero (not cut: q is trusted), then silence.
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))
    assert not np.any(r.commands[-1])
    # Within stall_time_s of the command exceeding the floor: one command per tick, so
    # the ticks between the first command above it and the first smaller one are counted.
    # A loaded machine delays ticks and the timer then catches up in a burst, so a few
    # more ticks than stall_time_s holds may fall in that time; twice as many may not.
    sizes = [float(np.abs(c).max()) for c in r.commands]
    above = next(i for i, s in enumerate(sizes) if s >= STALL_MIN_SPEED)
    down = next(i for i in range(1, len(sizes)) if sizes[i] < sizes[i - 1] - 1e-12)
    assert (down - above) * PERIOD <= 2 * stall_s
    statuses = [a.status[0] for a in r.diagnostics]
    stalled = [s for s in statuses
               if {kv.key: kv.value for kv in s.values}.get("stalled") == "true"]
    assert stalled and all(s.level == s.ERROR for s in stalled)
    assert {kv.key: kv.value for kv in stalled[-1].values}["zero_cause"] == ZeroCause.STALL
    # Stays disarmed until enabled again.
    count = len(r.commands)
    r.spin(0.2)
    assert len(r.commands) == count and not control.armed


def test_a_model_path_given_at_start_wins_over_the_learner_topic(rig, tmp_path):
    a = _fit_model(tmp_path / "a.npz", JOINTS, np.zeros(len(JOINTS)))
    b = _fit_model(tmp_path / "b.npz", JOINTS, np.full(len(JOINTS), 0.1))
    r = rig(225, model_path=str(a))
    # A second executor on the same graph that follows the learner: when it has loaded
    # the announcement, the first one has received it too.
    follower = Executor(context=r.context, namespace="follower", parameter_overrides=[
        Parameter("joints", value=JOINTS), Parameter("controller", value=""),
        Parameter("model_path", value=str(a)), Parameter("follow_learner", value=True)])
    try:
        r.executor.add_node(follower)
        r.models.publish(String(data=str(b)))
        r.spin_until(lambda: follower.model_path == str(b), what="the follower's switch")
        r.spin(0.2)
        assert r.node.model_path == str(a)
        assert r.node.get_parameter("model_path").value == str(a)
        assert follower.get_parameter("model_path").value == str(b)
        desc = r.node.describe_parameters(["follow_learner"])[0]
        assert desc.read_only and "model_path" in desc.description
    finally:
        r.executor.remove_node(follower)
        follower.destroy_node()


def test_sim_time_stamps_are_named_in_the_enable_refusal_and_the_warning(rig, capfd):
    r = rig(119)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.stamp = Time(seconds=100).to_msg()  # a simulation 100 s in; the node: system clock
    r.spin_until(lambda: r.node.rejected_states["stamp_too_old"] >= 3,
                 what="rejected states")
    response = r.enable(True)
    assert not response.success and not r.node.controller.armed
    assert r.node.controller.arm_check(r.node._now_ns())[0] == ZeroCause.STAMP_TOO_OLD
    assert "-p use_sim_time:=true" in response.message  # the parameter that fixes it
    err = capfd.readouterr().err  # the warning (at most every 2 s) names it too
    assert "stamp_too_old" in err and "use_sim_time:=true" in err
    assert r.commands == []


def test_a_frozen_stamp_is_named_while_messages_keep_arriving(rig):
    r = rig(121)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.commands) >= 5, what="commands")
    r.stamp = r.node.get_clock().now().to_msg()  # messages go on, their stamp stops
    r.spin_until(lambda: not r.node.controller.armed, what="the stale-state disarm")
    r.spin(0.05)
    assert not np.any(r.commands[-1])
    assert r.node.controller.zero_cause == ZeroCause.FROZEN_STAMP
    assert not r.enable(True).success
    assert r.node.controller.arm_check(r.node._now_ns())[0] == ZeroCause.FROZEN_STAMP
    # Joint states that stop altogether still read as such.
    r.spin(0.7, publish_states=False)
    assert r.node.controller.state_check(r.node._now_ns())[0] == ZeroCause.STALE_STATE


def test_joint_states_lacking_a_controlled_joint_are_named_by_the_refusal(rig):
    r = rig(124)
    r.node.controller.set_policy(_attractor_policy(r.node.robot.neutral()))

    def feed(names, key):
        """Publish messages of ``names`` until three were counted as ``key``."""
        count = r.node.rejected_states[key] + 3

        def publish():
            msg = JointState(name=list(names), position=[0.1] * len(names))
            msg.header.stamp = r.node.get_clock().now().to_msg()
            r.states.publish(msg)
            return r.node.rejected_states[key] >= count

        r.spin_until(publish, publish_states=False, what=f"{key} messages")

    def values():
        return {kv.key: kv.value for kv in r.diagnostics[-1].status[0].values}

    def enable():
        """~/enable true, without the rig's (complete) joint states meanwhile."""
        assert r.enable_client.wait_for_service(timeout_sec=5.0)
        future = r.enable_client.call_async(SetBool.Request(data=True))
        r.spin_until(future.done, publish_states=False, what="the ~/enable answer")
        return future.result()

    # The robot publishes six of the seven joints: the enable refusal and /diagnostics
    # name the missing one, what the messages carry and the topic.
    feed(JOINTS[:-1], "missing_joints")
    response = enable()
    assert not response.success and not r.node.controller.armed
    assert r.node.controller.arm_check(r.node._now_ns())[0] == ZeroCause.NO_STATE
    assert "'arm_left_7_joint'" in response.message and "'arm_left_1_joint'" in response.message
    assert "/joint_states" in response.message
    assert "-p joints:=" in response.message and "robot_config" in response.message  # fixes
    r.diagnostics.clear()
    r.spin_until(lambda: r.diagnostics, publish_states=False, what="diagnostics")
    assert "'arm_left_7_joint'" in values()["joint_states"]
    assert "missing_joints=" in values()["rejected_joint_states"]
    # Messages of other joints only: the controlled joints they should carry are named.
    feed(["gripper_left", "gripper_right"], "unknown_joints")
    response = enable()
    assert not response.success
    assert "'gripper_left'" in response.message and "'arm_left_1_joint'" in response.message
    # Armed on full states, then only six joints arrive: the stale-state disarm's
    # zero_reason names the missing joint as well.
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.commands) >= 3, what="commands")
    feed(JOINTS[:-1], "missing_joints")
    r.spin_until(lambda: (feed(JOINTS[:-1], "missing_joints"),
                          not r.node.controller.armed)[1],
                 publish_states=False, what="the stale-state disarm")
    control = r.node.controller
    assert control.zero_cause == ZeroCause.STALE_STATE
    assert "'arm_left_7_joint'" in control.zero_reason
    assert "state_timeout_s" in control.zero_reason
