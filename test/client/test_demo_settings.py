"""``policy-align demo``'s settings and random streams (no ROS graph)."""

import argparse

import numpy as np
import pytest

from policy_align_ros.client.demo.main import run_demo
from policy_align_ros.client.demo.settings import random_streams, settings_from_args


def test_seed_sets_every_stream_and_settings_are_checked():
    a, b = random_streams(3), random_streams(3)
    assert a["demonstrator"] == b["demonstrator"]
    assert np.array_equal(a["starts"].random(3), b["starts"].random(3))
    assert random_streams(4)["demonstrator"] != a["demonstrator"]
    with pytest.raises(ValueError, match="state"):
        settings_from_args(argparse.Namespace(state="elbows"))
    with pytest.raises(ValueError, match="demos"):
        settings_from_args(argparse.Namespace(demos=2))
    assert run_demo(argparse.Namespace(state="elbows")) == 2
