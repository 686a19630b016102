"""The executor's run-time parameters: declarations with descriptors and ranges.

The node (:mod:`policy_align_ros.nodes.executor`) validates and applies them in its
set-parameters callback (:mod:`policy_align_ros.control.settings`); ``docs/parameters.md``
is generated from these descriptors.
"""

from __future__ import annotations

from rclpy.node import Node

from policy_align_ros.control import (
    DEFAULT_DRIFT_CLAMP_M,
    DEFAULT_DRIFT_GAIN,
    DEFAULT_JOINT_LIMIT_MARGIN,
    DEFAULT_MAX_EXTRAPOLATION,
    DEFAULT_MAX_EXTRAPOLATION_RAD,
    DEFAULT_MIN_SINGULAR_VALUE,
    DEFAULT_STALL_TIME_S,
    DEFAULT_STATE_LIMIT_MARGIN,
)
from policy_align_ros.nodes._common import descriptor

__all__ = ["declare_control_parameters"]


def declare_control_parameters(node: Node, default_controller: str) -> None:
    """Declare the executor's run-time parameters on ``node``; ``default_controller`` is
    the robot config's controller name."""
    node.declare_parameter("model_path", "", descriptor(
        "model file (.npz); setting it loads the model or is refused with the reason; "
        "empty at start = wait for /learner/model (given at start, it wins over "
        "/learner/model unless follow_learner)"))
    node.declare_parameter("allow_forced_model", False, descriptor(
        "arm a model that learn refused and wrote only because it was forced (--force, "
        "the learner's force:=true; its file records the refusals); false = ~/enable is "
        "refused on such a model, naming the refusals; applies at the next ~/enable"))
    node.declare_parameter("stop_check", True, descriptor(
        "at ~/enable, run the model and its CV folds' models from the current state "
        "under the constraints in force, and warn (in the answer, the log and "
        "/diagnostics) when their stops disagree by more than 5 % of the travel; arms "
        "either way; constraints set while armed are checked so too, from where the "
        "robot stands (the log and /diagnostics); read when a check starts, and false "
        "also drops a check of new constraints still running"))
    node.declare_parameter("max_velocity", 0.5, descriptor(
        "speed limit of every joint [rad/s] (the URDF limit applies when lower)",
        float_range=(0.001, 10.0)))
    node.declare_parameter("max_acceleration", 2.0, descriptor(
        "largest change of a joint's command per second [rad/s^2], also when ramping "
        "down after a disable or a model swap", float_range=(0.01, 100.0)))
    node.declare_parameter("state_timeout_s", 0.1, descriptor(
        "joint states received longer ago than this, or stamped longer ago than this "
        "plus max_clock_skew_s, stop and disarm [s]",
        float_range=(0.001, 10.0)))
    node.declare_parameter("max_clock_skew_s", 0.05, descriptor(
        "allowed offset between joint-state stamps and the node clock [s]",
        float_range=(0.0, 10.0)))
    node.declare_parameter("state_limit_margin", DEFAULT_STATE_LIMIT_MARGIN, descriptor(
        "a joint state with a position outside its URDF limits by more than this is "
        "refused and disarms [rad]", float_range=(0.0, 10.0)))
    node.declare_parameter("max_extrapolation", DEFAULT_MAX_EXTRAPOLATION, descriptor(
        "extrapolation guard: beyond this distance from the demonstrated data "
        "[spacings of the training data] commands leading further out scale down, to "
        "zero one band (>= the stopping distance at max_velocity) further",
        float_range=(0.1, 1000.0)))
    node.declare_parameter("max_extrapolation_rad", DEFAULT_MAX_EXTRAPOLATION_RAD,
                           descriptor(
        "extrapolation guard: the robot stops within this joint-space distance of the "
        "demonstrated data, whatever max_extrapolation says [rad, 2-norm]",
        float_range=(0.01, 100.0)))
    node.declare_parameter("joint_limit_margin", DEFAULT_JOINT_LIMIT_MARGIN, descriptor(
        "joints brake to rest this far inside their URDF limits; a joint already "
        "within it may only move inwards [rad]", float_range=(0.0, 0.5)))
    node.declare_parameter("drift_gain", DEFAULT_DRIFT_GAIN, descriptor(
        "gain pulling frames held by position constraints back to where they were at "
        "enable [1/s]; 0 = no drift correction", float_range=(0.0, 50.0)))
    node.declare_parameter("drift_clamp_m", DEFAULT_DRIFT_CLAMP_M, descriptor(
        "largest held-frame error the drift correction acts on [m] (larger errors are "
        "corrected at drift_gain * drift_clamp_m m/s)", float_range=(0.0001, 1.0)))
    node.declare_parameter("min_singular_value", DEFAULT_MIN_SINGULAR_VALUE, descriptor(
        "the executor ramps to a stop when the constraint matrix's smallest singular "
        "value falls below this [m/rad for frame rows]; 0 = never",
        float_range=(0.0, 1.0)))
    node.declare_parameter("stall_time_s", DEFAULT_STALL_TIME_S, descriptor(
        "a joint commanded at >= 0.05 rad/s that moves by less than a quarter of that "
        "for this long ramps down and disarms [s]; 0 = off, else >= 0.1",
        float_range=(0.0, 10.0)))
    node.declare_parameter("follow_learner", False, descriptor(
        "load the models announced on /learner/model; they are followed anyway when no "
        "model_path was given at start (else the model_path given wins)",
        read_only=True))
    node.declare_parameter("constraints", "[]", descriptor(
        "YAML list of constraint specs in force, e.g. "
        "[{type: plane, frame: arm_left_7_link, normal: [0, 0, 1]}]"))
    node.declare_parameter("controller", default_controller, descriptor(
        "node name of the ros2_control controller whose joints parameter gives the "
        "command order; ~/enable reads it and refuses a different order or one it cannot "
        "read; none = arm without the check; unset = robot_config's. The commands go to "
        "/velocity_controller/commands: remap that topic to another controller's"))
    node.declare_parameter("start_enabled", False, descriptor(
        "arm at the first fresh joint state when model_path loaded at start (else "
        "wait for ~/enable)", read_only=True))
    node.declare_parameter("step_on_joint_state", False, descriptor(
        "one control step per new joint state instead of the rate_hz timer (lockstep "
        "with a simulator publishing at rate_hz); the timer then only stops the robot "
        "when joint states go stale", read_only=True))
