"""Tests of ``policy-align param`` (policy_align_ros.client.param; domain id 191)."""

import argparse

import pytest
from rcl_interfaces.msg import ParameterType, SetParametersResult
from rclpy.node import Node

from policy_align_ros.client.param import parse_value, run_param


@pytest.fixture
def target(monkeypatch, ros_context, ros_spin):
    """A node ``/target`` with a double (refusing negatives), a string, a bool array, an
    integer and a double array."""
    monkeypatch.setenv("ROS_DOMAIN_ID", "191")
    context = ros_context(191)
    node = Node("target", context=context)
    node.declare_parameter("gain", 1.5)
    node.declare_parameter("spec", "[]")
    node.declare_parameter("flags", [True, False])
    node.declare_parameter("count", 3)
    node.declare_parameter("limits", [1.0, 2.0])

    def check(params):
        for p in params:
            if p.name == "gain" and p.value < 0:
                return SetParametersResult(successful=False, reason="gain must be >= 0")
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(check)
    with ros_spin(context, node):
        yield node


def _run(action, name, value=None, node="/target", timeout=10.0):
    return run_param(argparse.Namespace(action=action, node=node, name=name, value=value,
                                        timeout=timeout))


def test_get_prints_value_and_type(target, capsys):
    assert _run("get", "gain") == 0
    out = capsys.readouterr().out
    assert "gain" in out and "1.5" in out and "double" in out


def test_set_reads_the_value_as_the_parameters_type(target, capsys):
    assert _run("set", "gain", "2") == 0  # an integer is accepted for a double
    assert target.get_parameter("gain").value == 2.0
    yaml_text = "[{type: plane, frame: hand, normal: [0, 0, 1]}]"
    assert _run("set", "spec", yaml_text) == 0  # a string keeps the text as it is
    assert target.get_parameter("spec").value == yaml_text
    assert _run("set", "flags", "[false, true]") == 0
    assert list(target.get_parameter("flags").value) == [False, True]


def test_refusals_and_errors_have_their_exit_status(target, capsys):
    assert _run("set", "gain", "-1") == 1
    assert "gain must be >= 0" in capsys.readouterr().err
    assert target.get_parameter("gain").value == 1.5
    assert _run("set", "gain", "fast") == 2
    assert _run("get", "nope") == 2
    assert _run("set", "gain") == 2
    assert _run("get", "gain", node="/absent", timeout=0.5) == 3
    assert target.get_parameter("gain").value == 1.5  # no refused set changed it
    assert capsys.readouterr().out == ""  # no value is shown for a refusal


def test_parse_value_rejects_wrong_types():
    assert parse_value("3", ParameterType.PARAMETER_INTEGER) == 3
    assert parse_value("[1, 2.5]", ParameterType.PARAMETER_DOUBLE_ARRAY) == [1.0, 2.5]
    for text, type_id in (("true", ParameterType.PARAMETER_DOUBLE),
                          ("1.5", ParameterType.PARAMETER_INTEGER),
                          ("1", ParameterType.PARAMETER_BOOL),
                          ("3", ParameterType.PARAMETER_STRING_ARRAY),
                          ("[a", ParameterType.PARAMETER_STRING_ARRAY)):
        with pytest.raises(ValueError):
            parse_value(text, type_id)


def test_numbers_yaml_reads_as_text_are_numbers():
    # YAML 1.1 reads "1e-3" and "inf" as strings; a user means numbers.
    assert parse_value("1e-3", ParameterType.PARAMETER_DOUBLE) == 1e-3
    assert parse_value("inf", ParameterType.PARAMETER_DOUBLE) == float("inf")
    assert parse_value("[2e2, 1]", ParameterType.PARAMETER_DOUBLE_ARRAY) == [200.0, 1.0]
    with pytest.raises(ValueError, match="'fast'"):
        parse_value("fast", ParameterType.PARAMETER_DOUBLE)


def test_an_integer_beyond_int64_is_a_usage_error(target, capsys):
    assert _run("set", "count", str(2**63)) == 2
    assert capsys.readouterr().err
    assert target.get_parameter("count").value == 3


def test_an_empty_array_keeps_the_parameters_type(target, capsys):
    # rclpy infers [] as a byte array, which a double-array parameter refuses.
    assert _run("set", "limits", "[]") == 0, capsys.readouterr().err
    assert list(target.get_parameter("limits").value) == []


@pytest.mark.parametrize("timeout", [float("inf"), float("nan"), 1e300])
def test_a_timeout_rclpy_cannot_wait_is_a_usage_error(target, timeout, capsys):
    assert _run("get", "gain", timeout=timeout) == 2
    assert capsys.readouterr().out == ""


def test_an_unusable_ros_domain_is_a_usage_error(monkeypatch, capsys):
    monkeypatch.setenv("ROS_DOMAIN_ID", "abc")
    assert _run("get", "gain", timeout=1.0) == 2
    assert capsys.readouterr().out == ""
