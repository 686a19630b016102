"""Tests of policy_align_ros.control.joint_order."""

import numpy as np
import pytest

from policy_align_ros.control import model_permutation


def test_model_permutation_maps_controller_order_to_model_order():
    perm = model_permutation(["b", "c", "a"], ["a", "b", "c"])
    q = np.array([1.0, 2.0, 3.0])  # a, b, c
    np.testing.assert_array_equal(q[perm], [2.0, 3.0, 1.0])
    np.testing.assert_array_equal(model_permutation(None, ["a", "b"]), [0, 1])
    with pytest.raises(ValueError, match=r"model needs \['d'\].*not in the model \['c'\]"):
        model_permutation(["a", "b", "d"], ["a", "b", "c"])
