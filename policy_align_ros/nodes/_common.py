"""Helpers shared by the policy_align_ros nodes: parameters, message conversion, main().

Units: joint positions in rad (m for prismatic joints), velocities in rad/s, times in s.
Only this subpackage, ``client/`` and ``cli.py`` may import rclpy and ROS message types.
"""

from __future__ import annotations

import faulthandler
import os
import signal
import sys
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import rclpy
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.client import Client
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterException,
    ParameterUninitializedException,
)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Float64MultiArray

from policy_align_ros.kinematics import Robot, RobotSetup, resolve_robot_setup
from policy_align_ros.kinematics.robot import ROBOTS, closest_names
from policy_align_ros.learning.policy_file import read_robot_fields
from policy_align_ros.nodes.start_parameters import (
    StartParameterError,
    StartParameterProblem,
    start_parameter_problem,
)
from policy_align_ros.ros_env import domain_id_problem

__all__ = [
    "DEFAULT_JOINTS",
    "LATCHED_QOS",
    "ROBOT_NAMES_TEXT",
    "StartNode",
    "accept",
    "call_with_timeout",
    "declare_robot",
    "descriptor",
    "load_robot",
    "optional_parameter",
    "reject",
    "run_node",
    "start_overrides",
    "undeclared_overrides",
]

#: Talos upper body (talos_reduced.urdf): torso, both 7-DoF arms and head. The grippers
#: are left out: they do not move the hands, and their reference posture is on a limit.
#: The same list as config/robots/talos.yaml (the robot config used when none is named).
DEFAULT_JOINTS: list[str] = (
    ["torso_1_joint", "torso_2_joint"]
    + [f"arm_left_{i}_joint" for i in range(1, 8)]
    + [f"arm_right_{i}_joint" for i in range(1, 8)]
    + ["head_1_joint", "head_2_joint"]
)

#: What a ``robot`` parameter takes, for its description: the names ``Robot.load`` knows
#: (:data:`~policy_align_ros.kinematics.robot.ROBOTS`), else a URDF file.
ROBOT_NAMES_TEXT = f"one of {', '.join(ROBOTS)} (example-robot-data), or a URDF path"

