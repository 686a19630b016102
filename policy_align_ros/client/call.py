"""``policy-align call SERVICE [--data true|false] [--timeout S]``, without ros2cli.

Calls a std_srvs/Trigger service, or a std_srvs/SetBool service when ``--data`` is given;
the type is read from the ROS graph, so a mismatch is reported before calling. The ROS
domain is the one of the environment (``ROS_DOMAIN_ID``). Prints ``success: <message>`` or
``failure: <message>``.

Exit status: 0 when the service answered ``success=true``, 1 when it answered
``success=false``, 2 for a usage error (wrong or unsupported type, a name that is not a
valid service name), 3 when the service did not appear or answer within ``--timeout``
seconds.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import rclpy
from rclpy.exceptions import NameValidationException
from rclpy.node import Node
from rclpy.validate_full_topic_name import validate_full_topic_name
from std_srvs.srv import SetBool, Trigger

from policy_align_ros.client.oneshot import open_context, spin_until

__all__ = ["call_service", "run_call"]

_TYPES = {"std_srvs/srv/Trigger": Trigger, "std_srvs/srv/SetBool": SetBool}


def _service_type(node: Node, service: str, deadline: float) -> str | None:
    while time.monotonic() < deadline:
        for name, types in node.get_service_names_and_types():
            if name == service and types:
                return types[0]
        time.sleep(0.05)
    return None


def call_service(
    node: Node, service: str, data: bool | None, timeout: float
) -> tuple[int, str]:
    """Call ``service`` from ``node``; returns (exit status, text), see the module docstring."""
    try:
        validate_full_topic_name(service, is_service=True)
    except NameValidationException as err:
        return 2, f"{service!r} is not a valid service name ({str(err).splitlines()[0]})"
    deadline = time.monotonic() + timeout
    srv_type = _service_type(node, service, deadline)
    if srv_type is None:
        return 3, f"service {service} not available after {timeout:g} s"
    wanted = "std_srvs/srv/Trigger" if data is None else "std_srvs/srv/SetBool"
    if srv_type not in _TYPES:
        return 2, f"service {service} has type {srv_type}; only Trigger and SetBool supported"
    if srv_type != wanted:
        hint = "give --data true|false" if data is None else "omit --data"
        return 2, f"service {service} is a {srv_type.rsplit('/', 1)[-1]}: {hint}"
    cls = _TYPES[srv_type]
    client = node.create_client(cls, service)
    try:
        if not client.wait_for_service(timeout_sec=max(deadline - time.monotonic(), 0.0)):
            return 3, f"service {service} not available after {timeout:g} s"
        request = cls.Request()
        if data is not None:
            request.data = data
        future = client.call_async(request)
        if not spin_until(node, future, deadline):
            return 3, f"service {service} did not answer within {timeout:g} s"
        response = future.result()
        return (0 if response.success else 1), response.message
    finally:
        node.destroy_client(client)


def run_call(args: argparse.Namespace) -> int:
    """Entry of ``policy-align call``; ``args`` has ``service``, ``data``, ``timeout``."""
    service = args.service if args.service.startswith("/") else "/" + args.service
    data = None if args.data is None else args.data == "true"
    context = open_context("call", args.timeout)
    if context is None:
        return 2
    node = None
    try:
        node = Node(f"policy_align_call_{os.getpid()}", context=context)
        status, text = call_service(node, service, data, args.timeout)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
    stream = sys.stdout if status in (0, 1) else sys.stderr
    print(f"{'success' if status == 0 else 'failure'}: {text}", file=stream)
    return status
