"""What a model file holds (policy_align_ros.data.show, ``policy-align show``). ROS-free."""

from __future__ import annotations

import json

import numpy as np
import pytest

from policy_align_ros.cli import main
from policy_align_ros.data import write_joint_state_bag
from policy_align_ros.data.pipeline import learn_pipeline
from policy_align_ros.data.show import model_report, report_lines
from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.learning.model_io import load_header

JOINTS = ["j1", "j2"]
GOAL = np.array([0.3, -0.2])


def _flows(seed, n=8, steps=40, dt=0.05):
    """Free Euler flows of xdot = -(x - GOAL), at rest near GOAL at their ends."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        x, X = rng.uniform(-2.0, 2.0, 2), []
        for _ in range(steps):
            X.append(x.copy())
            x = x - 0.15 * (x - GOAL)
        out.append(np.array(X))
    return out


@pytest.fixture(scope="module")
def learnt(tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    for k, q in enumerate(_flows(0)):
        stamps = 10**18 + k * 10**10 + np.arange(len(q)) * 50_000_000
        write_joint_state_bag(root / f"demo_{k:04d}", JOINTS, stamps, q)
    path = tmp_path_factory.mktemp("model") / "model.npz"
    result = learn_pipeline([root], path)
    assert result.written
    return result, path


def test_the_report_is_the_learners_summary_and_its_goal(learnt):
    result, path = learnt
    report = model_report(path)
    assert report["joints"] == JOINTS and report["n_dims"] == 2
    assert not report["forced"] and report["refusals"] == []
    assert report["continuous_joints"] == []  # no robot named: none known
    assert report["n_fold_models"] == len(load_header(path, "policy_align")["folds"]) >= 2
    assert report["stop_checked"]  # timed demonstrations and a goal report: checked
    # The learn line as the learner printed it, but for the path the report starts with.
    assert result.line().startswith(report["learn_summary"])
    goal = report["learnt_goal"]
    assert list(goal) == JOINTS
    np.testing.assert_allclose([goal[j] for j in JOINTS], GOAL, atol=0.02)
    assert json.loads(json.dumps(report, allow_nan=False)) == report
    lines = report_lines(report)
    assert lines[0] == f"model {path}" and not any(line.startswith("FORCED") for line in lines)


def test_a_forced_model_says_so_first(learnt, tmp_path):
    _, path = learnt
    model = PolicyAlign.load(path)
    block = model.fit_summary_["pipeline"]
    block.update(forced=True, refusals=["no better than a zero policy: ratio 2.4"])
    forced = model.save(tmp_path / "forced.npz")
    report = model_report(forced)
    assert report["forced"] and report["refusals"] == block["refusals"]
    lines = report_lines(report)
    assert lines[3].startswith("FORCED") and "ratio 2.4" in lines[3]


def test_a_model_saved_by_the_library_has_no_learn_summary(tmp_path):
    t = 0.05 * np.arange(40)
    demos = [Trajectory(np.column_stack([np.exp(-t) * a, np.exp(-t) * b]), t)
             for a, b in [(1.0, 0.5), (-1.0, 0.8), (0.4, -1.2), (-0.7, -0.9)]]
    path = PolicyAlign(random_state=0).fit(demos).save(tmp_path / "lib.npz")
    report = model_report(path)
    assert report["learn_summary"] is None and report["joints"] is None
    # No joint names: the coordinates are numbered. The flows decay towards the origin.
    goal = report["learnt_goal"]
    assert list(goal) == ["x0", "x1"]
    assert np.hypot(goal["x0"], goal["x1"]) < 0.2


def test_the_command_prints_it_and_refuses_what_is_no_model_file(learnt, tmp_path, capsys):
    _, path = learnt
    assert main(["show", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["joints"] == JOINTS
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a model")
    assert main(["show", str(garbage)]) == 2
    assert str(garbage) in capsys.readouterr().err
    assert main(["show", str(tmp_path / "missing.npz")]) == 2