#: Reliable, transient-local, depth 1: a late subscriber still gets the last message.
LATCHED_QOS = QoSProfile(
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


def descriptor(
    description: str,
    *,
    read_only: bool = False,
    float_range: tuple[float, float] | None = None,
    int_range: tuple[int, int] | None = None,
    constraints: str = "",
) -> ParameterDescriptor:
    """A ParameterDescriptor with a description and an optional range (enforced by rclpy)."""
    desc = ParameterDescriptor(
        description=description, read_only=read_only, additional_constraints=constraints
    )
    if float_range is not None:
        desc.floating_point_range = [
            FloatingPointRange(from_value=float(float_range[0]), to_value=float(float_range[1]))
        ]
    if int_range is not None:
        desc.integer_range = [
            IntegerRange(from_value=int(int_range[0]), to_value=int(int_range[1]), step=1)
        ]
    return desc


class StartNode(Node):
    """The base of the package's nodes: a value given at start (``-p`` or a parameters
    file) that a parameter declaration refuses raises
    :class:`~policy_align_ros.nodes.start_parameters.StartParameterError`, whose one line
    names the node, the parameter, the value, the problem and the fix (the type or range
    the parameter declares), instead of rclpy's
    ``InvalidParameterValueException`` / ``InvalidParameterTypeException``.

    :func:`run_node` prints that line; a node built without ``run_node`` (a test) gets the
    same exception.
    """

    def declare_parameters(self, namespace: str, parameters: list[tuple],
                           ignore_override: bool = False) -> list[Parameter]:
        """rclpy's ``declare_parameters``, raising StartParameterError for a refused value
        (``declare_parameter`` goes through here)."""
        try:
            return super().declare_parameters(namespace, parameters, ignore_override)
        except (InvalidParameterValueException, InvalidParameterTypeException) as err:
            problem = _declaration_problem(self, namespace, parameters, ignore_override, err)
            raise StartParameterError(problem) from err


def _declaration_problem(node: Node, namespace: str, parameters: list[tuple],
                         ignore_override: bool, err: ParameterException
                         ) -> StartParameterProblem:
    """The refused declaration among ``parameters`` (rclpy's exceptions end in ``": NAME"``)
    as a :class:`~policy_align_ros.nodes.start_parameters.StartParameterProblem`."""
    names = [f"{namespace}.{t[0]}" if namespace else t[0] for t in parameters]
    index = next((i for i, n in enumerate(names) if str(err).endswith(f": {n}")), 0)
    name, spec = names[index], parameters[index]
    default = spec[1] if len(spec) > 1 else None
    desc = spec[2] if len(spec) > 2 else None
    declared = default if isinstance(default, Parameter.Type) else None
    # Unlike _override, an override of None (``joints:=[]``) must differ from none given.
    override = None if ignore_override else start_overrides(node).get(name)
    value = override.value if override is not None else (
        None if declared is not None else default)
    if desc is not None and desc.dynamic_typing:
        declared = _type_of(value)  # any type is the parameter's
    elif declared is None:
        declared = (Parameter.Type(desc.type) if desc is not None and desc.type
                    else _type_of(default))
    allowed = None
    if desc is not None and desc.floating_point_range:
        allowed = (desc.floating_point_range[0].from_value,
                   desc.floating_point_range[0].to_value)
    elif desc is not None and desc.integer_range:
        allowed = (desc.integer_range[0].from_value, desc.integer_range[0].to_value)
    # The reason rclpy passed on (the node's check, or its own range check) sits between
    # "Reason: " and the name it appends; all of the message when that wording changes.
    reason = str(err).removesuffix(f": {name}")
    reason = reason.split("Reason: ", 1)[1] if "Reason: " in reason else reason
    return start_parameter_problem(
        node.get_fully_qualified_name(), name, value, expected_type=declared.name,
        given_type=_type_of(value).name, allowed=allowed, reason=reason)


def _type_of(value: Any) -> Parameter.Type:
    """The parameter type of ``value`` as rclpy infers it (NOT_SET for None)."""
    try:
        return Parameter.Type.from_parameter_value(value)
    except TypeError:  # not a parameter value at all
        return Parameter.Type.NOT_SET


def accept() -> SetParametersResult:
    """A successful parameter-set result."""
    return SetParametersResult(successful=True)


def reject(reason: str) -> SetParametersResult:
    """A refused parameter-set result carrying ``reason``."""
    return SetParametersResult(successful=False, reason=reason)


def publish_zero_command(node: Node, publisher: Any, n_joints: int, why: str) -> None:
    """Publish one zero velocity command (``n_joints`` values) and wait up to 0.2 s for
    the subscribers to acknowledge it: a forward command controller holds its last
    command, so the zero must arrive before the node goes away."""
    publisher.publish(Float64MultiArray(data=[0.0] * n_joints))
    publisher.wait_for_all_acked(Duration(seconds=0.2))
    node.get_logger().info(f"published zero command ({why})")


def optional_parameter(node: Node, name: str) -> Any:
    """Value of a parameter declared without a default, or None when it was never set."""
    try:
        return node.get_parameter(name).value
    except ParameterUninitializedException:
        return None


def start_overrides(node: Node) -> Mapping[str, Parameter]:
    """The parameters given at start (``-p`` or a parameters file), by name.

    rclpy has no public accessor for the overrides before a parameter is declared; the
    robot's parameters need them to choose their defaults, a refused start value to be
    shown, and the demonstrator to say where a value came from. This is the one place
    that reads rclpy's private attribute.
    """
    return getattr(node, "_parameter_overrides", {})


def undeclared_overrides(node: Node) -> list[str]:
    """The parameters given at start that ``node`` does not declare, each with the closest
    names it does (rclpy ignores them: a misspelt limit would leave its default in force).
    Names of rclpy's own QoS overrides (``qos_overrides.``) are left out."""
    declared = node.list_parameters([], 0).names
    return [f"{name!r} (closest: {closest_names(name, declared, 3)})"
            for name in sorted(start_overrides(node))
            if not name.startswith("qos_overrides.") and not node.has_parameter(name)]


def _warn_undeclared(node: Node) -> None:
    for text in undeclared_overrides(node):
        node.get_logger().warning(f"parameter {text} given at start is not one of this "
                                  "node's: ignored")


def _override(node: Node, name: str) -> Any:
    """The value given for ``name`` at start (:func:`start_overrides`), or None."""
    param = start_overrides(node).get(name)
    return None if param is None else param.value


def declare_robot(node: Node, role: str, model_path: str | None = None,
                  read_fields: Callable[[str], tuple[str | None, list[str] | None]]
                  = read_robot_fields) -> RobotSetup:
    """Declare ``robot_config``, ``robot`` and ``joints`` (read-only) and resolve them.

    ``robot`` and ``joints`` default to the resolved values (explicit parameter, then the
    model file at the ``model_path`` parameter's value when given, then the robot config;
    :func:`~policy_align_ros.kinematics.robot_config.resolve_robot_setup`), so a
    parameter get shows what the node uses. A model file that contradicts an explicit
    ``robot_config`` gives neither (the returned setup's ``model_refused`` says why).
    ``read_fields(path)`` reads the model file's ``(robot, joints)`` (the executor passes
    one that reads the whole model once:
    :class:`~policy_align_ros.control.loading.StartModel`).

    Raises
    ------
    ValueError
        When the joints cannot be known, naming the fix.
    """
    model = None
    path = _override(node, model_path) if model_path else None
    if path:
        try:
            model = read_fields(path)
        except (OSError, ValueError):
            model = None  # the model's own loading says why it is refused
    setup = resolve_robot_setup(_override(node, "robot"), _override(node, "joints"),
                                _override(node, "robot_config"), model)
    node.declare_parameter("robot_config", "", descriptor(
        "robot config: a shipped name (talos, panda, ur5) or a .yaml path; gives robot "
        "and joints (and the controller, home posture and frames where the node uses "
        "them) when they are not set; empty = the config named like the robot, else talos",
        read_only=True))
    node.declare_parameter("robot", setup.robot, descriptor(
        f"the {role} robot: {ROBOT_NAMES_TEXT}; unset = "
        + ("the model file's (unless it contradicts robot_config), else "
           if model_path else "") + "robot_config's",
        read_only=True))
    node.declare_parameter("joints", setup.joints, descriptor(
        f"{role} joints, in command order; unset = "
        + ("the model file's, else " if model_path else "") + "robot_config's",
        read_only=True))
    return setup


def load_robot(setup: RobotSetup) -> Robot:
    """The robot of ``setup``; ValueError naming where robot and joints came from and
    how to set them when it does not load (an unknown joint, a bad URDF)."""
    try:
        return Robot.load(setup.robot, setup.joints)
    except ValueError as err:
        raise ValueError(f"{err} ({setup.hint()})") from None


class _NextCycle:
    """Awaitable that suspends a coroutine callback until the executor's next cycle."""

    def __await__(self):
        yield


async def call_with_timeout(client: Client, request: Any, timeout_s: float) -> Any | None:
    """Call a service from a coroutine callback without blocking its executor.

    For ``async def`` callbacks (rclpy runs them as tasks): while this waits, the
    executor keeps serving the node's other callbacks, so a single-threaded executor does
    not deadlock. The wait is on the steady clock: a network timeout is wall time even
    with ``use_sim_time`` (a paused simulation must not stall the call forever).

    Parameters
    ----------
    client : rclpy.client.Client
    request
        The service request.
    timeout_s : float
        Longest wait, s, for the service to appear and answer.

    Returns
    -------
    response or None
        None when the service did not appear or answer within ``timeout_s``.
    """
    clock = Clock(clock_type=ClockType.STEADY_TIME)
    deadline = clock.now() + Duration(nanoseconds=round(timeout_s * 1e9))
    future = None
    while clock.now() < deadline:
        if future is None and client.service_is_ready():
            future = client.call_async(request)
        if future is not None and future.done():
            return future.result()
        await _NextCycle()
    if future is not None:
        client.remove_pending_request(future)
    return None


async def next_cycle() -> None:
    """Suspend a coroutine callback until the executor's next cycle: its other callbacks
    run in between (the executor's fold-stop check, done in slices)."""
    await _NextCycle()


_STOP = threading.Event()
#: Exit status of a node that could not start (a bad parameter), as run_node returns it.
START_FAILED = 1
#: Longest wait [s] for a node's destruction and the context's shutdown once the node's
#: own clean-up is done (see :func:`run_node`).
TEARDOWN_TIMEOUT_S = 5.0


def _request_stop(signum: int, frame: object) -> None:
    # Only set a flag: an exception raised inside rclpy's C++ calls (e.g. while taking a
    # message) surfaces as an unrelated RuntimeError instead of a KeyboardInterrupt.
    _STOP.set()


def run_node(
    make_node: Callable[[], Node],
    args: Sequence[str] | None = None,
    *,
    executor_factory: Callable[[], Any] = SingleThreadedExecutor,
    finish: Callable[[Any], None] | None = None,
) -> int:
    """``main()`` body of every node executable (ros2/demos Jazzy style).

    SIGINT and SIGTERM only set a flag that the spin loop checks every 0.1 s; the handlers
    are installed before ``rclpy.init``, so a signal at any point of the start-up is kept
    until the loop sees it (rclpy's own handlers shut the context down, which can leave a
    node running or its clean-up hanging). The context also stays valid for
    ``destroy_node``, so a node can still publish on the way out (the executor's final
    zero command).

    Parameters
    ----------
    make_node : callable
        Builds the node (after ``rclpy.init``).
    args : sequence of str, optional
        Command line (``--ros-args ...``); ``sys.argv`` when None.
    executor_factory : callable
        Executor class, e.g. MultiThreadedExecutor for a node with a worker callback group.
    finish : callable, optional
        Called with the node after the loop, before it is destroyed, while the context
        is still valid (the recorder saves what is left there).

    Returns
    -------
    int
        0 on a normal or interrupted run, 1 when the node could not start (bad parameter:
        one line ``error: ...`` on stderr, no traceback), else the result of the node's
        ``done`` future when it has one.
    """
    if not _start_rclpy(args):
        return 1
    node = None
    executor = None
    code = 0
    try:
        node = make_node()
        _warn_undeclared(node)
        executor = executor_factory()
        executor.add_node(node)
        # A node that can finish (the demonstrator) exposes a ``done`` future: its exit code.
        done = getattr(node, "done", None)
        while not _STOP.is_set() and not (done is not None and done.done()):
            executor.spin_once(timeout_sec=0.1)
        if done is not None and done.done():
            code = int(done.result())
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ParameterException, ValueError) as err:
        # A StartNode's refused value is a ValueError naming the node, the parameter, the
        # value and the fix (StartParameterError); rclpy's other parameter exceptions (a
        # node built on rclpy's Node, a parameter read before it is declared) are one line
        # too, rather than a traceback.
        print(f"error: {err}", file=sys.stderr)
        code = START_FAILED
    finally:
        _tear_down(node, executor, finish, code)
    return code


