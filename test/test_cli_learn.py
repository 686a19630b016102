"""Tests of ``policy-align learn`` (policy_align_ros.data.learn.run_learn). ROS-free."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from policy_align_ros.cli import main
from policy_align_ros.data.bags.dataset import load_dataset
from policy_align_ros.data.bags.write import write_joint_state_bag
from policy_align_ros.data.learn import parse_joints, parse_sigma, run_learn
from policy_align_ros.kinematics.robot_config import load_robot_config
from policy_align_ros.learning.policy_align import PolicyAlign
from policy_align_ros.learning.policy_file import read_robot_fields

T0 = 1_700_000_000 * 10**9
JOINTS = ["shoulder", "elbow", "wrist"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Six demonstrations of xdot = -x (phi = |x|^2 / 2) at 50 Hz, in one dataset dir."""
    root = tmp_path_factory.mktemp("dataset")
    rng = np.random.default_rng(0)
    t = np.arange(60) * 0.02
    for k in range(6):
        x0 = rng.uniform(-1.0, 1.0, size=3)
        q = x0[None, :] * np.exp(-t)[:, None]
        stamps = T0 + k * 10 * 10**9 + np.round(t * 1e9).astype(np.int64)
        write_joint_state_bag(root / f"demo_{k:04d}", JOINTS, stamps, q, -q)
    return root


def test_learn_from_dataset_writes_a_usable_model(dataset, tmp_path, capsys):
    out = tmp_path / "models" / "model.npz"
    assert main(["learn", str(dataset), "--out", str(out)]) == 0
    assert str(out) in capsys.readouterr().out  # says where the model went
    model = PolicyAlign.load(out)
    demos = model.fit_summary_["pipeline"]["demonstrations"]
    assert demos["found"] == 6 and len(demos["training"]) == 5
    assert len(demos["held_out"]) == 1
    assert model.joint_names_ == JOINTS
    # Along the demonstrations, the learnt policy points like the demonstrated -x.
    trajs, _, _ = load_dataset(dataset)
    x = np.concatenate([t.positions for t in trajs])
    pi = model.policy(x)
    cosine = np.sum(pi * -x, axis=1) / np.linalg.norm(pi, axis=1) / np.linalg.norm(x, axis=1)
    assert np.mean(cosine) > 0.7


def test_joint_subset_order_and_explicit_sigma(dataset, tmp_path):
    out = tmp_path / "m.npz"
    args = argparse.Namespace(inputs=[str(dataset / "demo_0000"), str(dataset / "demo_0003"),
                                      str(dataset / "demo_0005")],
                              out=str(out), joints="wrist, shoulder", sigma="0.05", gap=0.5)
    assert run_learn(args) == 0
    model = PolicyAlign.load(out)
    assert model.joint_names_ == ["wrist", "shoulder"]
    assert model.sigma2_ == pytest.approx(0.05)
    # One of the three is held out to score the fit: the other two train it.
    assert model.fit_summary_["n_trajectories"] == 2
    demos = model.fit_summary_["pipeline"]["demonstrations"]
    assert len(demos["held_out"]) == 1 and len(demos["training"]) == 2
    assert sorted(demos["held_out"] + demos["training"]) == ["demo_0000", "demo_0003",
                                                            "demo_0005"]


def test_holdout_zero_trains_on_everything_and_seed_changes_the_split(dataset, tmp_path):
    out = tmp_path / "m.npz"
    assert main(["learn", str(dataset), "--out", str(out), "--holdout", "0"]) == 0
    block = PolicyAlign.load(out).fit_summary_["pipeline"]
    assert block["demonstrations"]["held_out"] == [] and block["heldout_ncpe_observed"] is None
    held = []
    for seed in (0, 1):
        path = tmp_path / f"s{seed}.npz"
        assert main(["learn", str(dataset), "--out", str(path), "--seed", str(seed)]) == 0
        held.append(PolicyAlign.load(path).fit_summary_["pipeline"]["demonstrations"]
                    ["held_out"])
    assert held[0] != held[1]


