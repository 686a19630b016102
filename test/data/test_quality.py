"""Tests of policy_align_ros.data.quality: held-out demonstrations a policy does not explain."""

import numpy as np

from policy_align_ros.data.quality import poorly_explained
from policy_align_ros.learning import Trajectory


def _flow(x0, policy, steps=50, dt=0.02):
    X = [np.asarray(x0, dtype=float)]
    for _ in range(steps - 1):
        X.append(X[-1] + dt * policy(X[-1][None])[0])
    return Trajectory(np.array(X), times=dt * np.arange(steps))


def test_only_the_demonstration_the_policy_does_not_explain_is_named():
    policy = lambda X: -X  # noqa: E731 - the learnt policy: to the origin
    followed = _flow([1.0, 0.5], policy)
    reversed_ = _flow([0.1, 0.05], lambda X: X)  # moves away: the opposite of the policy
    teleported = _flow([0.8, -0.4], policy)
    jumped = teleported.positions.copy()
    jumped[25:] += [0.3, 0.0]  # a reset that moved the robot between two samples
    teleported = Trajectory(jumped, times=teleported.times)
    named = poorly_explained(policy, [followed, reversed_, teleported], ["a", "b", "c"])
    assert list(named) == ["b", "c"] and named["b"] > 1.0 and 0.5 <= named["c"]
    assert poorly_explained(policy, [followed], ["a"]) == {}
