"""Smoke and behaviour tests of policy_align_ros.experiments.humanoid (tiny sizes)."""

import argparse
import json

import numpy as np

from policy_align_ros.experiments import humanoid


def test_model_has_22_joints_and_hands_stay_on_their_planes() -> None:
    robot = humanoid._robot()
    assert robot.nq == 22
    demos, expert, normals = humanoid.make_humanoid_dataset(1, n_traj=4, n_samples=30,
                                                            switches=0)
    assert normals.shape == (4, 1, 3)
    for demo, n in zip(demos, normals[:, 0], strict=True):
        Q = demo.trajectory.positions
        heights = np.array([[n @ robot.frame_position(q, h) for h in humanoid.HANDS]
                            for q in Q])
        travel = np.linalg.norm(Q[-1] - Q[0])
        assert travel > 0.1
        # Euler steps keep the plane to first order; the drift is small against the motion.
        assert np.max(np.ptp(heights, axis=0)) < 0.05 * travel
        assert np.all(demo.n_active == 2)
        assert demo.potential[-1] < demo.potential[0]
        np.testing.assert_allclose(demo.policy, expert.policy(Q))


def test_switching_changes_the_plane() -> None:
    _, _, normals = humanoid.make_humanoid_dataset(2, n_traj=2, n_samples=9, switches=2)
    assert normals.shape == (2, 3, 3)
    calls = []
    parts = [lambda q, t, pi, i=i: calls.append(i) or np.zeros((0, 22)) for i in range(3)]
    c = humanoid.switching_constraint(parts, 9.0)
    for t in range(9):
        c(np.zeros(22), float(t), np.zeros(22))
    assert calls == [0, 0, 0, 1, 1, 1, 2, 2, 2]


def test_main_writes_table(tmp_path) -> None:
    args = argparse.Namespace(datasets=1, jobs=1, out=str(tmp_path), seed=0,
                              n_traj=10, n_samples=25)
    assert humanoid.main(args) == 0
    table = (tmp_path / "humanoid.md").read_text()
    assert "nUPE" in table and "0.1568" in table
    assert (tmp_path / "humanoid.png").stat().st_size > 10_000
    rows = json.loads((tmp_path / "humanoid.json").read_text())
    assert len(rows) == 1 and rows[0]["nUPE"] > 0.0
