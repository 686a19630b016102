"""Tests of policy_align_ros.data.learn (``policy-align learn``'s own output)."""

import re
import warnings

from policy_align_ros.data.learn import warning_lines


def _warning(message, category=UserWarning):
    return warnings.WarningMessage(message, category, "fit_stages.py", 280)


def test_warning_lines_say_each_text_once_and_count_numerical_warnings():
    caught = [_warning("poor fit"), _warning("overflow encountered in exp", RuntimeWarning),
              _warning("no minimum"), _warning("poor fit"),
              *[_warning(f"numerical {k % 5}", RuntimeWarning) for k in range(40)]]
    lines = warning_lines(caught)
    assert lines[:2] == ["poor fit", "no minimum"] and len(lines) == 3
    # One line for all 41: their count and the first kinds, not 41 lines.
    assert re.search(r"\b41\b", lines[2]) and "overflow encountered in exp" in lines[2]
    assert warning_lines([]) == []
