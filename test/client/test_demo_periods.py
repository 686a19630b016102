"""Missed control periods (policy_align_ros.client.demo.periods)."""

import numpy as np

from policy_align_ros.client.demo.periods import repeated_steps, stale_ticks
from policy_align_ros.learning import Trajectory


def test_repeated_steps_find_a_command_integrated_twice():
    dt, v = 0.04, np.array([0.3, -0.2])
    q = [np.array([0.1, 0.7])]
    for command in (v, v * 0.9, v * 0.9, v * 0.8, np.zeros(2), np.zeros(2)):
        q.append(q[-1] + dt * command)  # the simulator's Euler step
    # Steps 2 and 3 use the same command (a missed period); standing still is no miss.
    np.testing.assert_array_equal(repeated_steps(np.array(q)),
                                  [False, True, False, False, False])
    assert stale_ticks([Trajectory(np.array(q), dt * np.arange(len(q)))]) == (5, 1)
