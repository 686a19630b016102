"""Smoke and behaviour tests of policy_align_ros.experiments.grasp (tiny sizes)."""

import argparse
import json

import numpy as np
import pytest

from policy_align_ros.experiments import grasp


def test_panels_block_outside_the_gap_only() -> None:
    c = grasp.panel_constraint(grasp.training_panels(0.3), lookahead=0.0)
    forward = np.array([1.0, 0, 0, 1.0, 0, 0])
    near = grasp.BARRIER_X - 0.02
    blocked = np.array([near, 0.4, 0.0, near, -0.4, 0.0])
    in_gap = np.array([near, 0.1, 0.0, near, -0.1, 0.0])
    far = np.array([0.0, 0.4, 0.0, 0.0, -0.4, 0.0])
    A = c(blocked, 0.0, forward)
    np.testing.assert_allclose(A, [[1, 0, 0, 0, 0, 0], [0, 0, 0, 1, 0, 0]])
    assert c(in_gap, 0.0, forward).shape == (0, 6)
    assert c(far, 0.0, forward).shape == (0, 6)
    assert c(blocked, 0.0, -forward).shape == (0, 6)  # moving away is free


def test_demonstrations_never_cross_a_panel() -> None:
    scene = grasp.make_grasp_dataset(3, n_traj=15, n_samples=60)
    assert len(scene.demos) == 15 and scene.gaps.shape == (15,)
    crossings = 0
    for demo, gap in zip(scene.demos, scene.gaps, strict=True):
        X = demo.trajectory.positions
        assert X.shape == (60, 6)
        for h in range(2):
            side = X[:, 3 * h] - grasp.BARRIER_X
            on_panel = np.abs(X[:, 3 * h + 1]) > gap / 2
            crossings += np.sum((side[:-1] * side[1:] < 0) & on_panel[:-1] & on_panel[1:])
        # Velocities are the projected expert policy.
        np.testing.assert_allclose(
            demo.trajectory.velocities,
            np.einsum("mij,mj->mi", demo.projectors, demo.policy), atol=1e-12)
    assert crossings == 0
    # Some demonstrations touch a barrier, some samples are free.
    active = np.concatenate([d.n_active for d in scene.demos])
    assert 0 < np.mean(active > 0) < 1


def test_start_states_are_reachable_hand_positions() -> None:
    robot = grasp._robot()
    starts = grasp.hand_start_states(robot, np.random.default_rng(0), 20)
    assert starts.shape == (20, 6)
    assert np.all(starts[:, 1] > starts[:, 4])  # left hand left of right hand
    assert 0.05 < np.std(starts[:, 0]) < 0.5


def test_main_writes_table_and_figure(tmp_path) -> None:
    pytest.importorskip("policy_align_ros.learning.baselines")
    args = argparse.Namespace(datasets=1, jobs=1, out=str(tmp_path), seed=0,
                              n_traj=12, n_samples=30)
    assert grasp.main(args) == 0
    table = (tmp_path / "grasp.md").read_text()
    assert "Unseen barrier" in table and "0.2104" in table
    assert (tmp_path / "grasp.png").stat().st_size > 10_000
    rows = json.loads((tmp_path / "grasp.json").read_text())
    assert len(rows) == 1 and 0.0 <= rows[0]["discarded (%)"] <= 100.0
