"""Tests of policy_align_ros.control.joint_order."""

import numpy as np
import pytest

from policy_align_ros.control import (
    NO_ORDER_CHECK,
    model_permutation,
    order_check_off,
    unchecked_order_refusal,
)


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
