"""Tests of policy_align_ros.sim.script (the demonstrator's ROS-free expert logic)."""

import numpy as np
import pytest

from policy_align_ros.kinematics.robot import Robot, robots_dir
from policy_align_ros.sim.script import (
    DemonstrationScript,
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


GAIN = 0.5
# Kinova's Jaco: joints 1 and 4 are continuous, joint 2 a revolute with limits.
KINOVA_JOINTS = ["j2s6s200_joint_1", "j2s6s200_joint_2", "j2s6s200_joint_4"]


def _joints_script(robot: Robot, attractor) -> DemonstrationScript:
    # Speed limits far above the expert's speeds: the command is the policy itself.
    return DemonstrationScript(robot, attractor, GAIN, "joints", [], [], None,
                               np.full(robot.nq, 100.0), 0.01, np.random.default_rng(0))


@pytest.fixture(scope="module")
def kinova():
    path = robots_dir() / "kinova_description" / "robots" / "kinova.urdf"
    return Robot.load(str(path), joints=KINOVA_JOINTS)


def test_joints_expert_drives_a_wrapped_continuous_joint_the_short_way(kinova):
    script = _joints_script(kinova, [3.0, 2.0, -3.0])
    # Joint 1 is 0.28 rad past +pi from its attractor, reported wrapped near -pi; joint 4
    # likewise below -pi, reported near +pi. The plain difference is -6 and +6 rad.
    q = np.array([3.0 + 0.3 - 2 * np.pi, 2.1, -3.0 - 0.3 + 2 * np.pi])
    qdot = script.command(q)
    np.testing.assert_allclose(qdot, [-GAIN * 0.3, -GAIN * 0.1, GAIN * 0.3], atol=1e-12)
    # The reach controller turns the same way towards a start across +-pi.
    reach = script.reach_command(q, np.array([3.0, 2.0, -3.0]), GAIN)
    np.testing.assert_allclose(reach, [-GAIN * 0.3, -GAIN * 0.1, GAIN * 0.3], atol=1e-12)
    # ... and counts the start reached by the same short way (0.3 rad, not 6 rad).
    np.testing.assert_allclose(script.start_distance(q, np.array([3.0, 2.0, -3.0])), 0.3)


def test_joints_expert_is_unchanged_without_continuous_joints(hands):
    robot, _ = hands
    rng = np.random.default_rng(7)
    script = _joints_script(robot, None)
    q = script.attractor + rng.uniform(-0.05, 0.05, robot.nq)
    # The plain difference, bit for bit.
    np.testing.assert_array_equal(script.command(q), -GAIN * (q - script.attractor))