def _start_rclpy(args: Sequence[str] | None) -> bool:
    """Check the domain id, install the stop flag's handlers and ``rclpy.init``; False
    (after one line ``error: ...`` on stderr) when the node cannot start."""
    problem = domain_id_problem()
    if problem:  # else Fast DDS's one line about a port number, and no node
        print(f"error: {problem}", file=sys.stderr)
        return False
    _STOP.clear()
    signal.signal(signal.SIGINT, _request_stop)
    signal.signal(signal.SIGTERM, _request_stop)
    try:
        rclpy.init(args=list(args) if args is not None else None,
                   signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as err:  # rcl's RCLError, e.g. an unreadable --params-file
        print(f"error: {err}", file=sys.stderr)
        return False
    return True


def _tear_down(node: Node | None, executor: Any, finish: Callable[[Any], None] | None,
               code: int) -> None:
    """``finish``, then the executor, the node and the context, bounded in time."""
    # A second signal must not interrupt the clean-up (the final zero command).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if node is not None and finish is not None:
        finish(node)
    # Ignoring signals, a teardown that never returns would need SIGKILL: Fast DDS
    # can deadlock destroying a participant while the others vanish at once.
    # Everything the node owes is done by then (data saved, zero command published
    # first in destroy_node), so past the bound the process just ends.
    watchdog = threading.Timer(TEARDOWN_TIMEOUT_S, _exit_stuck, (code,))
    watchdog.daemon = True
    watchdog.start()
    # The timer is a Python thread: a teardown stuck in C++ that holds the GIL (Fast
    # DDS spinning in DomainParticipant::set_listener) starves it. faulthandler's
    # watchdog is a C thread: it dumps where every thread is and exits with status 1.
    faulthandler.dump_traceback_later(2 * TEARDOWN_TIMEOUT_S, exit=True)
    # The executor goes before the node and the context: left to the garbage
    # collector, it destroys its signal guard condition after the context shut down
    # (or after the collector finalised the condition itself), printing "Exception
    # ignored in Executor.__del__ ... InvalidHandle" on the way out.
    if executor is not None:
        executor.shutdown()
    if node is not None:
        node.destroy_node()
    rclpy.try_shutdown()
    watchdog.cancel()
    faulthandler.cancel_dump_traceback_later()


def _exit_stuck(code: int) -> None:
    print(f"warning: the middleware's teardown did not finish within "
          f"{TEARDOWN_TIMEOUT_S:g} s; exiting without it", file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(code)
