"""A parameter value refused while a node starts: the decision (ROS-free,
policy_align_ros.nodes.start_parameters) and the nodes' base class and ``run_node`` that
raise and print it (own rclpy.Context on domain 204; a node process on domain 205)."""

import math
import os
import subprocess
import sys

import pytest
import rclpy
from rclpy.parameter import Parameter

from policy_align_ros.nodes._common import StartNode, accept, descriptor, reject
from policy_align_ros.nodes.start_parameters import (
    Cause,
    StartParameterError,
    start_parameter_problem,
)


def _problem(value, given, expected="DOUBLE", allowed=(1.0, 1000.0), reason="rclpy's"):
    return start_parameter_problem("/n", "rate_hz", value, expected_type=expected,
                                   given_type=given, allowed=allowed, reason=reason)


@pytest.mark.parametrize("value, given, cause", [
    ("abc", "STRING", Cause.TYPE),
    (5, "INTEGER", Cause.TYPE),  # rcl reads 5 as an integer: no double
    ([1.0], "DOUBLE_ARRAY", Cause.TYPE),
    (-5.0, "DOUBLE", Cause.RANGE),
    (1e6, "DOUBLE", Cause.RANGE),
    (math.nan, "DOUBLE", Cause.RANGE),  # rclpy's range check refuses NaN
    (50.0, "DOUBLE", Cause.REFUSED),  # within range: the node's own check refused it
])
def test_the_cause_is_the_type_then_the_range_then_the_nodes_check(value, given, cause):
    problem = _problem(value, given)
    assert problem.cause == cause
    assert problem.node == "/n" and problem.name == "rate_hz" and problem.value is value
    # The line names the node, the parameter and the problem; the fix when there is one.
    assert problem.text.startswith("/n: rate_hz:=") and problem.problem in problem.text
    assert problem.fix in problem.text


def test_the_fix_of_a_wrong_type_or_range_gives_what_the_declaration_allows():
    for problem in (_problem("abc", "STRING"), _problem(-5.0, "DOUBLE")):
        assert problem.allowed == (1.0, 1000.0)
        assert "1.0" in problem.fix and "1000.0" in problem.fix
    # An integer for a double: the same number, written as a double.
    assert "rate_hz:=5.0" in _problem(5, "INTEGER").fix
    # A number for a string parameter: quoted, so rcl keeps it text.
    quoted = start_parameter_problem("/n", "dir", 5, expected_type="STRING",
                                     given_type="INTEGER")
    assert quoted.cause == Cause.TYPE and "'5'" in quoted.fix
    # Integer ranges stay integers.
    count = start_parameter_problem("/n", "num", 0, expected_type="INTEGER",
                                    given_type="INTEGER", allowed=(1, 100000))
    assert count.cause == Cause.RANGE and "100000" in count.fix and "100000.0" not in count.fix


def test_the_nodes_own_reason_is_kept_without_repeating_the_name():
    problem = start_parameter_problem("/n", "joints", None, expected_type="STRING_ARRAY",
                                      given_type="NOT_SET",
                                      reason="joints: must be a non-empty list")
    # Unset (rcl's ``joints:=[]``) has no type to differ: the node's check decides.
    assert problem.cause == Cause.REFUSED
    assert problem.reason == "must be a non-empty list" and problem.fix == ""
    assert "joints:=[]" in problem.text


def test_a_range_without_a_number_is_left_to_the_nodes_reason():
    problem = start_parameter_problem("/n", "x", True, expected_type="BOOL",
                                      given_type="BOOL", allowed=(0, 1), reason="no")
    assert problem.cause == Cause.REFUSED and problem.reason == "no"


def _check(params):
    """The probe's own check: ``even`` must be even, a number ``width`` not negative."""
    for p in params:
        if p.name == "even" and p.value % 2:
            return reject("even: odd")
        if p.name == "width" and not isinstance(p.value, str) and p.value < 0:
            return reject("width: negative")
    return accept()


class _Probe(StartNode):
    """A node declaring one parameter of each kind of check."""

    def __init__(self, **kwargs):
        super().__init__("probe", **kwargs)
        self.add_on_set_parameters_callback(_check)
        self.declare_parameter("rate_hz", 100.0, descriptor("rate", float_range=(1.0, 1e3)))
        self.declare_parameter("even", 2, descriptor("an even count", int_range=(0, 10)))
        self.declare_parameter("names", Parameter.Type.STRING_ARRAY, descriptor("names"))
        # A name or a number, as the learner's sigma: any type is the parameter's.
        width = descriptor("a rule name or a number")
        width.dynamic_typing = True
        self.declare_parameter("width", "medium", width)


@pytest.fixture(scope="module")
def context():
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=204)
    yield context
    rclpy.try_shutdown(context=context)


@pytest.mark.parametrize("name, value, cause, given", [
    ("rate_hz", -5.0, Cause.RANGE, -5.0),
    ("rate_hz", "fast", Cause.TYPE, "fast"),
    ("even", 3, Cause.REFUSED, 3),
    ("even", 12, Cause.RANGE, 12),
    ("names", 1.5, Cause.TYPE, 1.5),
    ("width", -1.0, Cause.REFUSED, -1.0),  # a number for a string default: no type error
])
def test_a_refused_start_value_raises_the_problem_of_its_declaration(context, name, value,
                                                                     cause, given):
    with pytest.raises(StartParameterError) as err:
        _Probe(context=context, parameter_overrides=[Parameter(name, value=value)])
    problem = err.value.problem
    assert problem.node == "/probe" and problem.name == name and problem.value == given
    assert problem.cause == cause
    assert str(err.value) == problem.text
    if name == "even":
        assert problem.allowed == (0, 10) and problem.expected_type == "INTEGER"
    if cause == Cause.REFUSED:
        assert problem.reason in ("odd", "negative")


def test_accepted_start_values_are_declared(context):
    node = _Probe(context=context, parameter_overrides=[Parameter("rate_hz", value=50.0),
                                                        Parameter("names", value=["a"]),
                                                        Parameter("width", value=0.5)])
    try:
        assert node.get_parameter("rate_hz").value == 50.0
        assert node.get_parameter("names").value == ["a"]
        assert node.get_parameter("width").value == 0.5
    finally:
        node.destroy_node()


_PROCESS = """
import sys
from policy_align_ros.nodes._common import StartNode, descriptor, run_node

class Probe(StartNode):
    def __init__(self):
        super().__init__("probe")
        self.declare_parameter("rate_hz", 100.0, descriptor("rate", float_range=(1.0, 1e3)))

sys.exit(run_node(Probe, ["--ros-args", "-p", "rate_hz:=-5.0"]))
"""


def test_a_node_process_reports_a_refused_value_in_one_line_and_exits():
    done = subprocess.run([sys.executable, "-c", _PROCESS],
                          env=dict(os.environ, ROS_DOMAIN_ID="205"), capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 1, done.stderr  # run_node's status for a start that failed
    assert "Traceback" not in done.stderr
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, done.stderr
    # The node, the parameter with the value given, and the allowed range.
    assert "/probe" in errors[0] and "rate_hz:=-5.0" in errors[0]
    assert "1.0" in errors[0] and "1000.0" in errors[0]
