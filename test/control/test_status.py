"""The executor's ~/enable answers and rejected-state notes (policy_align_ros.control.status).
ROS-free."""

import math

import pytest

from policy_align_ros.control import (
    ClockWatch,
    enable_answer,
    model_text,
    rejection_note,
    untrustworthy_reason,
)


def test_the_model_in_force_is_named_or_said_to_be_missing():
    assert "m.npz" in model_text("m.npz")
    assert model_text("") and model_text("") != model_text("m.npz")


@pytest.mark.parametrize("model_path", ["", "/tmp/m.npz"])
def test_an_enable_answer_carries_the_note_or_the_refusal_and_the_model(model_path):
    note = "; joint order check off (controller 'none')"
    accepted = enable_answer(True, "", note, model_path)
    assert accepted.endswith(note) and model_text(model_path) in accepted
    refused = enable_answer(False, "no joint state received", note, model_path)
    assert "no joint state received" in refused and note not in refused
    # The model is named when one is loaded (without one, the reason says so).
    assert (model_text(model_path) in refused) is bool(model_path)
    assert accepted != refused


@pytest.mark.parametrize("reason, routine", [
    ("unknown_joints", True),  # another publisher's joints on the same topic
    ("missing_joints", False), ("non_finite", False), ("time_not_increasing", False),
])
def test_only_foreign_joint_states_are_routine(reason, routine):
    got, text = rejection_note(reason, 3, "publish them all")
    assert got is routine
    assert reason in text and "3" in text and "publish them all" in text
    assert rejection_note(reason, 3)[1] in text  # the hint only adds to the note


JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]


def test_a_non_finite_joint_state_names_the_joint_and_the_field():
    names = ["gripper", *JOINTS]  # another publisher's joint first, also broken
    positions = [math.nan, 0.1, math.nan, 0.3]
    velocities = [0.0, 0.0, 0.0, math.inf]
    reason = untrustworthy_reason("non_finite", JOINTS, names, positions, velocities)
    assert reason.startswith("untrustworthy joint state: non_finite")
    assert "shoulder_lift_joint position nan" in reason and "elbow_joint velocity inf" in reason
    # Only the controlled joints count (the message's others are not checked).
    assert "gripper" not in reason and "shoulder_pan_joint" not in reason


def test_duplicate_names_and_lengths_are_named_too():
    reason = untrustworthy_reason("duplicate_joints", JOINTS, [*JOINTS, "elbow_joint"],
                                  [0.0] * 4)
    assert "'elbow_joint' 2 times" in reason and "shoulder_pan_joint" not in reason
    reason = untrustworthy_reason("length_mismatch", JOINTS, JOINTS, [0.0] * 2, [0.0])
    assert all(f"{n} {what}" in reason for n, what in ((3, "names"), (2, "positions"),
                                                       (1, "velocities"), (0, "efforts")))


def test_a_node_clock_that_stands_still_is_told_after_a_period():
    watch = ClockWatch(period_ns=10**9)
    assert watch.update(5 * 10**9, 100 * 10**9) == "advancing"
    assert watch.update(6 * 10**9, 101 * 10**9) == "advancing"
    # Paused: the node clock stays at 6 s while the steady clock runs on.
    assert watch.update(6 * 10**9, 101 * 10**9 + 5 * 10**8) == "advancing"
    assert watch.update(6 * 10**9, 104 * 10**9) != "advancing"
    assert watch.update(6 * 10**9 + 1, 104 * 10**9 + 1) == "advancing"  # resumed
    # use_sim_time before the first /clock message: not a pause, and said at once.
    assert ClockWatch(period_ns=10**9).update(0, 100 * 10**9) != "advancing"
