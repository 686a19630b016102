"""``policy-align bench scale``: its data and the child process's report."""

import numpy as np

from policy_align_ros.experiments.scale import _child, make_scale_dataset


def test_scale_data_and_child_report():
    trajs = make_scale_dataset(6, 30, np.random.default_rng(0), dim=5)
    assert len(trajs) == 6 and trajs[0].positions.shape == (30, 5)
    assert trajs[0].times[1] == 100.0 / 30
    report = _child(20, 40, seed=0)
    assert report["K"] == 20 and report["peak_mb"] > 0
    assert report["alignment_nmse"] < 0.05
