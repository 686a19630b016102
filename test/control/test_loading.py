"""A model file as the executor's policy (policy_align_ros.control.loading), read once at
start. ROS-free."""

import json
import re
from types import SimpleNamespace

import numpy as np
import pytest

from policy_align_ros.control import (
    ExtrapolationGuard,
    StartModel,
    SupportDistance,
    goal_margin_problem,
    learnt_goal,
    load_policy,
    model_guard,
    model_load_error,
    model_turn_centres,
    no_model_fix,
)
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
    with pytest.raises(ValueError, match=re.escape(str(bad)) + ".*'offsets'"):
        load_policy(str(bad), Robot.load("panda", JOINTS))
    with pytest.raises(FileNotFoundError):
        start.robot_fields(str(tmp_path / "missing.npz"))


def _goal_model(minima, rests, state=None, ends=None):
    goal = {"minima": [{"point": p} for p in minima],
            "demonstrated_goals": [{"point": p} for p in rests]}
    for entry, end in zip(goal["minima"], ends or (), strict=False):
        entry["end_distance"] = end
    return SimpleNamespace(fit_summary_={"goal": goal}, state_definition_=state)


def test_the_learnt_goal_is_the_minimum_nearest_where_the_demonstrations_rest():
    minima = [[1.0, 1.0], [0.1, -0.05]]  # lowest first, as goal_summary lists them
    np.testing.assert_array_equal(learnt_goal(_goal_model(minima, [[0.0, 0.0]])), minima[1])
    # Without a place where most rest: the minimum nearest where they end, not the lowest.
    np.testing.assert_array_equal(learnt_goal(_goal_model(minima, [], ends=[2.0, 0.1])),
                                  minima[1])
    # A report that does not give the distances to the ends: the lowest.
    np.testing.assert_array_equal(learnt_goal(_goal_model(minima, [])), minima[0])
    assert learnt_goal(_goal_model([], [[0.0, 0.0]])) is None
    assert learnt_goal(SimpleNamespace()) is None


def test_a_learnt_goal_at_a_limit_is_named_by_the_executors_joint():
    # The model's joints are the executor's in reverse order: the joint at its limit is
    # the model's first, the executor's second.
    robot = SimpleNamespace(lower=np.array([-1.0, 0.0]), upper=np.array([1.0, 2.0]),
                            joint_names=["a", "b"])
    perm = np.array([1, 0])
    at_limit = _goal_model([[0.01, 0.5]], [[0.0, 0.5]])
    # Read in the model's order, both joints would be inside their limits.
    assert "b" in goal_margin_problem(at_limit, perm, robot, 0.05)
    assert goal_margin_problem(_goal_model([[0.5, 0.5]], []), perm, robot, 0.05) == ""
    # A goal in frame positions is no posture to check.
    frames = _goal_model([[0.01, 0.5]], [], state={"type": "frames"})
    assert goal_margin_problem(frames, perm, robot, 0.05) == ""


def test_a_model_file_that_does_not_load_at_start_is_named_with_the_fix(tmp_path,
                                                                         monkeypatch):
    monkeypatch.chdir(tmp_path)
    try:
        PolicyAlign.load("nosuch.npz")
    except FileNotFoundError as err:
        text = model_load_error("nosuch.npz", err)
    # The parameter, the file, where a relative path was looked for, and the other way out.
    assert text.startswith("model_path") and "nosuch.npz" in text
    assert str(tmp_path) in text and "/learner/model" in text
    text = model_load_error("/abs/other.npz", ValueError("trained on other joints"))
    assert "trained on other joints" in text and str(tmp_path) not in text


@pytest.mark.parametrize("follows", [True, False])
def test_an_enable_without_a_model_names_the_ways_to_load_one(follows):
    text = no_model_fix("/ns/executor", follows)
    assert "policy-align param set /ns/executor model_path" in text
    assert "/learner/model" in text
    assert ("follow_learner" in text) is not follows  # the switch, when it is off