@pytest.mark.parametrize(
    ("argv", "expected"),
    [  # what the message names: the input, the option and the value, or the fix
        (["{tmp}/missing"], ["{tmp}/missing"]),
        (["{ds}/demo_0000"], ["--gap"]),  # one demonstration: split it at its pauses
        (["{ds}", "--joints", "elbow,,wrist"], ["--joints", "'elbow,,wrist'"]),
        (["{ds}", "--joints", "knee"], ["knee", "shoulder", "elbow", "wrist"]),
        (["{ds}", "{ds}/demo_0001", "--state", "frames:hand"], ["robot"]),
        (["{ds}", "--state", "hands"], ["state", "'hands'"]),
        (["{ds}", "--holdout", "2"], ["holdout_fraction", "2.0"]),
        (["{ds}", "--sigma", "huge"], ["--sigma", "'huge'"]),
        (["{ds}", "--sigma", "-1"], ["--sigma", "'-1'"]),
        (["{tmp}"], ["{tmp}"]),
        # A robot that does not load, or whose joints the recorded ones are not: the model
        # would name a robot the executor cannot load.
        (["{ds}", "--robot", "nosuchrobot"], ["nosuchrobot", "--robot"]),
        (["{ds}", "--robot", "panda"], ["'panda'", "shoulder", "--robot"]),
        # A figure that cannot be written is said before the fit, not after it.
        (["{ds}", "--plot", "{ds}/demo_0000/metadata.yaml/fit.png"], ["--plot"]),
    ],
)
def test_unusable_input_returns_2_with_a_message(dataset, tmp_path, capsys, argv, expected):
    argv = [a.format(tmp=tmp_path, ds=dataset) for a in argv]
    out = tmp_path / "model.npz"
    assert main(["learn", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("policy-align learn")  # the command that failed
    for item in expected:
        assert item.format(tmp=tmp_path, ds=dataset) in err, (item, err)
    assert not out.exists()


def test_parsers():
    assert parse_sigma("Wide") == "wide"
    assert parse_sigma("0.5") == 0.5
    with pytest.raises(ValueError, match=r"^sigma\b.*'inf'"):
        parse_sigma("inf")
    assert parse_sigma(0.5) == 0.5
    assert parse_joints(" ") is None
    assert parse_joints("a, b") == ["a", "b"]
    with pytest.raises(ValueError, match=r"^--joints\b.*'a,a'"):
        parse_joints("a,a")


def test_holdout_range_is_the_learner_nodes(dataset, tmp_path):
    from policy_align_ros.data.arguments import HOLDOUT_RANGE

    high = HOLDOUT_RANGE[1]
    assert main(["learn", str(dataset), "--out", str(tmp_path / "a.npz"),
                 "--holdout", str(high)]) == 0
    assert main(["learn", str(dataset), "--out", str(tmp_path / "b.npz"),
                 "--holdout", str(high + 0.1)]) == 2
    assert not (tmp_path / "b.npz").exists()


def test_out_of_other_joints_needs_overwrite(dataset, tmp_path, capsys):
    out = tmp_path / "model.npz"
    assert main(["learn", str(dataset), "--out", str(out)]) == 0
    before = out.read_bytes()
    args = ["learn", str(dataset), "--out", str(out), "--joints", "elbow,wrist"]
    assert main(args) == 2
    assert "--overwrite" in capsys.readouterr().err and out.read_bytes() == before
    assert main([*args, "--force"]) == 2 and out.read_bytes() == before
    assert main([*args, "--overwrite"]) == 0
    assert PolicyAlign.load(out).joint_names_ == ["elbow", "wrist"]
    assert main(args) == 0  # the same joints: replaced as before


def test_a_constant_joint_is_left_out_and_named(tmp_path, capsys):
    rng = np.random.default_rng(1)
    t = np.arange(60) * 0.02
    for k in range(6):
        x0 = rng.uniform(-1.0, 1.0, size=2)
        q = x0[None, :] * np.exp(-t)[:, None]
        q = np.column_stack([q, np.full(len(t), 0.02)])
        stamps = T0 + k * 10 * 10**9 + np.round(t * 1e9).astype(np.int64)
        write_joint_state_bag(tmp_path / "d" / f"demo_{k:04d}", ["a", "b", "finger"],
                              stamps, q)
    out = tmp_path / "m.npz"
    assert main(["learn", str(tmp_path / "d"), "--out", str(out)]) == 0
    assert "finger" in capsys.readouterr().err
    assert PolicyAlign.load(out).joint_names_ == ["a", "b"]
    assert main(["learn", str(tmp_path / "d"), "--out", str(out), "--joints", "a,b,finger",
                 "--overwrite"]) == 0
    assert PolicyAlign.load(out).joint_names_ == ["a", "b", "finger"]


def test_robot_config_gives_the_model_its_robot_and_joints(tmp_path):
    # A recording of the Panda's arm plus a finger joint the config leaves out.
    config = load_robot_config("panda")
    names = config.joints + ["panda_finger_joint1"]
    rng = np.random.default_rng(1)
    t = np.arange(60) * 0.02
    for k in range(6):
        x0 = rng.uniform(-0.5, 0.5, size=len(names))
        q = x0[None, :] * np.exp(-t)[:, None]
        stamps = T0 + k * 10 * 10**9 + np.round(t * 1e9).astype(np.int64)
        write_joint_state_bag(tmp_path / "demos" / f"demo_{k:04d}", names, stamps, q, -q)
    out = tmp_path / "model.npz"
    assert main(["learn", str(tmp_path / "demos"), "--out", str(out),
                 "--robot-config", "panda"]) == 0
    model = PolicyAlign.load(out)
    assert model.robot_ == "panda" and model.joint_names_ == config.joints
    assert read_robot_fields(out) == ("panda", config.joints)
    # Without it the model names no robot (an executor then needs robot or robot_config).
    assert main(["learn", str(tmp_path / "demos"), "--out", str(tmp_path / "plain.npz"),
                 "--joints", ",".join(config.joints)]) == 0
    assert PolicyAlign.load(tmp_path / "plain.npz").robot_ is None
    assert main(["learn", str(tmp_path / "demos"), "--out", str(tmp_path / "bad.npz"),
                 "--robot-config", "pandas"]) == 2


def test_the_summary_names_every_joint_up_to_a_dozen():
    from policy_align_ros.data.learn import SHOWN_JOINTS, _joint_list

    names = [f"j{k}" for k in range(SHOWN_JOINTS + 3)]
    assert _joint_list(names[:SHOWN_JOINTS]) == ", ".join(names[:SHOWN_JOINTS])
    shown = _joint_list(names)
    assert names[0] in shown and names[-1] not in shown and "5" in shown  # 5 more
