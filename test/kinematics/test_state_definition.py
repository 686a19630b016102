"""Tests of policy_align_ros.kinematics.state_definition."""

import json

import pytest
from task_space_rigs import ARM, ELBOW, HAND

from policy_align_ros.kinematics import FrameStateDefinition, Robot
from policy_align_ros.kinematics.robot import robots_dir


def test_definition_round_trips_and_matches_same_robot(robot: Robot) -> None:
    defn = FrameStateDefinition.from_robot(robot, [HAND, ELBOW])
    assert defn.dim == 6
    text = json.dumps(defn.to_dict())
    back = FrameStateDefinition.from_dict(json.loads(text))
    assert back == defn
    back.check(robot)
    urdf = robots_dir() / "talos_data" / "robots" / "talos_reduced.urdf"
    same = Robot.load(str(urdf), joints=ARM, reference={
        j: v[0] for j, v in robot.locked_posture.items() if len(v) == 1})
    defn.check(same)
    loaded = defn.load_robot()
    assert loaded.joint_names == ARM


def test_definition_check_names_what_differs(robot: Robot) -> None:
    defn = FrameStateDefinition.from_robot(robot, [HAND])
    with pytest.raises(ValueError, match=r"\bjoints\b.*\['torso_2_joint'\]"):
        defn.check(Robot.load("talos", joints=ARM[:-1]))
    with pytest.raises(ValueError, match=r"\bjoints\b"):
        defn.check(Robot.load("talos", joints=ARM[::-1]))
    with pytest.raises(ValueError, match=r"\['arm_right_4_joint'\]"):
        defn.check(Robot.load("talos", joints=ARM, reference={"arm_right_4_joint": -1.0}))
    with pytest.raises(ValueError, match="URDF"):
        defn.check(Robot.load("panda"))


@pytest.mark.parametrize(("change", "message"), [
    ({"type": "joints"}, r"'type'.*'frames'"),
    ({"frames": "gripper"}, "'frames'.*'gripper'"),
    ({"frames": []}, r"'frames'.*\[\]"),
    ({"urdf_sha256": 5}, "'urdf_sha256'.*5"),
    ({"locked_posture": {"a": ["x"]}}, r"locked_posture\['a'\].*'x'"),
    ({"locked_posture": {"a": [float("nan")]}}, r"locked_posture\['a'\]"),
    ({"locked_posture": None}, "'locked_posture'"),
    (None, "'root_frame'"),
])
def test_definition_from_dict_refuses_bad_fields(robot: Robot, change, message) -> None:
    data = FrameStateDefinition.from_robot(robot, [HAND]).to_dict()
    if change is None:
        del data["root_frame"]
    else:
        data.update(change)
    with pytest.raises(ValueError, match=message):
        FrameStateDefinition.from_dict(data)
