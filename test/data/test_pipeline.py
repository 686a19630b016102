"""The one learning pipeline (policy_align_ros.data.pipeline). ROS-free.

Datasets are rosbag2 bags of 2-D demonstrations (joints ``j1``, ``j2``, 20 Hz) of
``pi = -grad phi`` under a random line constraint, re-drawn half way, written with
:func:`write_joint_state_bag`; the frames test records talos arm joint states.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import shutil
import subprocess
import sys
import warnings

import numpy as np
import pytest

from policy_align_ros.data import write_joint_state_bag
from policy_align_ros.data.learn import run_learn
from policy_align_ros.data.pipeline import HOLDOUT_RANGE, learn_pipeline, state_name
from policy_align_ros.data.quality import Gates
from policy_align_ros.data.selection import find_duplicates, holdout_split
from policy_align_ros.learning import PolicyAlign

JOINTS = ["j1", "j2"]
DT_NS = 50_000_000


def _bowl(x):  # phi = |x|^2 / 2
    return -x


def _ripple(x):  # phi = |x|^2 / 2 + 0.6 sin(2 x1) sin(2 x2): not learnt from 4 demos
    return -(x + 1.2 * np.array([np.cos(2 * x[0]) * np.sin(2 * x[1]),
                                 np.sin(2 * x[0]) * np.cos(2 * x[1])]))


def _line_projector(rng):
    a = rng.normal(size=2)
    return np.eye(2) - np.outer(a, a) / (a @ a)


def _demos(n, seed, policy=_bowl, steps=30):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        N, x, X = _line_projector(rng), rng.uniform(-2.0, 2.0, 2), []
        for i in range(steps):
            if i == steps // 2:
                N = _line_projector(rng)
            X.append(x.copy())
            x = x + 0.05 * (N @ policy(x))
        out.append(np.array(X))
    return out


def _write(root, demos, names=None):
    for k, q in enumerate(demos):
        name = names[k] if names else f"demo_{k:04d}"
        stamps = 10**18 + k * 10**10 + np.arange(len(q)) * DT_NS
        write_joint_state_bag(root / name, JOINTS, stamps, q)
    return root


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return _write(tmp_path_factory.mktemp("clean"), _demos(8, 0))


@pytest.fixture(scope="module")
def clean(dataset, tmp_path_factory):
    """The pipeline on the clean dataset: (result, model path)."""
    path = tmp_path_factory.mktemp("clean_model") / "model.npz"
    return learn_pipeline([dataset], path), path


def test_training_block_holds_the_summary(clean, dataset):
    result, path = clean
    assert result.written and not result.refusals
    model = PolicyAlign.load(path)
    block = model.fit_summary_["pipeline"]
    assert block == json.loads(json.dumps(result.summary))  # JSON-able, stored as is
    demos = block["demonstrations"]
    assert demos["found"] == 8 and demos["duplicates"] == [] and demos["discarded"] == []
    assert len(demos["training"]) == 6 and len(demos["held_out"]) == 2
    assert sorted(demos["training"] + demos["held_out"]) == [f"demo_{k:04d}" for k in range(8)]
    train, held = holdout_split(8, 0.2, 0)
    assert demos["held_out"] == [f"demo_{k:04d}" for k in held]
    assert block["skipped_bags"] == [] and block["state"] == "joints"
    assert block["sigma2"] == model.sigma2_ and block["fit_time_s"] > 0
    assert 0.0 <= block["heldout_ncpe_observed"] < 0.05
    assert model.state_definition_ is None and model.joint_names_ == JOINTS
    assert block["current_model"]["note"] == "no current model"
    line = result.line()
    assert re.search(r"\b6\b.*\b2\b", line)  # training and held-out counts
    assert f"{block['heldout_ncpe_observed']:.4f}" in line and str(path) in line
    # Noise-free recordings: nothing to report, as for a summary without the noise value.
    quiet = dataclasses.replace(result, summary={**result.summary, "noise_to_step": None})
    assert block["noise_to_step"] < 1e-6 and quiet.line() == line


def test_the_summary_line_names_noisy_recordings(clean):
    result, _ = clean
    noisy = dataclasses.replace(result, summary={**result.summary, "noise_to_step": 0.42})
    assert "42 %" in noisy.line()


def test_same_dataset_twice_and_copied_bags_are_skipped_as_duplicates(
        clean, dataset, tmp_path):
    reference = clean[0].summary
    twice = learn_pipeline([dataset, dataset], tmp_path / "twice.npz")
    demos = twice.summary["demonstrations"]
    assert demos["found"] == 16
    assert demos["duplicates"] == [f"demo_{k:04d} (repeat)" for k in range(8)]
    assert demos["training"] == reference["demonstrations"]["training"]
    assert twice.summary["sigma2"] == reference["sigma2"]  # the very same fit
    # A dataset holding a copied bag and a re-recorded near-identical one (1e-7 rad noise).
    messy = tmp_path / "messy"
    shutil.copytree(dataset, messy)
    shutil.copytree(dataset / "demo_0002", messy / "demo_0002_copy")
    noisy = _demos(8, 0)[5] + np.random.default_rng(3).normal(scale=1e-7, size=(30, 2))
    _write(messy, [noisy], ["demo_0005_again"])
    result = learn_pipeline([messy], tmp_path / "messy.npz")
    demos = result.summary["demonstrations"]
    assert demos["found"] == 10
    assert result.summary["duplicate_of"] == {"demo_0002_copy": "demo_0002",
                                              "demo_0005_again": "demo_0005"}
    assert demos["duplicates"] == ["demo_0002_copy", "demo_0005_again"]
    assert demos["training"] == reference["demonstrations"]["training"]
    assert result.summary["sigma2"] == reference["sigma2"]


def test_the_same_bag_twice_is_a_clear_error_not_a_nan_crash(dataset, tmp_path):
    bag = dataset / "demo_0000"
    # The bag, the 2 demonstrations needed, the 1 found and the 1 duplicate skipped.
    with pytest.raises(ValueError, match=re.escape(str(bag)) + r".*\b2\b.*\b1\b.*\b1\b") as err:
        learn_pipeline([bag, bag], tmp_path / "m.npz")
    assert "NaN" not in str(err.value)
    assert not (tmp_path / "m.npz").exists()


def test_find_duplicates_keeps_the_first_and_ignores_distinct_demos():
    a, b = _demos(2, 7)
    assert find_duplicates([a, b, a + 1e-9, b[::-1]]) == {2: 0}
    assert find_duplicates([a, b], tol=0.0) == {}


def test_degenerate_fit_is_refused_keeps_the_old_model_and_force_writes_it(
        dataset, tmp_path, capsys):
    path = tmp_path / "model.npz"
    learn_pipeline([dataset], path)
    before = path.read_bytes()
    # A kernel far narrower than the gaps between demonstrations: each is its own group.
    refused = learn_pipeline([dataset], path, sigma=1e-6)
    assert refused.refused and not refused.written
    assert "max_discarded_fraction" in refused.refusals[0]  # the gate it failed
    assert "max_discarded_fraction" in refused.line() and str(path) in refused.line()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.npz"]
    # The command line: exit 1, the reason on stderr, the model untouched.
    args = dict(inputs=[str(dataset)], out=str(path), joints=None, sigma="1e-6", gap=0.5)
    assert run_learn(argparse.Namespace(**args)) == 1
    assert "max_discarded_fraction" in capsys.readouterr().err
    assert path.read_bytes() == before
    # force writes it and records what it overrode.
    assert run_learn(argparse.Namespace(**args, force=True)) == 0
    block = PolicyAlign.load(path).fit_summary_["pipeline"]
    assert block["forced"] and "max_discarded_fraction" in block["refusals"][0]
    assert block["sigma2"] == pytest.approx(1e-6)


def test_the_fit_is_drawn_also_when_refused(dataset, tmp_path, capsys):
    # The figure is for finding out what went wrong: a refused fit is drawn too, from the
    # demonstrations it was fitted on and those held out.
    figure = tmp_path / "fit.png"
    args = dict(inputs=[str(dataset)], out=str(tmp_path / "model.npz"), joints=None,
                sigma="1e-6", gap=0.5, plot=str(figure))
    assert run_learn(argparse.Namespace(**args)) == 1
    assert figure.read_bytes()[:4] == b"\x89PNG" and not (tmp_path / "model.npz").exists()
    # A suffix that names no figure format is unusable input, said before the fit.
    capsys.readouterr()
    assert run_learn(argparse.Namespace(**{**args, "plot": str(tmp_path / "fit.jpeg")})) == 2
    assert str(tmp_path / "fit.jpeg") in capsys.readouterr().err
    result = learn_pipeline([dataset], tmp_path / "m.npz")
    assert [len(result.train), len(result.held)] == [6, 2]
    assert result.train[0].n_dims == 2 and result.held[0].times is not None


def test_sigma_collapse_gate(dataset, tmp_path):
    result = learn_pipeline([dataset], tmp_path / "m.npz", sigma="narrow",
                            gates=Gates(min_sigma2_fraction=0.9))
    assert result.refused and "min_sigma2_fraction" in result.refusals[0]  # the gate
    # An explicit sigma^2 is the user's choice, never a collapse.
    explicit = learn_pipeline([dataset], tmp_path / "m.npz", sigma=result.summary["sigma2"],
                              gates=Gates(min_sigma2_fraction=0.9))
    assert explicit.written and not explicit.refusals
    with pytest.raises(ValueError, match="min_sigma2_fraction"):
        Gates(min_sigma2_fraction=-1.0)


def test_a_fit_worse_than_the_current_model_on_held_out_data_is_refused(tmp_path):
    path = tmp_path / "model.npz"
    big = learn_pipeline([_write(tmp_path / "big", _demos(16, 1, _ripple))], path,
                         holdout_fraction=0.0)
    before = path.read_bytes()
    small = _write(tmp_path / "small", _demos(5, 2, _ripple))
    result = learn_pipeline([small], path, seed=1)
    current = result.summary["current_model"]
    assert current["compared_on"] == result.summary["demonstrations"]["held_out"]
    assert current["new_ncpe_observed"] > current["heldout_ncpe_observed"] + 0.02
    assert result.refused and "heldout_tolerance" in result.refusals[0]  # the gate
    assert path.read_bytes() == before
    # The current model is not scored on demonstrations it was trained on (by content).
    again = learn_pipeline([tmp_path / "big"], path, holdout_fraction=0.2)
    assert again.summary["current_model"]["compared_on"] == []
    assert big.summary["training_fingerprints"]


def test_missing_joint_is_named_with_the_available_ones(dataset, tmp_path, capsys):
    from policy_align_ros.cli import main

    out = tmp_path / "m.npz"
    assert main(["learn", str(dataset), "--joints", "j1,not_a_joint", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "'not_a_joint'" in err and "j1, j2" in err  # the joint and those available
    assert not out.exists()


def test_truncated_and_foreign_bags_are_named_with_the_reason(dataset, tmp_path, capsys):
    from policy_align_ros.cli import main

    data = tmp_path / "data"
    shutil.copytree(dataset, data)
    mcap = data / "demo_0003" / "demo_0003.mcap"
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    stamps = 10**18 + np.arange(20) * DT_NS
    write_joint_state_bag(data / "other_robot", ["knee"], stamps, np.zeros((20, 1)))
    out = tmp_path / "m.npz"
    assert main(["learn", str(data), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    block = PolicyAlign.load(out).fit_summary_["pipeline"]
    skipped = {entry["bag"]: entry["reason"] for entry in block["skipped_bags"]}
    assert set(skipped) == {str(data / "demo_0003"), str(data / "other_robot")}
    assert "cannot open" in skipped[str(data / "demo_0003")]
    assert "j1, j2" in skipped[str(data / "other_robot")]
    assert "knee" in skipped[str(data / "other_robot")]
    assert f"{data / 'demo_0003'}: {skipped[str(data / 'demo_0003')]}" in err
    assert block["demonstrations"]["found"] == 7


def test_bad_arguments_name_the_parameter(dataset, tmp_path):
    for kwargs, match in (({"state": "hands"}, r"^state\b.*'hands'"),
                          ({"state": "frames:a,a"}, r"^state\b.*'frames:a,a'"),
                          ({"holdout_fraction": 1.5}, "holdout_fraction"),
                          ({"sigma": "huge"}, "sigma"),
                          ({"state": "frames:a", "robot": None}, r"^robot\b"),
                          # NumPy's "expected non-negative integer" named no parameter.
                          ({"seed": -1}, r"^seed\b.*-1\b"),
                          ({"seed": 1.5}, r"^seed\b.*\b1\.5\b")):
        with pytest.raises(ValueError, match=match):
            learn_pipeline([dataset], tmp_path / "m.npz", **kwargs)
    assert state_name(" frames: a ,b ") == "frames:a,b"
    assert not (tmp_path / "m.npz").exists()
    # An unwritable model path fails before the fit, naming the path.
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match=r"^model_path\b.*" + re.escape(
            str(tmp_path / "file")) + ".*" + re.escape(str(tmp_path / "file" / "sub" / "m.npz"))):
        learn_pipeline([dataset], tmp_path / "file" / "sub" / "m.npz")
    with pytest.raises(ValueError, match=r"^model_path\b.*" + re.escape(str(tmp_path))):
        learn_pipeline([dataset], tmp_path)


def test_frames_state_round_trip(tmp_path):
    """Learn from talos joint-state bags in hand positions; the model keeps the state."""
    from policy_align_ros.kinematics import Robot, TaskSpaceMap
    from policy_align_ros.sim.demonstrations import sample_start_states, task_space_rollout
    from policy_align_ros.sim.experts import TaskSpaceExpert

    hand = "gripper_left_base_link"
    joints = [f"arm_left_{i}_joint" for i in range(1, 8)]
    robot = Robot.load("talos", joints=joints)
    smap = TaskSpaceMap(robot, [hand])
    q0 = robot.neutral()
    target = smap.states(q0) + np.array([0.1, 0.05, 0.08])
    expert = TaskSpaceExpert(smap, target, 1.0)
    starts = sample_start_states(np.random.default_rng(0), q0, 6, 0.05, robot.lower,
                                 robot.upper)
    root = tmp_path / "talos"
    for k, q in enumerate(starts):
        demo = task_space_rollout(q, expert, None, 40, 0.05, name=str(k)).joints
        stamps = 10**18 + k * 10**10 + np.round(demo.times * 1e9).astype(np.int64)
        write_joint_state_bag(root / f"demo_{k:04d}", joints, stamps, demo.positions)
    path = tmp_path / "hand.npz"
    result = learn_pipeline([root], path, state=f"frames:{hand}", robot="talos",
                            holdout_fraction=0.0)
    assert result.written, result.line()
    model = PolicyAlign.load(path)
    definition = model.state_definition_
    assert definition["type"] == "frames" and definition["frames"] == [hand]
    assert definition["joints"] == joints and definition["robot"] == "talos"
    assert definition["urdf_sha256"] == robot.urdf_sha256()
    assert set(definition["rest"]) == set(joints)
    assert model.n_features_in_ == 3
    assert model.joint_names_ == [f"{hand}.x", f"{hand}.y", f"{hand}.z"]
    assert model.fit_summary_["pipeline"]["state"] == f"frames:{hand}"
    assert model.fit_summary_["pipeline"]["robot"] == "talos"
    x = smap.states(starts[0])
    assert model.policy(x[None]).shape == (1, 3)
    # Along the demonstrations the learnt hand velocity points at the target.
    pi = model.policy(x[None])[0]
    assert np.dot(pi, target - x) > 0.7 * np.linalg.norm(pi) * np.linalg.norm(target - x)


def test_an_unknown_frame_is_refused_before_any_bag_is_read(tmp_path):
    # An empty directory would be refused for holding no bag: the frame is named first.
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"^state\b.*'nosuch'.*'talos'"):
        learn_pipeline([tmp_path / "empty"], tmp_path / "m.npz", state="frames:nosuch",
                       robot="talos")
    with pytest.raises(ValueError, match=r"^state\b.*'arm_left_7_lnk'.*arm_left_7_link"):
        learn_pipeline([tmp_path / "empty"], tmp_path / "m.npz",
                       state="frames:arm_left_7_link,arm_left_7_lnk", robot="talos")


def test_joint_state_learning_needs_no_pinocchio(dataset, tmp_path):
    """data/ may import learning and rosbags only; kinematics loads for frames: states."""
    code = (
        "import sys\n"
        "from policy_align_ros.data import learn_pipeline\n"
        f"r = learn_pipeline([{str(dataset)!r}], {str(tmp_path / 'm.npz')!r},"
        " holdout_fraction=0.0)\n"
        "assert r.written\n"
        "bad = [m for m in ('pinocchio', 'rclpy', 'policy_align_ros.kinematics')"
        " if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr


def test_a_model_no_better_than_a_zero_policy_is_refused_and_force_writes_it(tmp_path,
                                                                              capsys):
    rng = np.random.default_rng(5)
    walks = [np.cumsum(rng.normal(scale=0.05, size=(60, 2)), axis=0) + rng.uniform(-1, 1, 2)
             for _ in range(7)]
    data = _write(tmp_path / "walks", walks)
    path = tmp_path / "model.npz"
    with pytest.warns(UserWarning):
        result = learn_pipeline([data], path)
    assert result.refused and not result.written and not path.exists()
    assert result.summary["worse_than_zero"] is True
    cv = result.summary["heldout_vs_zero"]["cv_folds"]
    assert cv["error"] >= cv["zero_error"] > 0
    # A refusal names the two errors compared.
    assert any(f"{cv['error']:.4g}" in r and f"{cv['zero_error']:.4g}" in r
               for r in result.refusals)
    args = dict(inputs=[str(data)], out=str(path), joints=None, sigma="medium", gap=0.5)
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the command prints the fit's warnings, once each
        assert run_learn(argparse.Namespace(**args)) == 1
    assert not path.exists()
    err = capsys.readouterr().err
    # The refusal and the fit's warning both name the two errors compared.
    assert err.count(f"{cv['error']:.4g}") == 2 and f"{cv['zero_error']:.4g}" in err
    assert run_learn(argparse.Namespace(**args, force=True)) == 0
    block = PolicyAlign.load(path).fit_summary_["pipeline"]
    assert block["forced"] and block["worse_than_zero"]


def test_a_model_whose_potential_has_no_minimum_is_refused(tmp_path):
    rng = np.random.default_rng(3)
    t = 0.02 * np.arange(100)
    lines = [rng.normal(scale=0.3, size=2) + t[:, None] * np.array([1.0, 0.5])
             for _ in range(8)]
    data = _write(tmp_path / "lines", lines)
    path = tmp_path / "model.npz"
    with pytest.warns(UserWarning):
        result = learn_pipeline([data], path, holdout_fraction=0.0)
    assert result.refused and not result.written and not path.exists()
    assert len(result.refusals) == 1
    assert result.summary["no_minimum"] is True and result.summary["worse_than_zero"] is False


def test_a_poor_fit_is_written_and_says_so(tmp_path):
    # Flows of a bowl pushed about by a random walk as large as their own steps: better
    # than standing still, but at most half of the held-out motion is the policy's.
    rng = np.random.default_rng(0)
    A, centre, demos = np.array([[2.0, 0.5], [0.5, 1.0]]), np.array([0.3, -0.2]), []
    for _ in range(8):
        x, X = rng.uniform(-2.0, 2.0, 2), []
        for _ in range(80):
            X.append(x.copy())
            x = x - 0.05 * A @ (x - centre) + 0.02 * rng.normal(size=2)
        demos.append(np.array(X))
    path = tmp_path / "model.npz"
    with pytest.warns(UserWarning):
        result = learn_pipeline([_write(tmp_path / "noisy", demos)], path,
                                holdout_fraction=0.0)
    assert result.written and not result.refusals
    assert result.summary["poor_fit"] is True and result.summary["worse_than_zero"] is False
    assert PolicyAlign.load(path).fit_summary_["pipeline"]["poor_fit"] is True


def test_the_learn_summary_reports_the_learnt_goal(clean):
    result, path = clean
    goal = result.summary["goal"]
    assert goal["n_minima"] >= 1 and goal["extent"] > 0
    assert result.summary["worse_than_zero"] is False and result.summary["no_minimum"] is False
    assert result.summary["poor_fit"] is False and result.summary["unfixed_goal"] is False
    model = PolicyAlign.load(path)
    assert len(model.fit_summary_["goal"]["minima"]) == goal["n_minima"]
    assert model.fit_summary_["pipeline"]["goal"] == goal
    # Each training demonstration's clock factor, as the model holds it.
    scales = result.summary["timing_scales"]
    assert scales == model.fit_summary_["timing_scales"] == model.timing_scales_.tolist()
    assert len(scales) == model.fit_summary_["n_trajectories"] and min(scales) > 0


def _write_joints(root, demos, joints):
    for k, q in enumerate(demos):
        stamps = 10**18 + k * 10**10 + np.arange(len(q)) * DT_NS
        write_joint_state_bag(root / f"demo_{k:04d}", joints, stamps, q)
    return root


def test_holdout_range_is_one_shared_constant(dataset, tmp_path):
    low, high = HOLDOUT_RANGE
    result = learn_pipeline([dataset], tmp_path / "m.npz", holdout_fraction=high)
    assert result.written and result.summary["holdout_fraction"] == high
    for bad in (low - 0.01, high + 0.01):
        with pytest.raises(ValueError, match="holdout_fraction"):
            learn_pipeline([dataset], tmp_path / "m.npz", holdout_fraction=bad)


def test_a_model_of_other_joints_is_replaced_only_with_overwrite(dataset, tmp_path):
    path = tmp_path / "m.npz"
    assert learn_pipeline([dataset], path).written
    before = path.read_bytes()
    other = _write_joints(tmp_path / "other", _demos(8, 0), ["a1", "a2"])
    with pytest.raises(ValueError, match="overwrite") as err:
        learn_pipeline([other], path)
    assert "j1" in str(err.value) and "a1" in str(err.value)
    assert path.read_bytes() == before
    # force (write a degenerate model) is not overwrite.
    with pytest.raises(ValueError, match="overwrite"):
        learn_pipeline([other], path, force=True)
    result = learn_pipeline([other], path, overwrite=True)
    assert result.written and PolicyAlign.load(path).joint_names_ == ["a1", "a2"]
    # The same joints in the same state: replaced without it.
    assert learn_pipeline([other], path, seed=1).written


def test_constant_joints_are_left_out_and_named_unless_joints_are_given(tmp_path):
    demos = [np.column_stack([q[:, 0], np.full(len(q), 0.04), q[:, 1]])
             for q in _demos(8, 0)]
    root = _write_joints(tmp_path / "grip", demos, ["j1", "gripper", "j2"])
    said = []
    result = learn_pipeline([root], tmp_path / "m.npz", log=said.append)
    assert result.summary["joints"] == ["j1", "j2"]
    assert result.summary["constant_joints"] == ["gripper"]
    assert result.model.n_features_in_ == 2
    assert any("gripper" in line for line in said) and "gripper" in result.line()
    named = learn_pipeline([root], tmp_path / "named.npz", joints=["j1", "gripper", "j2"])
    assert named.summary["joints"] == ["j1", "gripper", "j2"]
    assert named.summary["constant_joints"] == []


def test_one_continuous_recording_names_gap_and_one_bag_per_demonstration(tmp_path):
    q = np.concatenate(_demos(3, 0))  # three demonstrations without a pause between them
    stamps = 10**18 + np.arange(len(q)) * DT_NS
    write_joint_state_bag(tmp_path / "continuous", JOINTS, stamps, q)
    with pytest.raises(ValueError, match=re.escape(str(tmp_path / "continuous"))
                       + r".*\b2\b.*\b1\b") as err:
        learn_pipeline([tmp_path / "continuous"], tmp_path / "m.npz")
    assert "--gap" in str(err.value) and "gap_s" in str(err.value)
    assert "~/start_demo" in str(err.value) and "~/stop_demo" in str(err.value)


def test_a_continuous_joint_recorded_across_the_wrap_is_learnt_on_one_turn(tmp_path):
    # Kinova's joint 1 is continuous; its driver reports it in [-pi, pi). Flows of
    # xdot = -(q - goal) towards a goal just past pi cross the wrap.
    from policy_align_ros.kinematics.robot import robots_dir

    urdf = robots_dir() / "kinova_description" / "robots" / "kinova.urdf"
    joints = ["j2s6s200_joint_1", "j2s6s200_joint_2"]
    goal = np.array([3.3, 2.5])
    rng = np.random.default_rng(5)
    t = DT_NS * 1e-9 * np.arange(60)
    demos = []
    for _ in range(6):
        q = goal + (rng.uniform(-0.6, 0.6, 2) + 0.3) * np.exp(-1.5 * t)[:, None]
        q[:, 0] = np.remainder(q[:, 0] + np.pi, 2 * np.pi) - np.pi
        demos.append(q)
    root = _write_joints(tmp_path / "bags", demos, joints)
    # Without the robot the joint's kind is unknown: the jump is refused, naming the fix.
    with pytest.raises(ValueError, match="j2s6s200_joint_1") as err:
        learn_pipeline([root], tmp_path / "model.npz")
    assert "--robot" in str(err.value)
    result = learn_pipeline([root], tmp_path / "model.npz", robot=str(urdf))
    assert result.summary["continuous_joints"] == ["j2s6s200_joint_1"]
    (minimum, *_) = PolicyAlign.load(tmp_path / "model.npz").fit_summary_["goal"]["minima"]
    error = np.asarray(minimum["point"]) - goal
    error[0] = np.remainder(error[0] + np.pi, 2 * np.pi) - np.pi  # the same posture
    assert np.linalg.norm(error) < 0.02


def test_a_demonstration_far_off_the_others_clock_is_named():
    from policy_align_ros.data.pipeline import ODD_CLOCK, _odd_clocks

    names = ["bag_0", "bag_1", "bag_2", "bag_3"]
    assert _odd_clocks([0.9, 1.1, 1.0, 1.0], names) == ""  # every factor within ODD_CLOCK
    fast = _odd_clocks([0.26, 1.34, 1.2, 1.0], names)
    # It moved 1 / 0.26 times as fast; the slowest is within ODD_CLOCK and not named.
    assert "bag_0" in fast and "3.8" in fast and "bag_1" not in fast
    slow = _odd_clocks([0.9, 1.0, 1.1, 1.05 * ODD_CLOCK], names)
    assert "bag_3" in slow and "bag_0" not in slow
    assert _odd_clocks([0.1, 1.0], names) == ""  # not one factor per name: nothing claimed
