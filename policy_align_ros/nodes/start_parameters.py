"""A parameter value refused while a node starts, in one line (ROS-free).

rclpy refuses a value given at start (``-p NAME:=VALUE`` or a parameters file) while the
node declares the parameter: a value of another type than the declared one, one outside
the declared range, or one the node's own check refuses. Its exceptions word that for a
developer ("Invalid parameter value (-5.0) for parameter. Reason: Parameter rate_hz out of
range Min: 1.0, Max: 1000.0, value: -5.0: rate_hz") and name neither the node nor the fix.
:func:`start_parameter_problem` decides which of the three it is from the declaration
(its type and range) and the value, and :class:`StartParameterProblem` words it as one
line naming the node, the parameter, the value, the problem and the fix;
:class:`~policy_align_ros.nodes._common.StartNode` raises it, and
:func:`~policy_align_ros.nodes._common.run_node` prints it.

Types are rclpy's ``Parameter.Type`` names ("DOUBLE", "STRING_ARRAY", ...).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

__all__ = ["Cause", "StartParameterError", "StartParameterProblem", "start_parameter_problem"]

#: How each parameter type is named, and how a value of it is written on the command line.
TYPE_WORDS: dict[str, tuple[str, str]] = {
    "BOOL": ("a bool", "true or false"),
    "INTEGER": ("an integer", "a whole number"),
    "DOUBLE": ("a double", "a number with a decimal point"),
    "STRING": ("a string", "text"),
    "BYTE_ARRAY": ("a byte array", "a list of bytes"),
    "BOOL_ARRAY": ("a bool array", "a list such as [true, false]"),
    "INTEGER_ARRAY": ("an integer array", "a list such as [1, 2]"),
    "DOUBLE_ARRAY": ("a double array", "a list such as [0.0, 1.5]"),
    "STRING_ARRAY": ("a string array", "a list such as [a, b]"),
    "NOT_SET": ("no value", "a value"),
}


class Cause(StrEnum):
    """Why a value given at start was refused."""

    #: Of another type than the parameter's (``rate_hz:=abc``, ``rate_hz:=5`` for a double).
    TYPE = "type"
    #: Outside the range the parameter's descriptor declares.
    RANGE = "range"
    #: Refused by the node's own check of the value (its reason says why).
    REFUSED = "refused"


@dataclass(frozen=True)
class StartParameterProblem:
    """A value given at start that a node refused while declaring its parameter.

    Attributes
    ----------
    node : str
        The node's fully qualified name.
    name : str
        The parameter.
    value
        The value given (None: given empty or unset, as rcl passes ``[]``).
    cause : Cause
    expected_type, given_type : str
        The parameter's type and the value's.
    allowed : (low, high) or None
        The parameter's declared range, None without one.
    reason : str
        The node's own reason (:attr:`Cause.REFUSED`), without the parameter's name.
    """

    node: str
    name: str
    value: Any
    cause: Cause
    expected_type: str
    given_type: str
    allowed: tuple[float, float] | None = None
    reason: str = ""

    @property
    def problem(self) -> str:
        """What is wrong with the value."""
        if self.cause == Cause.TYPE:
            return (f"{_article(self.given_type)} where {self.name} takes "
                    f"{_article(self.expected_type)}")
        if self.cause == Cause.RANGE:
            return "out of range"
        return self.reason

    @property
    def fix(self) -> str:
        """How to give an accepted value (empty: the node's reason says it)."""
        within = ""
        if self.allowed is not None:
            within = f" from {_number(self.allowed[0])} to {_number(self.allowed[1])}"
        if self.cause == Cause.TYPE:
            if (self.expected_type == "DOUBLE" and self.given_type == "INTEGER"
                    and isinstance(self.value, int)):
                # The usual slip: rcl reads 5 as an integer, so a double needs 5.0.
                return f"write it with a decimal point: {self.name}:={float(self.value)!r}"
            if self.expected_type == "STRING":
                # rcl reads the value as YAML: 0.3, true or 5 are no strings unless quoted.
                return f"quote it to keep it text: {self.name}:=\"'{_shown(self.value)}'\""
            how = TYPE_WORDS.get(self.expected_type, (self.expected_type, "a value"))[1]
            return f"give {how}{within}"
        if self.cause == Cause.RANGE:
            return f"give {_article(self.expected_type)}{within}"
        return ""

    @property
    def text(self) -> str:
        """The whole line: node, parameter, value, problem and fix."""
        line = f"{self.node}: {self.name}:={_shown(self.value)} refused: {self.problem}"
        return f"{line}; {self.fix}" if self.fix else line

    def __str__(self) -> str:
        return self.text


class StartParameterError(ValueError):
    """A value given at start refused while a node declared its parameter
    (:class:`~policy_align_ros.nodes._common.StartNode`); ``problem`` says which and why,
    and the message is its one line."""

    def __init__(self, problem: StartParameterProblem) -> None:
        super().__init__(problem.text)
        self.problem = problem


def start_parameter_problem(node: str, name: str, value: Any, *, expected_type: str,
                            given_type: str, allowed: Sequence[float] | None = None,
                            reason: str = "") -> StartParameterProblem:
    """Why the value given at start for parameter ``name`` of ``node`` was refused.

    Parameters
    ----------
    node : str
        The node's fully qualified name.
    name : str
        The parameter.
    value
        The value given at start (None: unset, as rcl passes ``[]``).
    expected_type, given_type : str
        The parameter's declared type and the value's (rclpy ``Parameter.Type`` names).
    allowed : (low, high), optional
        The declared range (an integer or floating-point range).
    reason : str
        The reason the declaration gave (the node's check, or rclpy's range check).

    Returns
    -------
    StartParameterProblem
        :attr:`Cause.TYPE` when the types differ (an unset value has none to differ),
        else :attr:`Cause.RANGE` when the value is not a number within ``allowed``, else
        :attr:`Cause.REFUSED` with ``reason`` (less a leading ``"NAME: "``).
    """
    span = None if allowed is None else (allowed[0], allowed[1])
    if given_type not in (expected_type, "NOT_SET"):
        cause = Cause.TYPE
    elif span is not None and _outside(value, span):
        cause = Cause.RANGE
    else:
        cause = Cause.REFUSED
    return StartParameterProblem(
        node, name, value, cause, expected_type, given_type, span,
        reason.removeprefix(f"{name}: ") if cause == Cause.REFUSED else "")


def _outside(value: Any, span: tuple[float, float]) -> bool:
    """Whether ``value`` is a number outside ``span`` (NaN is: rclpy's check refuses it)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    low, high = min(span), max(span)
    return math.isnan(value) or not low <= value <= high


def _article(type_name: str) -> str:
    return TYPE_WORDS.get(type_name, (type_name.lower(),))[0]


def _number(x: float) -> str:
    # repr keeps a double's decimal point (1.0), which tells the type along with the range.
    return repr(x) if isinstance(x, float) else str(x)


def _shown(value: Any) -> str:
    """``value`` as it is written after ``NAME:=`` on the command line."""
    if value is None:
        return "[]"  # rcl passes an empty list, whose type it cannot tell, as unset
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_shown(v) for v in value) + "]"
    return repr(value) if isinstance(value, float) else str(value)
