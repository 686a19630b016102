"""Robot configs and the nodes' robot/joints precedence (ROS-free)."""

import numpy as np
import pytest

from policy_align_ros.kinematics import Robot, constraint_from_spec
from policy_align_ros.kinematics.robot import robots_dir
from policy_align_ros.kinematics.robot_config import (
    learning_robot,
    load_robot_config,
    resolve_robot_setup,
    shipped_robot_configs,
)

PANDA = [f"panda_joint{i}" for i in range(1, 8)]


@pytest.mark.parametrize("name", ["talos", "panda", "ur5"])
def test_shipped_configs_load_on_their_robot(name):
    config = load_robot_config(name)
    assert name in shipped_robot_configs()
    robot = Robot.load(config.robot, config.joints)
    assert robot.joint_names == config.joints
    for frame in [config.tool, *config.hands, *config.constraint_frames]:
        robot.frame_id(frame)  # raises for an unknown frame
    q = robot.neutral() if config.home is None else np.array(config.home)
    assert np.all(q >= robot.lower) and np.all(q <= robot.upper)
    constraint = constraint_from_spec(config.unseen_constraint, robot)
    assert np.linalg.matrix_rank(constraint.matrix(q)) >= 1


def test_a_config_file_by_path_with_a_relative_urdf(tmp_path):
    urdf = robots_dir() / "ur_description" / "urdf" / "ur5_robot.urdf"
    (tmp_path / "my.urdf").write_bytes(urdf.read_bytes())
    path = tmp_path / "mine.yaml"
    path.write_text("robot: my.urdf\njoints: [shoulder_pan_joint, elbow_joint]\n"
                    "controller: /arm_controller\n")
    config = load_robot_config(str(path))
    assert config.robot == str(tmp_path / "my.urdf") and config.controller == "/arm_controller"
    setup = resolve_robot_setup(robot_config=str(path))
    assert setup.joints == ["shoulder_pan_joint", "elbow_joint"]
    assert Robot.load(setup.robot, setup.joints).nq == 2


@pytest.mark.parametrize("text, field", [
    ("robot: panda\n", "joints"),
    ("robot: panda\njoints: [a, a]\n", "twice"),
    ("robot: panda\njoints: [a]\nhome: [0.1, 0.2]\n", "home"),
    ("robot: panda\njoints: [a]\ncolour: red\n", "colour"),
    ("- just a list\n", "mapping"),
])
def test_malformed_config_files_name_the_field(tmp_path, text, field):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=field):
        load_robot_config(str(path))


def test_an_unknown_config_name_lists_the_shipped_ones():
    with pytest.raises(ValueError, match="panda"):
        load_robot_config("pand")


def test_explicit_parameters_come_first():
    setup = resolve_robot_setup("panda", ["panda_joint2", "panda_joint1"], "ur5",
                                ("talos", ["torso_1_joint"]))
    assert setup.robot == "panda" and setup.joints == ["panda_joint2", "panda_joint1"]
    assert setup.sources == {"robot": "parameter", "joints": "parameter"}


def test_the_model_file_comes_before_the_robot_config():
    setup = resolve_robot_setup(model=("panda", PANDA[::-1]))
    assert setup.robot == "panda" and setup.sources["joints"] == "model file"
    assert setup.joints == PANDA  # the same joints: in the config's (controller) order
    few = resolve_robot_setup(model=("panda", PANDA[:3]))
    assert few.robot == "panda" and few.joints == PANDA[:3] and not few.model_refused
    # A file written before the robot field: its joints, the explicit robot.
    old = resolve_robot_setup("panda", model=(None, PANDA[:2]))
    assert old.joints == PANDA[:2] and old.sources["joints"] == "model file"
    # A model of another robot gives no joints: the robot config's.
    other = resolve_robot_setup("panda", model=("talos", ["torso_1_joint"]))
    assert other.joints == PANDA and other.sources["joints"] == "robot config panda"


def test_a_model_contradicting_the_robot_config_given_is_left_out():
    talos = load_robot_config("talos")
    # Another robot: the config's robot and joints; the reason names both sides.
    setup = resolve_robot_setup(robot_config="talos", model=("panda", PANDA[:3]))
    assert setup.robot == "talos" and setup.joints == talos.joints
    assert setup.sources == {"robot": "robot config talos", "joints": "robot config talos"}
    for item in ("'panda'", PANDA[2], "'talos'", talos.joints[-1], "robot_config",
                 "-p robot:=", "-p joints:="):
        assert item in setup.model_refused, item
    # The config's robot but other joints, also from a file naming no robot, and with
    # the robot explicit but the joints left to the model.
    for kwargs in ({"model": ("panda", PANDA[:3])}, {"model": (None, PANDA[:3])},
                   {"robot": "panda", "model": ("panda", PANDA[:3])}):
        setup = resolve_robot_setup(robot_config="panda", **kwargs)
        assert setup.joints == PANDA and PANDA[2] in setup.model_refused, kwargs
    # No conflict: the config's joints in another order; no robot_config given; explicit
    # joints; an explicit robot that the config is not for.
    same = resolve_robot_setup(robot_config="panda", model=("panda", PANDA[::-1]))
    assert same.joints == PANDA and not same.model_refused
    explicit = resolve_robot_setup("panda", PANDA[:3], "panda", ("panda", PANDA[:3]))
    assert explicit.joints == PANDA[:3] and not explicit.model_refused
    other = resolve_robot_setup("panda", robot_config="talos", model=("panda", PANDA[:3]))
    assert other.joints == PANDA[:3] and not other.model_refused


def test_the_robot_config_comes_last_and_talos_when_nothing_is_named():
    assert resolve_robot_setup("panda").joints == PANDA
    ur5 = resolve_robot_setup(robot_config="ur5")
    assert ur5.robot == "ur5" and len(ur5.joints) == 6 and ur5.config.home is not None
    default = resolve_robot_setup()
    assert default.robot == "talos" and len(default.joints) == 18
    assert default.controller == "/velocity_controller"


def test_unknown_joints_are_an_error_naming_the_fix():
    urdf = str(robots_dir() / "ur_description" / "urdf" / "ur5_robot.urdf")
    for kwargs in ({"robot": urdf}, {"robot": "panda", "robot_config": "ur5"},
                   {"robot": "ur10"}):
        with pytest.raises(ValueError, match="robot_config") as err:
            resolve_robot_setup(**kwargs)
        assert "joints" in str(err.value)
    # An unknown robot name is named as such, with the closest known names.
    with pytest.raises(ValueError, match=r"'pandas'.*\bpanda\b"):
        resolve_robot_setup("pandas")


def test_the_learner_takes_robot_and_joints_from_the_config_when_unset():
    assert learning_robot(None, None, "panda") == ("panda", PANDA)
    assert learning_robot(None, ["panda_joint1"], "panda") == ("panda", ["panda_joint1"])
    assert learning_robot("ur5", None, "panda") == ("ur5", None)
    assert learning_robot(None, None, "") == (None, None)
