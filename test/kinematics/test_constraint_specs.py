"""The ``constraints`` parameter's text -> constraint specs
(policy_align_ros.kinematics.constraints.parse_constraint_specs)."""

import pytest

from policy_align_ros.kinematics.constraints import parse_constraint_specs


@pytest.mark.parametrize("text", ["", "  ", "[]", "null"])
def test_empty_text_means_no_constraint(text):
    assert parse_constraint_specs(text) == []


def test_a_list_of_mappings_and_a_single_mapping():
    specs = parse_constraint_specs("[{type: plane, frame: f, normal: [0, 0, 1]}, "
                                   '{"type": "joints", "joints": ["a"]}]')
    assert specs == [{"type": "plane", "frame": "f", "normal": [0, 0, 1]},
                     {"type": "joints", "joints": ["a"]}]
    assert parse_constraint_specs("{type: position, frame: f}") == [
        {"type": "position", "frame": "f"}]


@pytest.mark.parametrize("text", ["[{type: plane", "[1, 2]", "plane", "[{a: 1}, 3]"])
def test_text_that_is_not_a_list_of_mappings_is_refused(text):
    with pytest.raises(ValueError, match="constraints"):
        parse_constraint_specs(text)
