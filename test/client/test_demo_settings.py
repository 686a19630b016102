"""``policy-align demo``'s settings and random streams (no ROS graph)."""

import argparse
import os

import numpy as np
import pytest

from policy_align_ros.client.demo.main import run_demo
from policy_align_ros.client.demo.settings import (
    pick_domain_id,
    random_streams,
    settings_from_args,
)
from policy_align_ros.kinematics.robot_config import load_robot_config


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


def test_domain_id_honours_ros_domain_id_then_falls_back_to_a_private_one():
    # An explicit id wins, then the user's ROS_DOMAIN_ID, then 1 + pid % 100.
    assert pick_domain_id(17, {"ROS_DOMAIN_ID": "42"}) == 17
    assert pick_domain_id(None, {"ROS_DOMAIN_ID": "42"}) == 42
    assert pick_domain_id(None, {"ROS_DOMAIN_ID": " 0 "}) == 0
    private = 1 + os.getpid() % 100
    assert pick_domain_id(None, {}) == private
    assert pick_domain_id(None, {"ROS_DOMAIN_ID": ""}) == private
    for bad in ("seven", "233", "-1", "1.5"):
        with pytest.raises(ValueError, match="ROS_DOMAIN_ID"):
            pick_domain_id(None, {"ROS_DOMAIN_ID": bad})
    with pytest.raises(ValueError, match="domain_id"):
        pick_domain_id(300, {})
    # With a Fast DDS profile, whose ports may allow it, the user's id is taken.
    profiled = {"ROS_DOMAIN_ID": "241", "FASTRTPS_DEFAULT_PROFILES_FILE": "/tmp/dds.xml"}
    assert pick_domain_id(None, profiled) == 241


def test_demo_refuses_a_bad_ros_domain_id_before_starting_anything(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "not-a-number")
    out = tmp_path / "demo"
    assert run_demo(argparse.Namespace(out=str(out))) == 2
    assert not out.exists()


def test_robot_names_a_config_that_fills_the_unset_settings():
    s = settings_from_args(argparse.Namespace(robot="ur5"))
    config = load_robot_config("ur5")
    assert s.robot == "ur5" and s.joints == config.joints and s.frames == ["tool0"]
    assert s.home == config.home and s.unseen_constraint == config.unseen_constraint
    # An explicit joint subset keeps the robot's reference posture (home is per joint).
    few = settings_from_args(argparse.Namespace(robot="ur5", joints=config.joints[:3]))
    assert few.joints == config.joints[:3] and few.home == []
    # A robot without a config: all its joints, no frames, no unseen constraint.
    bare = settings_from_args(argparse.Namespace(robot="ur10"))
    assert bare.robot_config == "" and bare.joints == [] and bare.frames == []
    with pytest.raises(ValueError, match="hands"):
        settings_from_args(argparse.Namespace(robot="panda", state="hands"))
