"""The executor's parameter values on its controller (policy_align_ros.control.settings).
ROS-free."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from policy_align_ros.control import (
    FLOAT_SETTINGS,
    ExtrapolationGuard,
    apply_setting,
    build_controller,
    constraints_from_text,
    constraints_problem,
    setting_problem,
)
from policy_align_ros.kinematics import Robot

JOINTS = ["panda_joint1", "panda_joint2", "panda_joint4"]

#: Parameter values as the executor declares them (rate_hz 50: a 20 ms period).
VALUES = {"rate_hz": 50.0, "max_velocity": 0.3, "max_acceleration": 1.5,
          "state_timeout_s": 0.2, "max_clock_skew_s": 0.04, "state_limit_margin": 0.1,
          "drift_gain": 2.0, "drift_clamp_m": 0.02, "min_singular_value": 0.01,
          "joint_limit_margin": 0.03, "stall_time_s": 0.5, "allow_forced_model": True}


@pytest.fixture(scope="module")
def robot():
    return Robot.load("panda", JOINTS)


@pytest.mark.parametrize("name, value, refused", [
    ("joints", ["a", "b"], False),
    ("joints", ["a", "a"], True),  # a joint twice
    ("joints", None, True),  # ``joints:=[]`` arrives unset
    ("joints", [], True),
    ("max_velocity", 0.5, False),
    ("max_velocity", math.nan, True),  # a NaN passes rclpy's range check
    ("state_timeout_s", math.inf, True),
    ("stall_time_s", 0.0, False),  # off
    ("stall_time_s", 0.05, True),  # too short to tell a stall from the tracking lag
    ("stall_time_s", 0.5, False),
    ("constraints", "not checked here", False),
    ("model_path", "", False),
])
def test_values_refused_beyond_their_range_name_the_parameter(name, value, refused):
    problem = setting_problem(name, value)
    assert bool(problem) is refused
    if refused:
        assert problem.startswith(name)


def test_every_float_setting_is_refused_when_not_finite():
    for name in FLOAT_SETTINGS:
        assert setting_problem(name, math.nan), name


def test_the_controller_is_built_from_the_parameter_values(robot):
    control = build_controller(robot, VALUES.__getitem__, [])
    step = control.step
    assert step.dt == pytest.approx(1.0 / VALUES["rate_hz"])
    # max_velocity capped by the URDF's limits, per joint.
    np.testing.assert_allclose(step.max_velocity,
                               np.minimum(robot.velocity_limit, VALUES["max_velocity"]))
    assert control.max_acceleration == VALUES["max_acceleration"]
    assert control.state_timeout_s == VALUES["state_timeout_s"]
    assert control.max_clock_skew_s == VALUES["max_clock_skew_s"]
    assert control.state_limit_margin == VALUES["state_limit_margin"]
    for name in ("drift_gain", "drift_clamp_m", "min_singular_value", "joint_limit_margin"):
        assert getattr(step, name) == VALUES[name], name
    assert control.stall.stall_time_s == VALUES["stall_time_s"]
    # The stall detector follows the robot's continuous joints across the wrap (none here).
    np.testing.assert_array_equal(control.stall.continuous, robot.continuous)
    assert step.allow_forced_model is True
    assert control.joint_names == JOINTS and not control.armed


def test_run_time_values_reach_the_controller_and_the_rest_is_left_to_the_node(robot):
    control = build_controller(robot, VALUES.__getitem__, [])
    limit = robot.velocity_limit
    assert apply_setting(control, "max_velocity", 0.1, limit)
    np.testing.assert_allclose(control.step.max_velocity, np.minimum(limit, 0.1))
    for name, value in (("max_acceleration", 3.0), ("state_timeout_s", 0.5),
                        ("max_clock_skew_s", 0.2), ("state_limit_margin", 0.3)):
        assert apply_setting(control, name, value, limit)
        assert getattr(control, name) == value, name
    for name, value in (("drift_gain", 1.0), ("drift_clamp_m", 0.05),
                        ("min_singular_value", 0.02), ("joint_limit_margin", 0.04),
                        ("allow_forced_model", False)):
        assert apply_setting(control, name, value, limit)
        assert getattr(control.step, name) == value, name
    assert apply_setting(control, "stall_time_s", 0.0, limit)
    assert control.stall.stall_time_s == 0.0
    # Without a model there is no guard: accepted, read by the next model's guard.
    assert control.step.guard is None
    assert apply_setting(control, "max_extrapolation", 3.0, limit)
    control.step.guard = ExtrapolationGuard(lambda q: (0.0, np.zeros(len(q))), 6.0)
    assert apply_setting(control, "max_extrapolation", 3.0, limit)
    assert apply_setting(control, "max_extrapolation_rad", 0.4, limit)
    assert control.step.guard.max_extrapolation == 3.0
    assert control.step.guard.max_extrapolation_rad == 0.4
    for name in ("constraints", "model_path", "controller"):
        assert not apply_setting(control, name, "x", limit), name


def test_constraint_specs_are_built_on_the_robot_or_refused_with_the_reason(robot):
    frame = robot.model.frames[-1].name
    text = f"[{{type: plane, frame: {frame}, normal: [0, 0, 1]}}]"
    assert len(constraints_from_text(text, robot)) == 1
    assert constraints_from_text("[]", robot) == []
    assert constraints_problem(text, robot) == ""
    assert "no_such_frame" in constraints_problem(
        "[{type: plane, frame: no_such_frame, normal: [0, 0, 1]}]", robot)
    assert constraints_problem("[{type: plane", robot)  # not YAML


def test_a_constraint_that_fails_unexpectedly_is_refused_not_raised():
    # A robot whose kinematics raise something other than ValueError (here, no frame
    # lookup at all): still a refusal, naming the parameter and the exception.
    broken = SimpleNamespace(nq=2)
    problem = constraints_problem("[{type: plane, frame: f, normal: [0, 0, 1]}]", broken)
    assert problem.startswith("constraints") and "AttributeError" in problem
