"""Markdown tables of the nodes' parameters, made from the descriptors they declare.

Each node is constructed with its defaults in a private ``rclpy.Context`` (nothing is
published to another graph), and every declared parameter's descriptor is read back: type,
default, range, read-only flag and description (which states the unit). The README's
parameter tables are this module's output (``python tools/update_readme.py --params``), and
a test checks that they still agree with the code.
"""

from __future__ import annotations

import contextlib
import importlib
import tempfile
from collections.abc import Sequence

import rclpy
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node

__all__ = ["NODE_CLASSES", "parameter_rows", "parameter_tables"]

#: Executable name -> (module, Node subclass) of every node in the package.
NODE_CLASSES = {
    "recorder": ("policy_align_ros.nodes.recorder", "RecorderNode"),
    "learner": ("policy_align_ros.nodes.learner", "Learner"),
    "executor": ("policy_align_ros.nodes.executor", "Executor"),
    "sim_robot": ("policy_align_ros.nodes.sim_robot", "SimRobot"),
    "demonstrator": ("policy_align_ros.nodes.demonstrator", "Demonstrator"),
}

_BUILTIN = ("use_sim_time", "start_type_description_service")

_TYPES = {
    ParameterType.PARAMETER_BOOL: "bool",
    ParameterType.PARAMETER_INTEGER: "int",
    ParameterType.PARAMETER_DOUBLE: "float",
    ParameterType.PARAMETER_STRING: "string",
    ParameterType.PARAMETER_BYTE_ARRAY: "byte[]",
    ParameterType.PARAMETER_BOOL_ARRAY: "bool[]",
    ParameterType.PARAMETER_INTEGER_ARRAY: "int[]",
    ParameterType.PARAMETER_DOUBLE_ARRAY: "float[]",
    ParameterType.PARAMETER_STRING_ARRAY: "string[]",
}


def _range(desc: ParameterDescriptor) -> str:
    for r in list(desc.floating_point_range) + list(desc.integer_range):
        return f"[{_number(r.from_value)}, {_number(r.to_value)}]"
    return ""


def _number(value: float) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _default(value: object) -> str:
    if value is None:
        return "unset"
    if isinstance(value, str):
        return f'`"{value}"`' if len(value) <= 40 else f'`"{value[:37]}..."`'
    if isinstance(value, float):
        return f"`{_number(value)}`"
    if isinstance(value, (list, tuple)) or hasattr(value, "tolist"):
        items = list(value)
        if len(items) > 3:
            return f"{len(items)} items"
        return f"`{[_number(v) if isinstance(v, float) else v for v in items]}`"
    return f"`{value}`"


def parameter_rows(node: Node) -> list[tuple[str, str, str, str, str]]:
    """(name, type, default, range, description) of every parameter ``node`` declared.

    The parameters rclpy declares on every node (``use_sim_time``,
    ``start_type_description_service``) are left out.
    """
    names = sorted(n for n in node._parameters if n not in _BUILTIN)
    rows = []
    for name, desc in zip(names, node.describe_parameters(names), strict=True):
        try:
            value = node.get_parameter(name).value
        except ParameterUninitializedException:
            value = None
        kind = _TYPES.get(desc.type, "any")
        extra = " (read-only)" if desc.read_only else ""
        text = " ".join(desc.description.split()) + extra
        if desc.additional_constraints:
            text += f"; {' '.join(desc.additional_constraints.split())}"
        rows.append((name, kind, _default(value), _range(desc), text.replace("|", "\\|")))
    return rows


def parameter_tables(nodes: Sequence[str] = tuple(NODE_CLASSES), domain_id: int = 231) -> str:
    """Markdown: one table per node, its parameters with type, default, range, meaning."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    parts = []
    # Nodes resolve relative default paths (dataset_dir) against the working directory:
    # a scratch one keeps the caller's clean.
    with tempfile.TemporaryDirectory() as scratch, contextlib.chdir(scratch):
        parts = _tables(nodes, context)
    return "\n\n".join(parts)


def _tables(nodes: Sequence[str], context: rclpy.Context) -> list[str]:
    parts = []
    try:
        for exe in nodes:
            module, cls = NODE_CLASSES[exe]
            node = getattr(importlib.import_module(module), cls)(context=context)
            try:
                rows = parameter_rows(node)
            finally:
                node.destroy_node()
            parts.append(f"**`{exe}`** (`config/{exe}.yaml`)\n\n"
                         "| parameter | type | default | range | meaning |\n"
                         "|---|---|---|---|---|\n"
                         + "\n".join(f"| `{r[0]}` | {r[1]} | {r[2]} | {r[3]} | {r[4]} |"
                                     for r in rows))
    finally:
        rclpy.try_shutdown(context=context)
    return parts
