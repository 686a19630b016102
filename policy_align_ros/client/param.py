"""``policy-align param get|set NODE NAME [VALUE]``: node parameters without ros2cli.

``get`` prints ``NAME: VALUE (TYPE)`` (``NAME: unset (TYPE)`` for a parameter declared
without a value, such as the recorder's ``joints``). ``set`` parses ``VALUE`` as the
parameter's current type, or its declared type when it is unset (read from the node
first): a string parameter takes the text as it is (so YAML such as the executor's
``constraints`` needs no extra quoting), numbers, booleans and arrays are read as YAML, and
an integer is accepted for a double, and so is a float literal YAML 1.1 reads as text
(``1e-3``, ``inf``). The node's own validation decides;
its reason is printed when it refuses. The ROS domain is the environment's
(``ROS_DOMAIN_ID``).

Exit status: 0 success, 1 the node refused the value, 2 a usage error (no such parameter,
a value that does not parse as the parameter's type, a node name that is not valid), 3 the
node did not answer within ``--timeout`` seconds.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any

import rclpy
import yaml
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters
from rclpy.exceptions import NameValidationException
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python

from policy_align_ros.client.oneshot import open_context, spin_until

__all__ = ["get_parameter", "parse_value", "run_param", "set_parameter"]

#: Range of a ROS integer parameter (int64).
_INT64 = (-(2**63), 2**63 - 1)

_TYPE_NAMES = {
    ParameterType.PARAMETER_BOOL: "bool",
    ParameterType.PARAMETER_INTEGER: "integer",
    ParameterType.PARAMETER_DOUBLE: "double",
    ParameterType.PARAMETER_STRING: "string",
    ParameterType.PARAMETER_BYTE_ARRAY: "byte array",
    ParameterType.PARAMETER_BOOL_ARRAY: "bool array",
    ParameterType.PARAMETER_INTEGER_ARRAY: "integer array",
    ParameterType.PARAMETER_DOUBLE_ARRAY: "double array",
    ParameterType.PARAMETER_STRING_ARRAY: "string array",
}


class ParamError(Exception):
    """A failure with its exit status (see the module docstring)."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def parse_value(text: str, type_id: int) -> Any:
    """``text`` as a Python value of the parameter type ``type_id`` (ValueError if not)."""
    if type_id == ParameterType.PARAMETER_STRING:
        return text
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ValueError(f"{text!r} is not valid YAML ({err})") from None
    name = _TYPE_NAMES.get(type_id, "unset")

    def scalar(v: Any, kind: int) -> Any:
        if kind == ParameterType.PARAMETER_BOOL and isinstance(v, bool):
            return v
        if kind == ParameterType.PARAMETER_INTEGER and isinstance(v, int) \
                and not isinstance(v, bool):
            if not _INT64[0] <= v <= _INT64[1]:  # rclpy fails deep in serialisation
                raise ValueError(f"{v} is outside the integer range [-2^63, 2^63 - 1]")
            return v
        if kind == ParameterType.PARAMETER_DOUBLE and isinstance(v, (int, float)) \
                and not isinstance(v, bool):
            return float(v)
        if kind == ParameterType.PARAMETER_DOUBLE and isinstance(v, str):
            # YAML 1.1 reads "1e-3" and "inf" as text; they are numbers to a user.
            try:
                return float(v)
            except ValueError:
                pass
        if kind == ParameterType.PARAMETER_STRING:
            return str(v)
        raise ValueError(f"{text!r} is not a {name}")

    element = {
        ParameterType.PARAMETER_BOOL_ARRAY: ParameterType.PARAMETER_BOOL,
        ParameterType.PARAMETER_INTEGER_ARRAY: ParameterType.PARAMETER_INTEGER,
        ParameterType.PARAMETER_DOUBLE_ARRAY: ParameterType.PARAMETER_DOUBLE,
        ParameterType.PARAMETER_STRING_ARRAY: ParameterType.PARAMETER_STRING,
    }.get(type_id)
    if element is not None:
        if not isinstance(value, list):
            raise ValueError(f"{text!r} is not a {name} (write [a, b, ...])")
        return [scalar(v, element) for v in value]
    if type_id in (ParameterType.PARAMETER_BOOL, ParameterType.PARAMETER_INTEGER,
                   ParameterType.PARAMETER_DOUBLE):
        return scalar(value, type_id)
    raise ValueError(f"parameters of type {name} cannot be set here")


