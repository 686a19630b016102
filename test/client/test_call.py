"""Tests of ``policy-align call`` (policy_align_ros.client.call; domain ids 190-199)."""

import argparse
import os
import subprocess
import sys

import pytest
from rclpy.node import Node
from std_srvs.srv import SetBool, Trigger

from policy_align_ros.client.call import run_call


@pytest.fixture
def services(monkeypatch, ros_context, ros_spin):
    """A node offering /ok (Trigger, success), /no (Trigger, failure), /flag (SetBool)."""
    monkeypatch.setenv("ROS_DOMAIN_ID", "190")
    context = ros_context(190)
    node = Node("services", context=context)
    seen = []

    def trigger(ok):
        def handle(request, response):
            response.success, response.message = ok, "done" if ok else "nope"
            return response
        return handle

    def flag(request, response):
        seen.append(request.data)
        response.success, response.message = True, f"flag={request.data}"
        return response

    node.create_service(Trigger, "/ok", trigger(True))
    node.create_service(Trigger, "/no", trigger(False))
    node.create_service(SetBool, "/flag", flag)
    with ros_spin(context, node):
        yield seen


def _call(service, data=None, timeout=10.0):
    return run_call(argparse.Namespace(service=service, data=data, timeout=timeout))


def test_trigger_success_and_failure(services, capsys):
    # The exit status follows the service's answer, whose message reaches the user.
    assert _call("/ok") == 0
    assert "done" in capsys.readouterr().out
    assert _call("no") == 1
    assert "nope" in capsys.readouterr().out


def test_setbool_with_data(services, capsys):
    assert _call("/flag", data="false") == 0
    assert services == [False]
    assert "flag=False" in capsys.readouterr().out


def test_type_mismatch_and_missing_service(services, capsys):
    assert _call("/flag") == 2
    assert _call("/ok", data="true") == 2
    assert services == []  # a usage error calls nothing
    assert _call("/missing", timeout=0.5) == 3
    assert capsys.readouterr().err  # each refusal gives its reason


@pytest.mark.parametrize("timeout", [float("inf"), float("nan"), 1e300])
def test_a_timeout_rclpy_cannot_wait_is_a_usage_error(services, timeout, capsys):
    assert _call("/ok", timeout=timeout) == 2
    assert capsys.readouterr().err


def test_an_unusable_ros_domain_is_a_usage_error(monkeypatch, capsys):
    monkeypatch.setenv("ROS_DOMAIN_ID", "abc")
    assert _call("/ok", timeout=1.0) == 2
    assert capsys.readouterr().err


# A call in its own process, then the garbage collector's worst order forced (an executor's
# signal guard condition finalised before the executor): no executor may still hold one.
_CALL_THEN_COLLECT = """
import argparse, gc, sys
from rclpy.signals import SignalHandlerGuardCondition
from policy_align_ros.client.call import run_call

code = run_call(argparse.Namespace(service="/missing", data=None, timeout=0.3))
for obj in gc.get_objects():
    if isinstance(obj, SignalHandlerGuardCondition):
        obj.__del__()
gc.collect()
sys.exit(code)
"""


def test_a_call_process_ends_without_ignored_exceptions():
    done = subprocess.run([sys.executable, "-c", _CALL_THEN_COLLECT],
                          env=dict(os.environ, ROS_DOMAIN_ID="195"), capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 3, done.stderr
    assert "Exception ignored" not in done.stderr, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
