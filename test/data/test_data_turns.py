"""Tests of policy_align_ros.data.turns (recorded continuous joints on one turn)."""

import numpy as np
import pytest

from policy_align_ros.data.turns import check_jumps, unwrap_turns
from policy_align_ros.learning import Trajectory


def _wrap(a):
    """As a driver reports an angle: in [-pi, pi)."""
    return np.remainder(a + np.pi, 2 * np.pi) - np.pi


def test_demonstrations_across_the_wrap_are_continuous_and_on_one_turn():
    t = np.linspace(0.0, 1.0, 50)
    through = 2.8 + 0.6 * t  # passes pi at about t = 0.57
    beyond = 3.3 + 0.1 * t  # entirely past pi: reported as negative angles
    other = np.linspace(0.1, 0.4, 50)  # a joint with limits: left as it is
    trajs = [Trajectory(np.column_stack([_wrap(a), other]), t, name=f"d{k}")
             for k, a in enumerate((through, beyond))]
    assert np.abs(np.diff(trajs[0].positions[:, 0])).max() > 6.0  # the driver's jump
    out = unwrap_turns(trajs, np.array([True, False]))
    for before, after, true in zip(trajs, out, (through, beyond), strict=True):
        # The true angles up to one whole turn, shared by both demonstrations.
        np.testing.assert_allclose(after.positions[:, 0] - true,
                                   after.positions[0, 0] - true[0], atol=1e-12)
        np.testing.assert_array_equal(after.positions[:, 1], other)
        np.testing.assert_array_equal(after.times, before.times)
        assert after.name == before.name
    shift = [after.positions[0, 0] - true[0]
             for after, true in zip(out, (through, beyond), strict=True)]
    np.testing.assert_allclose(shift[0], shift[1], atol=1e-12)
    turns = shift[0] / (2 * np.pi)
    assert abs(turns - round(turns)) < 1e-12
    # Without continuous joints nothing changes.
    same = unwrap_turns(trajs, np.array([False, False]))
    assert all(a is b for a, b in zip(same, trajs, strict=True))


def test_a_jump_of_more_than_half_a_turn_is_refused_naming_joint_demonstration_and_fix():
    t = np.linspace(0.0, 1.0, 20)
    calm = Trajectory(np.column_stack([0.1 * t, 0.2 * t]), t)
    check_jumps([calm], ["calm"], ["a", "b"], None)  # nothing to refuse
    wrapped = Trajectory(np.column_stack([0.1 * t, _wrap(3.0 + 0.3 * t)]), t)
    with pytest.raises(ValueError, match=r"^joint b\b.*\bwrapped\b.*--robot"):
        check_jumps([calm, wrapped], ["calm", "wrapped"], ["a", "b"], None)
    with pytest.raises(ValueError, match=r"^joint b\b.*\bwrapped\b.*\bjaco\b"):
        check_jumps([calm, wrapped], ["calm", "wrapped"], ["a", "b"], "jaco")


def test_a_step_far_faster_than_the_velocity_limit_is_refused_and_jitter_is_not():
    # 1 kHz at 0.5 rad/s, limit 2 rad/s; stamps jittered down to 0.05 ms apart.
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.uniform(0.00005, 0.00195, 2000))
    calm = Trajectory(np.column_stack([0.5 * t, -0.3 * t]), t)
    limits = np.array([2.0, 2.0])
    check_jumps([calm], ["calm"], ["a", "b"], "panda", limits)  # jitter is no jump
    # A reset moved the robot by 0.28 rad between two samples (a splice of two runs).
    X = calm.positions.copy()
    X[1000:, 1] += 0.28
    spliced = Trajectory(X, t)
    with pytest.raises(ValueError, match=r"^joint b\b.*\bspliced\b.*\bpanda\b"):
        check_jumps([calm, spliced], ["calm", "spliced"], ["a", "b"], "panda", limits)
    # A driver at 1 kHz over encoders read at 50 Hz: 20 repeats, then a step. No jump.
    held = np.repeat(calm.positions[::20], 20, axis=0)[:len(t)] * 3.0  # 1.5 rad/s
    check_jumps([Trajectory(held, t)], ["held"], ["a", "b"], "panda", limits)
    check_jumps([spliced], ["spliced"], ["a", "b"], "panda")  # limits unknown: not checked
    check_jumps([spliced], ["spliced"], ["a", "b"], "panda", np.array([np.inf, 0.0]))