# -- the executor's decisions about the model file given at start -----------------------
def test_a_start_model_refused_for_the_robot_config_is_named_released_and_cleared(
        model_file):
    why = "it names robot panda, robot_config talos"
    start = StartModel(refused=why)
    start.robot_fields(model_file)  # read for the robot fields before the refusal
    line = start.refusal(model_file)
    assert model_file in line and why in line  # the file and the reason
    assert start.take(model_file) is None  # the model read for it is released
    assert start.given(model_file)  # model_path must then read empty
    # Not refused: nothing to say, the model stays for the load, model_path stays.
    kept = StartModel()
    kept.robot_fields(model_file)
    assert kept.refusal(model_file) == ""
    assert isinstance(kept.take(model_file), PolicyAlign)
    assert not kept.given(model_file)
    # Refused, but no model_path given (the refusal came from the robot config alone).
    assert not StartModel(refused=why).given("")


def test_a_start_model_that_does_not_load_keeps_the_start_up_error(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    start = StartModel()
    assert start.load_error == ""
    try:
        PolicyAlign.load("nosuch.npz")
    except FileNotFoundError as err:
        start.load_failed("nosuch.npz", err)
    # The same error as model_load_error's, which names the file and the fix.
    assert start.load_error and "nosuch.npz" in start.load_error
    assert str(tmp_path) in start.load_error


@pytest.mark.parametrize("given, follow_learner, follows", [
    ("", False, True),  # no model_path at start: the learner's models are loaded
    ("", True, True),
    ("model.npz", False, False),  # an explicit model file wins
    ("model.npz", True, True),  # unless asked to follow the learner
])
def test_the_learner_is_followed_unless_a_model_file_was_given_at_start(given,
                                                                        follow_learner,
                                                                        follows):
    start = StartModel()
    start.given(given)
    assert start.given_path == given
    assert start.follows_learner(follow_learner) is follows


def test_a_refused_start_model_still_wins_over_the_learner(model_file):
    # The file named is the one meant: refused for the robot config, it is not replaced
    # by the learner's model unless asked.
    start = StartModel(refused="contradicts robot_config")
    assert start.given(model_file)
    assert not start.follows_learner(False)
    assert start.follows_learner(True)


def test_an_ignored_announcement_names_the_model_given_and_the_switch():
    start = StartModel()
    start.given("mine.npz")
    note = start.ignored_announcement("/tmp/learnt.npz")
    assert "/tmp/learnt.npz" in note and "mine.npz" in note
    assert "follow_learner" in note


# -- what a newly loaded model sets up ---------------------------------------------------
def test_a_joint_state_model_gets_a_guard_on_its_joint_space_data(model_file):
    robot = Robot.load("panda", JOINTS)
    model, policy, perm, state = load_policy(model_file, robot)
    guard, problem = model_guard(model, policy, perm, state, 4.0, 0.7)
    assert problem == "" and isinstance(guard, ExtrapolationGuard)
    assert isinstance(guard.distance, SupportDistance)
    assert guard.max_extrapolation == 4.0 and guard.max_extrapolation_rad == 0.7


def test_a_model_that_cannot_have_a_guard_is_run_without_one_and_says_why():
    # A frames model whose policy has no state map: no distance to its data.
    guard, problem = model_guard(SimpleNamespace(), lambda x: x, np.arange(2), "frames a",
                                 4.0, 0.7)
    assert guard is None and problem


def test_turn_centres_come_from_a_joint_state_models_support_only():
    robot = SimpleNamespace(continuous=np.array([False, True]))
    model = SimpleNamespace(support_states_=np.array([[0.0, 3.0], [1.0, 4.0]]))
    perm = np.array([1, 0])  # the model's joints are the executor's in reverse order
    centres = model_turn_centres(model, "joints", robot, perm)
    # The executor's continuous second joint is the model's first, whose middle is 0.5.
    assert np.isnan(centres[0]) and centres[1] == 0.5
    # A frames model sees the joints through the kinematics, on every turn alike.
    assert model_turn_centres(model, "frames a", robot, perm) is None
    assert model_turn_centres(SimpleNamespace(), "joints", robot, perm) is None
