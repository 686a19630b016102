"""Tests of policy_align_ros.sim.script (the demonstrator's ROS-free expert logic)."""

import numpy as np
import pytest

from policy_align_ros.sim.script import (
    drop_roundoff_at_limits,
    hand_plane_rows,
    random_plane_specs,
    reachable_home,
    stale_joint_state,
)


def test_random_plane_specs_are_unit_normals_per_frame():
    specs = random_plane_specs(["a", "b"], np.random.default_rng(0))
    assert [s["frame"] for s in specs] == ["a", "b"]
    for s in specs:
        assert s["type"] == "plane"
        assert np.linalg.norm(s["normal"]) == pytest.approx(1.0)
    assert specs[0]["normal"] != specs[1]["normal"]


def test_hand_plane_rows_put_each_normal_in_its_hand_block():
    specs = [{"type": "plane", "frame": "r", "normal": [0.0, 0.0, 1.0]},
             {"type": "plane", "frame": "other", "normal": [1.0, 0.0, 0.0]}]
    rows, rest = hand_plane_rows(specs, ["l", "r"])
    np.testing.assert_array_equal(rows, [[0, 0, 0, 0, 0, 1]])
    assert rest == [specs[1]]
    assert hand_plane_rows([], ["l"])[0].shape == (0, 3)


def test_roundoff_out_of_a_limit_is_dropped_but_a_real_push_is_kept():
    lower, upper = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    q = np.array([1.0, -1.0, 0.0])
    qdot = drop_roundoff_at_limits(q, np.array([1e-17, -1e-12, 0.5]), lower, upper)
    np.testing.assert_array_equal(qdot, [0.0, 0.0, 0.5])
    kept = drop_roundoff_at_limits(q, np.array([0.2, 0.3, 0.0]), lower, upper)
    np.testing.assert_array_equal(kept, [0.2, 0.3, 0.0])  # outward 0.2 stays; inward 0.3


def test_stale_joint_state_says_why_or_nothing():
    assert stale_joint_state(None, 5.0, 0.1)  # none yet: stale
    assert stale_joint_state(4.95, 5.0, 0.1) == ""
    assert stale_joint_state(5.0, 5.0, 0.1) == ""
    assert "0.300" in stale_joint_state(4.7, 5.0, 0.1)  # its age named
    assert "1.000" in stale_joint_state(6.0, 5.0, 0.1)  # how far the clock went back


def test_the_reachable_home_is_the_reference_posture_moved_inside_the_limits():
    # z1's reference posture folds joints against their stops (0 on [0, 2.97]).
    class Folded:
        lower = np.array([0.0, -2.88, -1.0, -np.inf])
        upper = np.array([2.97, 0.0, 1.0, np.inf])

        @staticmethod
        def neutral():
            return np.array([0.0, 0.0, 0.3, 5.0])

    home = reachable_home(Folded(), margin=0.1)
    np.testing.assert_allclose(home, [0.1, -0.1, 0.3, 5.0])
    narrow = Folded()
    narrow.lower, narrow.upper = np.array([0.0, -0.2, -1.0, -1.0]), np.array([0.2, 0.0, 1, 1])
    home = reachable_home(narrow, margin=0.1)
    assert np.all(home > narrow.lower) and np.all(home < narrow.upper)
