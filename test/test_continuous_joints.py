"""Continuous joints end to end, without ROS: demonstrations of Kinova's Jaco whose
continuous joints a driver reports in [-pi, pi), and which cross it, are written as bags,
learnt by ``learn_pipeline`` and run by the executor's controller (loaded as the executor
loads a model file) on a simulated arm that reports its joints the same way.
"""

import numpy as np

from policy_align_ros.control import (
    DEFAULT_MAX_EXTRAPOLATION,
    DEFAULT_MAX_EXTRAPOLATION_RAD,
    build_controller,
    install_model,
    load_policy,
    wrap_continuous,
)
from policy_align_ros.data import learn_pipeline
from policy_align_ros.data.bags.write import write_joint_state_bag
from policy_align_ros.kinematics import Robot
from policy_align_ros.kinematics.robot import robots_dir

URDF = str(robots_dir() / "kinova_description" / "robots" / "kinova.urdf")
#: Joints 1 and 4 are continuous; the goal puts them near +pi and -pi.
JOINTS = ["j2s6s200_joint_1", "j2s6s200_joint_2", "j2s6s200_joint_4"]
GOAL = np.array([3.0, 2.0, -3.0])
DT = 0.02
SETTINGS = {"rate_hz": 1.0 / DT, "max_velocity": 1.0, "max_acceleration": 2.0,
            "state_timeout_s": 0.2, "max_clock_skew_s": 0.04, "state_limit_margin": 0.1,
            "drift_gain": 0.0, "drift_clamp_m": 0.01, "min_singular_value": 0.01,
            "joint_limit_margin": 0.05, "stall_time_s": 0.5, "allow_forced_model": False}


def _record(directory, continuous, rng, count=8, steps=150):
    """The expert ``qdot = -(q - GOAL)`` from starts on both sides of the wrap, as a
    driver reports it: each bag's continuous joints wrapped to [-pi, pi)."""
    for k in range(count):
        q = GOAL + rng.uniform(-0.8, 0.8, GOAL.size)
        Q = [q]
        for _ in range(steps - 1):
            Q.append(Q[-1] - DT * (Q[-1] - GOAL))
        stamps = 10**18 + np.arange(steps) * round(DT * 1e9)
        write_joint_state_bag(directory / f"demo_{k:04d}", JOINTS, stamps,
                              wrap_continuous(np.array(Q), continuous))


def test_demonstrations_across_the_wrap_are_learnt_and_run_across_it(tmp_path):
    robot = Robot.load(URDF, JOINTS)
    assert list(robot.continuous) == [True, False, True]
    _record(tmp_path / "demos", robot.continuous, np.random.default_rng(6))
    result = learn_pipeline([tmp_path / "demos"], tmp_path / "m.npz", robot=URDF,
                            joints=JOINTS, holdout_fraction=0.0)
    assert result.written and result.summary["continuous_joints"] == JOINTS[::2]

    control = build_controller(robot, SETTINGS.__getitem__, [])
    model, policy, permutation, state = load_policy(str(tmp_path / "m.npz"), robot)
    install_model(control, robot, str(tmp_path / "m.npz"), model, policy, permutation, state,
                  max_extrapolation=DEFAULT_MAX_EXTRAPOLATION,
                  max_extrapolation_rad=DEFAULT_MAX_EXTRAPOLATION_RAD)
    # A new start across the wrap from the goal on both continuous joints: 3.6 rad is
    # reported as -2.68 rad, -3.6 rad as 2.68 rad.
    q = GOAL + np.array([0.6, 0.3, -0.6])
    now = 10**9
    control.joint_state(wrap_continuous(q, robot.continuous), now, now)
    assert control.arm(now)[0]
    for _ in range(round(10.0 / DT)):
        now += round(DT * 1e9)
        control.joint_state(wrap_continuous(q, robot.continuous), now, now)
        out = control.tick(now)
        if out.command is not None:
            q = q + DT * out.command
    # The short way to the goal, never taken for a stall (the controller stays armed).
    assert control.armed, control.zero_reason
    assert np.max(np.abs(wrap_continuous(q - GOAL, robot.continuous))) < 0.02
    assert np.max(np.abs(q - GOAL)) < 0.02  # on the goal's own turn, not a turn away
