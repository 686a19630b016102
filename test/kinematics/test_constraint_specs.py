"""The ``constraints`` parameter's text -> constraint specs
(policy_align_ros.kinematics.constraints.parse_constraint_specs)."""

import re

import pytest
import yaml

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


@pytest.mark.parametrize("value", [None, [], ()])
def test_no_value_and_an_empty_list_mean_no_constraint(value):
    # rcl passes ``-p constraints:=[]`` as None (a list whose type it cannot tell).
    assert parse_constraint_specs(value) == []


@pytest.mark.parametrize("value", [5, 1.5, True, ["a"], [{"type": "position", "frame": "f"}]])
def test_a_value_of_another_type_is_refused_with_the_form_the_parameter_takes(value):
    with pytest.raises(ValueError, match="constraints") as err:
        parse_constraint_specs(value)
    # The form it names, as rcl passes it once the shell's and YAML's quotes are gone,
    # gives specs.
    quoted = re.search(r"""constraints:="(.*?)"'""", str(err.value))
    assert quoted is not None
    assert parse_constraint_specs(yaml.safe_load(f'"{quoted.group(1)}"')) == [
        {"type": "position", "frame": "tool0"}]
