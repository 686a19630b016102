"""``executor``: drive a robot with a learnt policy under the configured constraints.

At ``rate_hz`` it publishes ``qdot = s N(q) pi_hat(q)`` (rad/s, order = ``joints``) on
``/velocity_controller/commands`` (std_msgs/Float64MultiArray), from the latest
``/joint_states`` (sensor_msgs/JointState, matched by name). ``N(q)`` comes from the
``constraints`` parameter (a YAML list of constraint specs, see
``policy_align_ros.kinematics.constraint_from_spec``) and ``s`` keeps every joint under
``max_velocity`` (rad/s) and inside its limits (:mod:`policy_align_ros.kinematics.control`).

A ros2_control JointGroupVelocityController holds its last command forever, so the
executor publishes zeros when disabled (``~/enable``, std_srvs/SetBool), while joint states
are older than ``state_timeout_s``, while no model is loaded, and when it shuts down. The
model is loaded from ``model_path`` at start and again whenever ``/learner/model``
(std_msgs/String, transient local) announces a file; a model trained on other joints is
refused.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool

from policy_align_ros.kinematics import Robot, constraint_from_spec
from policy_align_ros.kinematics.control import ControlStep, model_permutation
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.nodes._common import (
    DEFAULT_JOINTS,
    LATCHED_QOS,
    accept,
    descriptor,
    joint_positions,
    parse_constraint_specs,
    reject,
    run_node,
)

__all__ = ["Executor", "load_policy", "main", "speed_limits"]


def load_policy(path: str, joints: Sequence[str]) -> tuple[PolicyAlign, np.ndarray]:
    """Load a PolicyAlign model file and check it was trained on ``joints``.

    Returns
    -------
    (model, permutation)
        The model and the index array mapping controller order to model order.

    Raises
    ------
    ValueError, FileNotFoundError, OSError
        For a missing or unreadable file, or a model trained on other joints.
    """
    model = PolicyAlign.load(path)
    if model.joint_names_ is None and model.n_features_in_ != len(joints):
        raise ValueError(f"model {path}: has {model.n_features_in_} state dimensions, the "
                         f"executor {len(joints)} joints")
    return model, model_permutation(model.joint_names_, joints)


def speed_limits(urdf_limits: np.ndarray, max_velocity: float) -> np.ndarray:
    """Per-joint speed limits (n,) in rad/s: ``max_velocity`` or the URDF's when lower.

    URDFs often give 0 for "no limit", so non-positive URDF entries are ignored.
    """
    urdf = np.where(urdf_limits > 0.0, urdf_limits, np.inf)
    return np.minimum(urdf, float(max_velocity))


class Executor(Node):
    """The ``executor`` node (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__("executor", **kwargs)
        self.robot: Robot | None = None
        self.control: ControlStep | None = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        self.declare_parameter("robot", "talos", descriptor(
            "example-robot-data name or URDF path of the controlled robot", read_only=True))
        self.declare_parameter("joints", DEFAULT_JOINTS, descriptor(
            "controlled joints, in command order", read_only=True))
        self.declare_parameter("rate_hz", 100.0, descriptor(
            "control rate [Hz]", read_only=True, float_range=(1.0, 1000.0)))
        joints = list(self.get_parameter("joints").value)
        self.robot = Robot.load(self.get_parameter("robot").value, joints)
        self.declare_parameter("model_path", "", descriptor(
            "model file (.npz) loaded at start; empty = wait for /learner/model"))
        self.declare_parameter("max_velocity", 0.5, descriptor(
            "speed limit of every joint [rad/s] (the URDF limit applies when lower)",
            float_range=(0.001, 10.0)))
        self.declare_parameter("state_timeout_s", 0.1, descriptor(
            "joint states older than this give zero commands [s]", float_range=(0.001, 10.0)))
        self.declare_parameter("constraints", "[]", descriptor(
            "YAML list of constraint specs in force, e.g. "
            "[{type: plane, frame: arm_left_7_link, normal: [0, 0, 1]}]"))
        self.declare_parameter("start_enabled", False, descriptor(
            "publish policy commands from the start (else wait for ~/enable)",
            read_only=True))

        self._index = {name: i for i, name in enumerate(joints)}
        self._period = 1.0 / self.get_parameter("rate_hz").value
        self.control = ControlStep(
            self.robot.lower, self.robot.upper, self._speed_limits(), self._period,
            constraints=self._constraints(self.get_parameter("constraints").value))
        self.enabled = bool(self.get_parameter("start_enabled").value)
        self.model_path = ""
        self._q: np.ndarray | None = None
        self._q_time = -np.inf
        self._zero_reason = ""

        self._pub = self.create_publisher(Float64MultiArray, "/velocity_controller/commands", 10)
        self.create_subscription(JointState, "/joint_states", self._on_joint_state, 10)
        self.create_subscription(String, "/learner/model", self._on_model, LATCHED_QOS)
        self.create_service(SetBool, "~/enable", self._on_enable)
        self.create_timer(self._period, self._on_timer)
        path = self.get_parameter("model_path").value
        if path:
            self._load(path)

    # -- parameters -------------------------------------------------------------------
    def _speed_limits(self) -> np.ndarray:
        return speed_limits(self.robot.velocity_limit, self.get_parameter("max_velocity").value)

    def _constraints(self, text: str) -> list:
        return [constraint_from_spec(spec, self.robot) for spec in parse_constraint_specs(text)]

    def _on_set_parameters(self, params: Sequence[Parameter]):
        """Validate only; :meth:`_after_set_parameters` applies accepted values."""
        for param in params:
            if param.name == "joints":
                if len(set(param.value)) != len(param.value) or not param.value:
                    return reject("joints: must be a non-empty list without repeats")
            elif param.name == "constraints" and self.robot is not None:
                try:
                    self._constraints(param.value)
                except ValueError as err:
                    return reject(str(err))
        return accept()

    def _after_set_parameters(self, params: Sequence[Parameter]) -> None:
        if self.control is None:
            return  # still declaring: __init__ builds the controller from the values
        for param in params:
            if param.name == "constraints":
                self.control.constraints = self._constraints(param.value)
                self.get_logger().info(f"constraints now {param.value}")
            elif param.name == "max_velocity":
                self.control.max_velocity = self._speed_limits()

    # -- model ------------------------------------------------------------------------
    def _load(self, path: str) -> bool:
        try:
            model, perm = load_policy(path, self.robot.joint_names)
        except (ValueError, OSError) as err:
            self.get_logger().error(f"model not loaded: {err}")
            return False
        self.control.policy = model.policy
        self.control.permutation = perm
        self.model_path = path
        self.get_logger().info(f"model loaded from {path}")
        return True

    def _on_model(self, msg: String) -> None:
        self._load(msg.data)

    # -- inputs -----------------------------------------------------------------------
    def _on_joint_state(self, msg: JointState) -> None:
        q = joint_positions(msg, self._index)
        if q is None:
            self.get_logger().warning(
                "joint state without all configured joints or with NaN: ignored",
                throttle_duration_sec=2.0)
            return
        self._q = q
        self._q_time = time.monotonic()

    def _on_enable(self, request: SetBool.Request, response: SetBool.Response):
        was = self.enabled
        self.enabled = bool(request.data)
        if was and not self.enabled:
            self.publish_zeros("disabled")
        response.success = True
        model = f"model {self.model_path}" if self.control.policy else "no model loaded yet"
        response.message = f"{'enabled' if self.enabled else 'disabled'} ({model})"
        return response

    # -- output -----------------------------------------------------------------------
    def command(self) -> tuple[np.ndarray, str]:
        """The command to publish now and, when it is zero for safety, the reason."""
        n = len(self._index)
        if not self.enabled:
            return np.zeros(n), "disabled"
        if self._q is None or time.monotonic() - self._q_time > self.get_parameter(
                "state_timeout_s").value:
            return np.zeros(n), "joint states stale"
        return self.control(self._q)

    def _on_timer(self) -> None:
        if not self.enabled:
            # Disabled: the topic belongs to someone else (the zeros went out on disable).
            return
        qdot, reason = self.command()
        if reason and reason != self._zero_reason:
            self.get_logger().warning(f"publishing zeros: {reason}")
        self._zero_reason = reason
        self._pub.publish(Float64MultiArray(data=qdot.tolist()))

    def publish_zeros(self, why: str) -> None:
        """Publish one zero command and wait briefly for subscribers to acknowledge it."""
        self._pub.publish(Float64MultiArray(data=[0.0] * len(self._index)))
        self._pub.wait_for_all_acked(Duration(seconds=0.2))
        self.get_logger().info(f"published zero command ({why})")

    def destroy_node(self) -> None:
        """Stop the robot (zero command) before the node goes away."""
        if self.context.ok() and hasattr(self, "_pub"):
            self.publish_zeros("shutdown")
        super().destroy_node()


def main(args: Sequence[str] | None = None) -> int:
    """Console script ``executor``."""
    return run_node(Executor, args, keep_context_on_signal=True)


if __name__ == "__main__":
    raise SystemExit(main())
