"""The executor bench's parts (policy_align_ros.experiments.executor_bench)."""

import sys
from pathlib import Path

import numpy as np

from policy_align_ros.control import ControlStep
from policy_align_ros.experiments.executor_bench import time_stop_check
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.fold_stops import check_horizon

sys.path.insert(0, str(Path(__file__).parents[1] / "learning"))
from flows import quadratic_flow  # noqa: E402


def test_the_stop_check_is_timed_once_per_start_over_the_model_and_its_folds():
    rng = np.random.default_rng(0)
    trajs = [quadratic_flow(np.eye(2), np.zeros(2), rng.uniform(-1, 1, 2), 40, 0.05)
             for _ in range(6)]
    model = PolicyAlign(random_state=0).fit(trajs)
    step = ControlStep(-3 * np.ones(2), 3 * np.ones(2), np.ones(2), 0.01, policy=model.policy)
    found = time_stop_check(model, np.arange(2), step, rng.uniform(-1, 1, (3, 2)))
    assert found["runs"] == 1 + len(model.fold_regressors_) and found["runs"] > 1
    assert found["steps"] >= check_horizon(model)[1]
    assert 1 <= found["median_steps"] < found["steps"]  # exact data: every run stops
    assert 0.0 <= found["median_s"] <= found["max_s"] < found["capped_s"] < np.inf
    assert 0.0 < found["slice_p50_us"] <= found["slice_p99_us"] < np.inf
    model.fold_regressors_ = []
    assert np.isnan(time_stop_check(model, np.arange(2), step, np.zeros((1, 2)))["runs"])
