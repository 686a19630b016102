"""What the ArmedController says about joint states it cannot use: stamps of another clock
(simulated time against the system clock, or the reverse) and a stamp that stops
advancing while messages keep arriving. Injected clock, no ROS.
"""

import numpy as np
from control_rigs import DT, DT_NS, LOWER, UPPER, VMAX, N, _Linear

from policy_align_ros.control import ArmedController, ControlStep, ZeroCause, clock_mismatch_hint

SYSTEM_NOW = 1_764_000_000 * 10**9  # a system clock, ns
SIM_STAMP = 100 * 10**9  # a simulation 100 s in


def _controller():
    step = ControlStep(LOWER, UPPER, VMAX, DT, policy=_Linear(np.zeros(N)))
    return ArmedController(step, 2.0, 0.1, 0.05)


def test_sim_time_stamps_on_the_system_clock_suggest_use_sim_time():
    control = _controller()
    out = control.joint_state(np.zeros(N), SIM_STAMP, SYSTEM_NOW)
    assert out.rejected == "stamp_too_old"
    accepted, refusal, _ = control.arm(SYSTEM_NOW)
    assert not accepted and control.arm_check(SYSTEM_NOW)[0] == ZeroCause.STAMP_TOO_OLD
    assert "-p use_sim_time:=true" in refusal  # the parameter that fixes it


def test_system_stamps_on_a_simulated_clock_suggest_the_reverse():
    control = _controller()
    out = control.joint_state(np.zeros(N), SYSTEM_NOW, SIM_STAMP)
    assert out.rejected == "stamp_in_future"
    assert "use_sim_time:=false" in control.arm(SIM_STAMP)[1]


def test_small_offsets_and_other_rejections_carry_no_clock_hint():
    control = _controller()
    now = SYSTEM_NOW
    assert control.joint_state(np.zeros(N), now - 2 * 10**9, now).rejected == "stamp_too_old"
    assert "use_sim_time" not in control.arm(now)[1]  # 2 s late: a delay, not a clock
    assert control.joint_state(np.zeros(N), 0, now).rejected == "zero_stamp"
    assert "use_sim_time" not in control.arm(now)[1]
    assert clock_mismatch_hint("zero_stamp", 0, now) == ""
    assert clock_mismatch_hint("stamp_too_old", now - 10**9, now) == ""
    assert "use_sim_time:=true" in clock_mismatch_hint("stamp_too_old", SIM_STAMP, now)
    # Both on the system clock, a minute apart: unsynchronised clocks, not sim time.
    hint = clock_mismatch_hint("stamp_too_old", now - 60 * 10**9, now)
    assert hint and "use_sim_time:=true" not in hint


def test_a_frozen_stamp_is_told_apart_from_messages_that_stop():
    control = _controller()
    t = SYSTEM_NOW
    control.joint_state(np.zeros(N), t, t)
    assert control.arm(t)[0]
    # Messages every period with the same stamp: stale after the timeout, as "frozen".
    for k in range(1, 15):
        control.joint_state(np.zeros(N), t, t + k * DT_NS)
        out = control.tick(t + k * DT_NS)
    assert not control.armed and out.zero_cause == ZeroCause.FROZEN_STAMP
    # The messages stop too: then it reads as joint states no longer received.
    later = t + 40 * DT_NS
    assert control.state_check(later)[0] == ZeroCause.STALE_STATE
    # A new stamp clears it.
    control.joint_state(np.zeros(N), later, later)
    assert control.state_check(later) == (None, "") and control.state_problem(later) == ""


def test_a_restarted_simulation_is_told_as_such_not_as_unsynchronised_clocks():
    # Armed at 19 s of simulated time; the simulation restarts: the first joint state of
    # the new run (stamped 2 s) comes before the /clock message that takes the node back.
    control = _controller()
    t = 19 * 10**9
    control.joint_state(np.zeros(N), t, t)
    assert control.arm(t)[0]
    out = control.joint_state(np.zeros(N), 2 * 10**9, t + DT_NS)
    assert out.rejected == "stamp_backwards" and not control.armed
    hint = clock_mismatch_hint(out.rejected, 2 * 10**9, t + DT_NS)
    assert hint and "use_sim_time" not in hint  # no parameter is wrong
    # Stamps ahead of a simulated node clock are no restart: a /clock that stalled.
    assert clock_mismatch_hint("stamp_in_future", t + 10**10 + 1, 10**9) != hint
    # Then the node clock follows: the jump, not the stamp, is said to be the cause.
    out = control.tick(2 * 10**9 + DT_NS)
    assert control.zero_cause == ZeroCause.CLOCK_JUMPED_BACK
    assert [level for level, _ in out.events] == ["warning"]  # and it is logged


def test_a_fault_long_before_a_restart_keeps_its_cause():
    # The joint states stopped (stale) ten minutes before the simulation restarted: the
    # restart did not cause that fault, and /diagnostics keeps saying what did.
    control = _controller()
    t = 19 * 10**9
    control.joint_state(np.zeros(N), t, t)
    assert control.arm(t)[0]
    control.tick(t + 10**9)
    assert control.zero_cause == ZeroCause.STALE_STATE
    control.tick(t + 600 * 10**9)  # ten minutes of control periods on, still stale
    control.tick(2 * 10**9)  # the restart
    assert control.zero_cause == ZeroCause.STALE_STATE
