"""Tests of policy_align_ros.control.causes: the zero-command causes are stable identifiers
that cover the controller's joint-state rejections and are documented."""

import re
from pathlib import Path

from policy_align_ros.control import (
    IMPLAUSIBLE_POSITION,
    NO_CAUSE,
    STAMP_REJECTIONS,
    ZeroCause,
)
from policy_align_ros.data.messages import UNTRUSTWORTHY

SAFETY_DOC = Path(__file__).resolve().parents[2] / "docs" / "executor_safety.md"


def test_causes_are_distinct_snake_case_identifiers():
    values = [cause.value for cause in ZeroCause]
    assert len(set(values)) == len(values)
    assert all(re.fullmatch(r"[a-z][a-z_]*", value) for value in values)
    assert NO_CAUSE not in values  # "none" on /diagnostics cannot be mistaken for a cause
    assert ZeroCause("stall") is ZeroCause.STALL  # read back from /diagnostics


def test_every_rejection_key_is_a_cause():
    # The executor counts rejected joint states by these keys and disarms with the cause
    # of the same name: a key without one would raise in its joint-state callback.
    for key in (*STAMP_REJECTIONS, IMPLAUSIBLE_POSITION, *UNTRUSTWORTHY):
        assert ZeroCause(key).value == key


def test_every_cause_is_documented():
    text = SAFETY_DOC.read_text()
    missing = [cause.value for cause in ZeroCause if f"`{cause.value}`" not in text]
    assert missing == []
