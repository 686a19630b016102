"""Tests of policy_align_ros.data.messages' JointState-to-vector conversion (ROS-free)."""

from array import array

import numpy as np
import pytest

from policy_align_ros.data.messages import (
    NEW,
    SAME,
    SKIP,
    SKIP_REASONS,
    UNTRUSTWORTHY,
    JointSelector,
    StreamClock,
    UnusableReasons,
    describe_foreign,
    describe_skips,
    validate_joint_names,
)


def test_vector_matches_joints_by_name_and_ignores_extra_joints():
    sel = JointSelector(["b", "a"])
    q = sel.vector(["a", "x", "b"], array("d", [1.0, 9.0, 2.0]), array("d", [0.1, 0.2, 0.3]))
    assert isinstance(q, np.ndarray) and q.dtype == float
    np.testing.assert_array_equal(q, [2.0, 1.0])
    # A new array every time: the caller may keep it while the message buffer is reused.
    buf = array("d", [1.0, 2.0])
    q = sel.vector(["a", "b"], buf)
    buf[0] = 5.0
    np.testing.assert_array_equal(q, [2.0, 1.0])


@pytest.mark.parametrize("names, positions, velocities, efforts, reason", [
    # A joint twice, the second with another value: which one would be the truth?
    (["a", "b", "a"], [1.0, 2.0, 3.0], [], [], "duplicate_joints"),
    (["a", "b", "a"], [1.0, 2.0, 1.0], [], [], "duplicate_joints"),
    (["a", "b"], [1.0], [], [], "length_mismatch"),
    (["a", "b"], [1.0, 2.0, 3.0], [], [], "length_mismatch"),
    (["a", "b"], [1.0, 2.0], [0.0], [], "length_mismatch"),
    (["a", "b"], [1.0, 2.0], [], [0.0, 0.0, 0.0], "length_mismatch"),
    (["a", "b"], [1.0, float("nan")], [], [], "non_finite"),
    (["a", "b"], [1.0, float("inf")], [], [], "non_finite"),
    (["a", "b"], [1.0, 2.0], [0.0, float("nan")], [], "non_finite"),
    (["x", "y"], [1.0, 2.0], [], [], "unknown_joints"),
    (["a", "x"], [1.0, 2.0], [], [], "missing_joints"),
])
def test_vector_rejects_what_select_rejects(names, positions, velocities, efforts, reason):
    sel = JointSelector(["a", "b"])
    assert sel.vector(names, positions, velocities, efforts) == reason
    # One set of rules: the list conversion (recorder, bags) gives the same reason.
    assert sel.select(names, positions, velocities, efforts) == reason
    assert reason in SKIP_REASONS
    assert (reason in UNTRUSTWORTHY) == (reason not in ("unknown_joints", "missing_joints"))


def test_vector_ignores_nan_in_joints_it_does_not_use():
    sel = JointSelector(["a"])
    np.testing.assert_array_equal(sel.vector(["a", "z"], [1.0, float("nan")]), [1.0])


def test_vector_after_a_cached_name_list_changes_selection():
    sel = JointSelector(["a", "b"])
    np.testing.assert_array_equal(sel.vector(["b", "a"], [2.0, 1.0]), [1.0, 2.0])
    sel.set_joints(["b"])
    np.testing.assert_array_equal(sel.vector(["b", "a"], [2.0, 1.0]), [2.0])
    for k in range(100):  # more name lists than the cache holds: still right
        names = ["b", f"extra_{k}"]
        np.testing.assert_array_equal(sel.vector(names, [float(k), 0.0]), [float(k)])


def test_joint_selector_and_clock_units():
    sel = JointSelector(["b", "a"])
    assert sel.select(["a", "b", "c"], [1.0, 2.0, 3.0], [4.0, 5.0, 6.0]) == ([2.0, 1.0],
                                                                             [5.0, 4.0])
    assert sel.select(["a", "b"], [1.0, 2.0], [], [1.0]) == "length_mismatch"
    open_sel = JointSelector(None)
    assert open_sel.select(["x"], [float("nan")]) == "non_finite"
    assert open_sel.select(["y"], [1.0]) == ([1.0], None)
    open_sel.commit(["y"])
    # The cache built while the selection was open must not leak into the fixed one.
    assert open_sel.select(["x"], [1.0]) == "unknown_joints"
    clock = StreamClock(gap_ns=100)
    assert clock.step(1000) == NEW
    clock.accept(1000)
    assert [clock.step(s) for s in (1050, 1000, 950, 1101, 850)] == [SAME, SKIP, SKIP, NEW,
                                                                     NEW]
    assert StreamClock(0).step(5) == NEW
    with pytest.raises(ValueError, match=r"^joints: .*'a'"):
        validate_joint_names(["a", "a"])
    with pytest.raises(ValueError, match=r"^joints: .*''"):
        validate_joint_names(["a", ""])
    assert validate_joint_names([]) is None


# -- The recorder's skip report (describe_skips) --
def test_only_reasons_that_occurred_are_counted():
    detail = describe_skips({"bad_names": 2, "time_not_increasing": 0, "nan": 1}, 0)
    assert detail == "bad_names=2, nan=1"
    assert describe_skips({"bad_names": 0}, 0) == ""


def test_clock_reasons_get_a_hint_and_paused_messages_are_counted():
    detail = describe_skips({"time_in_future": 3, "time_negative": 1}, 4)
    assert detail.startswith("time_in_future=3, time_negative=1 (")
    assert detail.count(" (time_") == 2
    assert detail.endswith(", paused_while_a_write_is_pending=4")
    assert describe_skips({}, 4) == "paused_while_a_write_is_pending=4"
    # Stamps that repeat or jump back (a paused or restarted simulation) get one each too.
    detail = describe_skips({"time_not_increasing": 2, "clock_reset": 1}, 0)
    assert detail.startswith("time_not_increasing=2, clock_reset=1 (")
    assert detail.count(" (") == 2


def test_a_message_skipped_for_its_joints_is_described_by_what_it_lacks_and_carries():
    # A typo in a configured joint: the missing one is named, and what the message carries.
    text = describe_foreign(["joint1", "jiont7"], ["joint1", "joint7", "gripper"])
    missing, carried = text.split(";")
    assert "'jiont7'" in missing and "'joint1'" not in missing and "1" in missing
    assert "'gripper'" in carried and "3" in carried
    arm = [f"joint{i}" for i in range(1, 8)]
    text = describe_foreign(arm, arm[:-1])  # the robot publishes joint1..joint6
    assert "'joint7'" in text and "'joint1'" in text and "6" in text
    # Another publisher's joints only: the selected joints it should carry, and the first
    # few it does, counted.
    many = [f"other{i}" for i in range(20)]
    text = describe_foreign(arm, many)
    assert "'joint1'" in text and "'other0'" in text and "'other19'" not in text
    assert "20" in text
    assert describe_foreign(arm, [])  # no names at all


def test_unusable_reasons_add_the_fix_and_keep_a_bounded_cache():
    reasons = UnusableReasons(["joint1", "joint2"], "FIX", size=2)
    first = reasons(["joint1"])
    assert first.startswith(describe_foreign(["joint1", "joint2"], ["joint1"]))
    assert first.endswith("FIX")
    assert reasons(("joint1",)) is first  # the same list of names: cached
    reasons(["a"])
    reasons(["b"])  # a third list clears the cache rather than growing it
    assert len(reasons._known) <= 2
    assert reasons(["joint1"]) == first
