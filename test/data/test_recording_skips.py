"""The recorder's skip report (policy_align_ros.data.recording.describe_skips)."""

from policy_align_ros.data.recording import describe_skips


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
