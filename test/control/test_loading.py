"""A model file as the executor's policy (policy_align_ros.control.loading), read once at
start. ROS-free."""

import json

import numpy as np
import pytest

from policy_align_ros.control import StartModel, load_policy
from policy_align_ros.experiments.toy import make_toy_dataset
from policy_align_ros.kinematics import Robot
from policy_align_ros.learning import PolicyAlign, model_io

JOINTS = ["panda_joint1", "panda_joint2"]


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    data = make_toy_dataset("sinusoid", 10, 25, np.random.default_rng(0))
    model = PolicyAlign(sigma="medium").fit(data.trajectories, joint_names=JOINTS)
    model.robot_ = "panda"
    return str(model.save(tmp_path_factory.mktemp("loading") / "model.npz"))


@pytest.fixture
def reads(monkeypatch):
    """The paths model_io.load_npz reads (header alone or the whole file)."""
    seen = []
    load_npz = model_io.load_npz
    monkeypatch.setattr(model_io, "load_npz",
                        lambda *a, **k: seen.append(str(a[0])) or load_npz(*a, **k))
    return seen


def test_the_start_model_gives_robot_fields_and_the_model_from_one_read(model_file, reads):
    start = StartModel()
    assert start.robot_fields(model_file) == ("panda", JOINTS)
    assert start.take("other.npz") is None  # another path: not this model
    assert start.robot_fields(model_file) == ("panda", JOINTS)
    model = start.take(model_file)
    assert isinstance(model, PolicyAlign) and model.joint_names_ == JOINTS
    assert start.take(model_file) is None  # given once
    assert reads == [model_file, model_file]  # one read per robot_fields call
    robot = Robot.load("panda", JOINTS)
    loaded, policy, perm, state = load_policy(model_file, robot, model=model)
    assert loaded is model and state == "joints" and perm.tolist() == [0, 1]
    assert len(reads) == 2  # the model given is not read again
    X = np.array([[0.1, -0.2]])
    np.testing.assert_array_equal(policy(X), PolicyAlign.load(model_file).policy(X))


def test_a_file_that_does_not_load_still_names_its_robot_from_its_header(model_file,
                                                                          tmp_path):
    header, arrays = model_io.load_npz(model_file, "policy_align")
    bad = tmp_path / "bad.npz"
    del arrays["offsets"]
    np.savez(bad, __header__=np.array(json.dumps(header)), **arrays)
    start = StartModel()
    assert start.robot_fields(str(bad)) == ("panda", JOINTS)
    assert start.take(str(bad)) is None
    with pytest.raises(ValueError, match="malformed"):
        load_policy(str(bad), Robot.load("panda", JOINTS))
    with pytest.raises(FileNotFoundError):
        start.robot_fields(str(tmp_path / "missing.npz"))
