"""The demo's new start states (policy_align_ros.client.demo.task; no ROS graph)."""

import argparse

import numpy as np
import pytest

from policy_align_ros.client.demo.settings import (
    MIN_START_SEPARATION,
    DemoSettings,
    StageError,
    random_streams,
    settings_from_args,
)
from policy_align_ros.client.demo.task import Task, new_starts
from policy_align_ros.kinematics import Robot
from policy_align_ros.nodes._common import DEFAULT_JOINTS


def test_new_starts_come_from_the_start_distribution_and_avoid_recorded_ones():
    robot = Robot.load("talos", DEFAULT_JOINTS)
    task = Task(robot, settings_from_args(argparse.Namespace(seed=0)))
    streams = random_streams(0)
    recorded = new_starts(task, np.random.default_rng(1), 20, np.empty((0, robot.nq)))
    starts = new_starts(task, streams["starts"], 50, recorded)
    gaps = np.linalg.norm(starts[:, None, :] - recorded[None], axis=2)
    assert gaps.min() >= MIN_START_SEPARATION
    # Spread like the demonstrators' N(q_c, 0.1 I), clipped to the limits.
    assert np.all((starts >= robot.lower) & (starts <= robot.upper))
    assert 0.05 < np.var(starts - task.attractor) < 0.15
    # A recorded start that every draw would hit is refused, not silently reused.
    with pytest.raises(StageError):
        new_starts(Task(robot, DemoSettings(start_variance=0.0)), streams["starts"], 1,
                   task.attractor[None])
