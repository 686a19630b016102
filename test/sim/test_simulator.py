"""Tests of policy_align_ros.sim.simulator (ROS-free kinematic simulation)."""

import numpy as np
import pytest

from policy_align_ros.sim.simulator import KinematicSim, integrate_clamped

LOWER = np.array([-1.0, -0.5, -2.0])
UPPER = np.array([1.0, 0.5, 2.0])


def test_integrate_clamped_stops_at_limits_and_reports_actual_velocity():
    q, qdot = integrate_clamped(np.array([0.9, 0.0, 0.0]), np.array([1.0, -1.0, 0.5]), 0.2,
                                LOWER, UPPER)
    np.testing.assert_allclose(q, [1.0, -0.2, 0.1])
    np.testing.assert_allclose(qdot, [0.5, -1.0, 0.5])


def test_sim_integrates_fresh_commands_and_holds_still_when_stale():
    sim = KinematicSim(LOWER, UPPER, np.zeros(3), command_timeout_s=0.1)
    sim.set_command(np.array([0.1, 0.2, -0.3]), t=0.0)
    for k in range(1, 6):
        sim.step(0.01, t=0.01 * k)
    np.testing.assert_allclose(sim.q, [0.005, 0.01, -0.015])
    before = sim.q.copy()
    sim.step(0.01, t=0.5)  # the command is 0.5 s old: stale
    np.testing.assert_array_equal(sim.q, before)
    np.testing.assert_array_equal(sim.qdot, np.zeros(3))


def test_a_command_from_after_a_clock_jump_back_is_stale():
    # A restarted /clock: the last command's time lies ahead of the clock, its age unknown.
    sim = KinematicSim(LOWER, UPPER, np.zeros(3), command_timeout_s=0.1)
    sim.set_command(np.array([0.1, 0.2, -0.3]), t=10.0)
    assert sim.command_is_fresh(10.05)
    assert not sim.command_is_fresh(5.0)
    sim.step(0.01, t=5.0)
    np.testing.assert_array_equal(sim.q, np.zeros(3))


def test_sim_never_leaves_the_joint_limits():
    rng = np.random.default_rng(0)
    sim = KinematicSim(LOWER, UPPER, np.zeros(3))
    for k in range(200):
        sim.set_command(rng.normal(scale=5.0, size=3), t=0.05 * k)
        q = sim.step(0.05, t=0.05 * k)
        assert np.all(q >= LOWER) and np.all(q <= UPPER)


def test_sim_rejects_bad_commands_and_keeps_the_previous_one():
    sim = KinematicSim(LOWER, UPPER, np.zeros(3))
    sim.set_command(np.array([0.1, 0.0, 0.0]), t=0.0)
    with pytest.raises(ValueError, match=r"\b3\b.*\(2,\)"):
        sim.set_command(np.zeros(2), t=0.0)
    with pytest.raises(ValueError, match="NaN"):
        sim.set_command(np.array([np.nan, 0.0, 0.0]), t=0.0)
    sim.step(0.1, t=0.05)
    np.testing.assert_allclose(sim.q, [0.01, 0.0, 0.0])


def test_sim_applies_velocity_limits_joint_by_joint():
    sim = KinematicSim(LOWER, UPPER, np.zeros(3), velocity_limit=np.array([0.1, 1.0, 1.0]))
    sim.set_command(np.array([1.0, -0.5, 0.0]), t=0.0)
    sim.step(0.1, t=0.0)
    np.testing.assert_allclose(sim.q, [0.01, -0.05, 0.0])


def test_reset_clamps_into_limits_and_drops_the_command():
    sim = KinematicSim(LOWER, UPPER, np.zeros(3))
    sim.set_command(np.ones(3), t=0.0)
    q = sim.reset(np.array([5.0, -5.0, 0.3]))
    np.testing.assert_allclose(q, [1.0, -0.5, 0.3])
    sim.step(0.1, t=0.0)
    np.testing.assert_allclose(sim.q, [1.0, -0.5, 0.3])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"lower": UPPER, "upper": LOWER}, "lower > upper"),
        ({"command_timeout_s": 0.0}, "command_timeout_s"),
        ({"velocity_limit": np.array([1.0, 0.0, 1.0])}, "velocity_limit"),
        ({"q0": np.zeros(2)}, "q0"),
    ],
)
def test_bad_construction_is_a_value_error(kwargs, match):
    args = {"lower": LOWER, "upper": UPPER, "q0": np.zeros(3), **kwargs}
    with pytest.raises(ValueError, match=match):
        KinematicSim(args.pop("lower"), args.pop("upper"), args.pop("q0"), **args)
