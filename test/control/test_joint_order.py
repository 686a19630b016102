"""Tests of policy_align_ros.control.joint_order."""

import numpy as np
import pytest

from policy_align_ros.control import (
    NO_ORDER_CHECK,
    controller_order_refusal,
    joint_order_problem,
    model_permutation,
    order_check_off,
    unchecked_order_refusal,
)

ARM = [f"joint{i}" for i in range(1, 8)]


def test_model_permutation_maps_controller_order_to_model_order():
    perm = model_permutation(["b", "c", "a"], ["a", "b", "c"])
    q = np.array([1.0, 2.0, 3.0])  # a, b, c
    np.testing.assert_array_equal(q[perm], [2.0, 3.0, 1.0])
    np.testing.assert_array_equal(model_permutation(None, ["a", "b"]), [0, 1])
    with pytest.raises(ValueError, match=r"\['d'\].*\['c'\]"):
        model_permutation(["a", "b", "d"], ["a", "b", "c"])


@pytest.mark.parametrize("controller, off", [
    ("none", True), (" None ", True), ("", True),
    ("/velocity_controller", False), ("/none", False), ("nonexistent", False),
])
def test_only_an_explicit_none_or_empty_controller_turns_the_order_check_off(controller, off):
    assert order_check_off(controller) is off


def test_an_unread_joint_order_refusal_names_the_fixes():
    why = "it did not answer within 1 s"
    text = unchecked_order_refusal("/velocity_controller", why)
    # The controller, what went wrong (passed through) and the parameter that opts out.
    assert "/velocity_controller" in text and why in text
    assert f"-p controller:={NO_ORDER_CHECK}" in text


def test_a_controller_order_problem_names_the_slot_and_the_fix():
    text = joint_order_problem(ARM[::-1], ARM, "/velocity_controller")
    assert "'joint7'" in text and "'joint1'" in text and "/velocity_controller" in text
    # The fix: the executor's joints in the controller's order, or the robot config.
    assert f"-p joints:=[{','.join(ARM[::-1])}]" in text and "robot_config" in text
    assert joint_order_problem(ARM, ARM, "/c") == ""


@pytest.mark.parametrize("theirs, missing, extra", [
    (ARM[:-1], ["joint7"], []),
    ([*ARM, "gripper"], [], ["gripper"]),
    ([*ARM[:-1], "gripper"], ["joint7"], ["gripper"]),
])
def test_other_controller_joints_name_only_the_parts_that_differ(theirs, missing, extra):
    text = joint_order_problem(theirs, ARM, "/c")
    assert "[]" not in text  # an empty side is left out
    for names in (missing, extra):
        assert (str(names) in text) == bool(names)
    assert f"-p joints:=[{','.join(theirs)}]" in text


def test_the_controllers_answer_refuses_an_enable_with_the_cause():
    joints = ["a", "b"]
    assert controller_order_refusal("/c", ["a", "b"], joints, True, 1.0) == ""
    # Another order: the mismatch, as joint_order_problem names it.
    assert (controller_order_refusal("/c", ["b", "a"], joints, True, 1.0)
            == joint_order_problem(["b", "a"], joints, "/c"))
    # No order read: refused as unchecked, told apart by whether the controller answered.
    silent = controller_order_refusal("/c", None, joints, False, 1.0)
    no_joints = controller_order_refusal("/c", None, joints, True, 1.0)
    assert silent and no_joints and silent != no_joints
    assert f"-p controller:={NO_ORDER_CHECK}" in silent  # the unchecked refusal's fixes