def _call(node: Node, srv_type, service: str, request, deadline: float):
    try:
        client = node.create_client(srv_type, service)
    except NameValidationException as err:  # e.g. a node name with a space
        raise ParamError(2, f"{service.rsplit('/', 1)[0]}: not a valid node name "
                            f"({str(err).splitlines()[0]})") from None
    try:
        if not client.wait_for_service(timeout_sec=max(deadline - time.monotonic(), 0.0)):
            raise ParamError(3, f"node {service.rsplit('/', 1)[0]} not found: service "
                                f"{service} not available")
        future = client.call_async(request)
        if not spin_until(node, future, deadline):  # a set call makes two
            raise ParamError(3, f"service {service} did not answer")
        return future.result()
    finally:
        node.destroy_client(client)


def get_parameter(node: Node, target: str, name: str, deadline: float) -> tuple[Any, int]:
    """Value and type id of parameter ``name`` of node ``target``.

    A parameter declared without a value gives ``None`` and its declared type; ParamError
    if the node has no such parameter.
    """
    request = GetParameters.Request(names=[name])
    response = _call(node, GetParameters, f"{target}/get_parameters", request, deadline)
    if response.values and response.values[0].type != ParameterType.PARAMETER_NOT_SET:
        msg = response.values[0]
        return parameter_value_to_python(msg), msg.type
    # Unset: declared (with a type, like the recorder's joints) or unknown?
    described = _call(node, DescribeParameters, f"{target}/describe_parameters",
                      DescribeParameters.Request(names=[name]), deadline)
    if described.descriptors and described.descriptors[0].type in _TYPE_NAMES:
        return None, described.descriptors[0].type
    raise ParamError(2, f"node {target} has no parameter {name!r}")


def set_parameter(node: Node, target: str, name: str, text: str, deadline: float) -> str:
    """Set ``name`` on ``target`` from ``text``; returns the node's answer (ParamError)."""
    _, type_id = get_parameter(node, target, name, deadline)
    try:
        value = parse_value(text, type_id)
    except ValueError as err:
        raise ParamError(2, f"{name}: {err}") from None
    # The type is given, not inferred: rclpy infers an empty list as a byte array.
    param = Parameter(name, Parameter.Type(type_id), value)
    request = SetParameters.Request(parameters=[param.to_parameter_msg()])
    response = _call(node, SetParameters, f"{target}/set_parameters", request, deadline)
    result = response.results[0]
    if not result.successful:
        raise ParamError(1, f"{target} refused {name}={text}: {result.reason or 'no reason'}")
    return f"{name} set to {value!r}"


def run_param(args: argparse.Namespace) -> int:
    """Entry of ``policy-align param``; ``args`` has action, node, name, value, timeout."""
    target = args.node if args.node.startswith("/") else "/" + args.node
    if args.action == "set" and args.value is None:
        print("policy-align param: error: set needs a VALUE", file=sys.stderr)
        return 2
    if args.action == "get" and args.value is not None:
        print("policy-align param: error: get takes no VALUE", file=sys.stderr)
        return 2
    context = open_context("param", args.timeout)
    if context is None:
        return 2
    deadline = time.monotonic() + args.timeout
    try:
        node = Node(f"policy_align_param_{os.getpid()}", context=context)
        try:
            if args.action == "get":
                value, type_id = get_parameter(node, target, args.name, deadline)
                shown = "unset" if value is None else repr(value)
                text = f"{args.name}: {shown} ({_TYPE_NAMES.get(type_id, '?')})"
            else:
                text = set_parameter(node, target, args.name, args.value, deadline)
            status = 0
        except ParamError as err:
            status, text = err.status, str(err)
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    print(text, file=sys.stdout if status == 0 else sys.stderr)
    return status
