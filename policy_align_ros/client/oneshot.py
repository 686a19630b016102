"""What ``policy-align call`` and ``policy-align param`` share: a checked timeout, a private
``rclpy.Context``, and a service future awaited until a deadline.
"""

from __future__ import annotations

import sys
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.task import Future

from policy_align_ros.ros_env import domain_id_problem

__all__ = ["MAX_TIMEOUT_S", "open_context", "spin_until"]

#: Longest ``--timeout`` [s]: rclpy's waits take int64 nanoseconds.
MAX_TIMEOUT_S = 1e6


def open_context(command: str, timeout: float) -> rclpy.Context | None:
    """A new initialised context, or ``None`` after printing a usage error to stderr.

    Parameters
    ----------
    command : str
        The sub-command for the message, e.g. ``"call"``.
    timeout : float
        The ``--timeout`` [s]; it must lie in ``(0, MAX_TIMEOUT_S]`` (also rejects NaN and
        inf, which rclpy cannot wait).
    """
    if not 0 < timeout <= MAX_TIMEOUT_S:
        print(f"policy-align {command}: error: --timeout must be > 0 and <= "
              f"{MAX_TIMEOUT_S:g} s", file=sys.stderr)
        return None
    problem = domain_id_problem()
    if problem:
        print(f"policy-align {command}: error: {problem}", file=sys.stderr)
        return None
    context = rclpy.Context()
    try:
        rclpy.init(context=context)
    except RuntimeError as err:  # rcl's RCLError, e.g. a ROS_DOMAIN_ID that is no number
        print(f"policy-align {command}: error: {err}", file=sys.stderr)
        return None
    return context


def spin_until(node: Node, future: Future, deadline: float) -> bool:
    """Spin ``node`` until ``future`` is done or ``time.monotonic()`` passes ``deadline``.

    Returns whether ``future`` holds a result. The executor is shut down before returning:
    its guard conditions outlive it otherwise, and callers may call many times.
    """
    executor = SingleThreadedExecutor(context=node.context)
    try:
        executor.add_node(node)
        executor.spin_until_future_complete(
            future, timeout_sec=max(deadline - time.monotonic(), 0.0))
    finally:
        executor.shutdown()
    return future.done() and future.result() is not None
