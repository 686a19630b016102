"""The learn pipeline's arguments (policy_align_ros.data.arguments). ROS-free."""

from __future__ import annotations

import pytest

from policy_align_ros.data.arguments import (
    HOLDOUT_RANGE,
    SIGMA_RULES,
    check_writable,
    parse_sigma,
    state_name,
)


def test_sigma_is_a_rule_or_a_positive_number_and_a_bad_one_is_named():
    assert [parse_sigma(rule.upper()) for rule in SIGMA_RULES] == list(SIGMA_RULES)
    assert parse_sigma("0.25") == 0.25
    for bad in ("huge", "0", "-1", "nan", "inf"):
        with pytest.raises(ValueError, match="sigma") as err:
            parse_sigma(bad)
        assert repr(bad) in str(err.value)


def test_the_state_is_joints_or_checked_frames():
    assert state_name("joints") == "joints"
    assert state_name("frames: a, b") == "frames:a,b"
    with pytest.raises(ValueError, match="^state") as err:
        state_name("frames:a,a")  # a frame twice
    assert "frames:a,a" in str(err.value)


def test_a_file_is_writable_where_a_file_can_be_created(tmp_path):
    check_writable(tmp_path / "new" / "dir" / "model.npz")  # parents are created on writing
    with pytest.raises(ValueError, match="model_path") as err:
        check_writable(tmp_path)  # a directory
    assert str(tmp_path) in str(err.value)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ValueError, match="--plot") as err:
        check_writable(blocker / "fit.png", "--plot")  # under a file
    assert str(blocker) in str(err.value)
    assert HOLDOUT_RANGE[0] == 0.0 and HOLDOUT_RANGE[1] <= 0.5  # half at least trains


def test_a_frames_state_is_checked_against_its_robot_naming_the_wrong_parameter():
    from policy_align_ros.data.arguments import check_state_frames

    check_state_frames("joints", None)  # nothing to check
    check_state_frames("frames:arm_left_7_link", "talos")
    with pytest.raises(ValueError, match=r"^state\b.*'nosuch'"):
        check_state_frames("frames:nosuch", "talos")
    with pytest.raises(ValueError, match=r"^robot\b.*'tals'"):  # the robot, not the state
        check_state_frames("frames:arm_left_7_link", "tals")
    with pytest.raises(ValueError, match=r"^robot\b"):
        check_state_frames("frames:arm_left_7_link", None)
