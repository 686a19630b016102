"""The executor's parameter values on its controller, ROS-free.

The node declares the parameters with their ranges (``nodes/executor_parameters.py``,
which rclpy enforces) and reads their values; here a value is checked beyond its range
(:func:`setting_problem`, :func:`constraints_problem`), the armed controller is built
from the values at start (:func:`build_controller`) and a value changed at run time is
applied to it (:func:`apply_setting`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from policy_align_ros.control.armed import ArmedController
from policy_align_ros.control.limits import speed_limits
from policy_align_ros.control.stall import StallDetector, stall_time_problem
from policy_align_ros.control.step import ControlStep
from policy_align_ros.kinematics.constraints import (
    ConstraintModel,
    constraint_from_spec,
    parse_constraint_specs,
)
from policy_align_ros.kinematics.robot import Robot

__all__ = ["FLOAT_SETTINGS", "apply_setting", "build_controller", "constraints_from_text",
           "constraints_problem", "setting_problem"]

#: Float parameters that must be finite (rclpy checks their ranges, which a NaN passes).
FLOAT_SETTINGS = ("max_velocity", "max_acceleration", "state_timeout_s",
                  "max_clock_skew_s", "max_extrapolation", "drift_gain", "drift_clamp_m",
                  "min_singular_value", "state_limit_margin", "joint_limit_margin",
                  "max_extrapolation_rad", "stall_time_s")

#: Run-time parameters that are attributes of the same name of the controller, of its
#: control step and of its extrapolation guard (when the model has one).
_ON_CONTROLLER = ("max_acceleration", "state_timeout_s", "max_clock_skew_s",
                  "state_limit_margin")
_ON_STEP = ("drift_gain", "drift_clamp_m", "min_singular_value", "joint_limit_margin",
            "allow_forced_model")
_ON_GUARD = ("max_extrapolation", "max_extrapolation_rad")


def setting_problem(name: str, value: Any) -> str:
    """Why ``value`` is refused for the executor's parameter ``name`` beyond the range of
    its descriptor; "" when it is accepted (or is not checked here: the constraints, the
    model and the controller need the node's robot and graph)."""
    if name == "joints":
        # ``joints:=[]`` on the command line arrives unset (None), not as a list.
        if not value or len(set(value)) != len(value):
            return "joints: must be a non-empty list without repeats"
    elif name in FLOAT_SETTINGS:
        if not math.isfinite(value):
            return f"{name}: must be finite, got {value}"
        if name == "stall_time_s":
            return stall_time_problem(value)
    return ""


def constraints_from_text(text: str, robot: Robot) -> list[ConstraintModel]:
    """The constraints of the ``constraints`` parameter (a YAML list of specs) on
    ``robot``; ValueError naming what is wrong with a spec."""
    return [constraint_from_spec(spec, robot) for spec in parse_constraint_specs(text)]


def constraints_problem(text: str, robot: Robot) -> str:
    """Why the ``constraints`` parameter ``text`` is refused on ``robot``; "" when every
    spec makes a constraint (:func:`constraints_from_text`)."""
    try:
        constraints_from_text(text, robot)
    except Exception as err:  # noqa: BLE001 - a refusal, never a dead executor
        # The specs are checked to raise ValueError; anything else that slips through must
        # still refuse the change rather than kill the node while the controller holds its
        # last command.
        return (str(err) if isinstance(err, ValueError)
                else f"constraints: {type(err).__name__}: {err}")
    return ""


def build_controller(robot: Robot, value: Callable[[str], Any],
                     constraints: Sequence[ConstraintModel]) -> ArmedController:
    """The armed controller of ``robot`` (joints in command order) from the parameter
    values ``value(name)``, with ``constraints`` in force; its control period
    (``step.dt``, s) is ``1 / rate_hz``."""
    joints = list(robot.joint_names)
    step = ControlStep(
        robot.lower, robot.upper, speed_limits(robot.velocity_limit, value("max_velocity")),
        1.0 / value("rate_hz"), constraints=constraints,
        drift_gain=value("drift_gain"), drift_clamp_m=value("drift_clamp_m"),
        min_singular_value=value("min_singular_value"),
        joint_limit_margin=value("joint_limit_margin"))
    step.allow_forced_model = bool(value("allow_forced_model"))
    return ArmedController(
        step, value("max_acceleration"), value("state_timeout_s"),
        value("max_clock_skew_s"), joint_names=joints,
        state_limit_margin=value("state_limit_margin"),
        stall=StallDetector(len(joints), value("stall_time_s"), joint_names=joints,
                            continuous=robot.continuous))


def apply_setting(controller: ArmedController, name: str, value: Any,
                  velocity_limit: np.ndarray) -> bool:
    """Apply the new ``value`` of the run-time parameter ``name`` to ``controller``.

    Parameters
    ----------
    controller : ArmedController
        Built by :func:`build_controller`.
    name : str
        The parameter set.
    value
        Its new value (checked: its range and :func:`setting_problem`).
    velocity_limit : ndarray, shape (n,)
        The robot's URDF speed limits (rad/s), which ``max_velocity`` is capped by.

    Returns
    -------
    bool
        Whether ``name`` is a setting of the controller (applied, or kept for the next
        model when it is the guard's and the model has none); False for the parameters
        the node applies itself (constraints, model, controller name).
    """
    step = controller.step
    if name == "max_velocity":
        step.max_velocity = speed_limits(velocity_limit, value)
    elif name == "stall_time_s":
        controller.stall.stall_time_s = value
    elif name in _ON_CONTROLLER:
        setattr(controller, name, value)
    elif name in _ON_STEP:
        # allow_forced_model applies at the next ~/enable: it never disarms by itself.
        setattr(step, name, value)
    elif name in _ON_GUARD:
        # A new model's guard reads the parameter when it is made (model_guard).
        if step.guard is not None:
            setattr(step.guard, name, value)
    else:
        return False
    return True
