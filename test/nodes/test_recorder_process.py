"""The ``recorder`` node as a process: signals mid-demo, bad start-up parameters (domain ids
103, 104, 107, 108, 110).

Each test owns an ``rclpy.Context`` with its own ``domain_id`` and shuts it down.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from recorder_rig import T0, _Harness, _msg, _ros, _wait

from policy_align_ros.data import load_dataset


def test_sigkill_mid_demo_keeps_earlier_demos(tmp_path):
    dataset = tmp_path / "ds"
    env = dict(os.environ, ROS_DOMAIN_ID="103")
    cmd = [sys.executable, "-m", "policy_align_ros.nodes.recorder", "--ros-args",
           "-p", f"dataset_dir:={dataset}", "-p", "joints:=[a, b]"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    rng = np.random.default_rng(3)
    sent = []
    try:
        with _ros(103) as ctx:
            harness = _Harness(ctx, None)
            try:
                harness.ready()
                for demo in range(3):
                    assert harness.call(harness.start).success
                    q = rng.normal(size=(40, 2))
                    for k in range(40):
                        harness.pub.publish(_msg(T0 + (demo * 1000 + k) * 10**7, "ab", q[k]))
                        time.sleep(0.002)
                    sent.append(q)
                    time.sleep(1.0)  # let the messages arrive before the service call
                    if demo < 2:
                        response = harness.call(harness.stop)
                        assert response.success, response.message
                        assert response.message == str(dataset / f"demo_{demo:04d}")
            finally:
                harness.close()
        assert proc.poll() is None, proc.stderr.read().decode()
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    assert sorted(p.name for p in dataset.iterdir()) == ["demo_0000", "demo_0001"]
    for bag in dataset.iterdir():
        assert sorted(p.name for p in bag.iterdir()) == [f"{bag.name}.mcap", "metadata.yaml"]
    trajs, names, report = load_dataset(dataset, gap_s=0)
    assert names == ["a", "b"] and len(trajs) == 2
    for traj, q in zip(trajs, sent[:2], strict=True):
        np.testing.assert_array_equal(traj.positions, q)
    assert report.messages_skipped == 0


@pytest.mark.parametrize("bad", [
    ["joints:=[a, a]"], ["dataset_dir:=''"],
    ["dataset_dir:={tmp}/file/ds"],  # ENOTDIR: under a file
    ["dataset_dir:={tmp}/file"],  # a file, not a directory
])
def test_invalid_start_up_parameters_exit_with_a_message(tmp_path, bad):
    (tmp_path / "file").write_text("a file")
    bad = [item.format(tmp=tmp_path) for item in bad]
    args = [item for p in [f"dataset_dir:={tmp_path}", *bad] for item in ("-p", p)]
    proc = subprocess.run(
        [sys.executable, "-m", "policy_align_ros.nodes.recorder", "--ros-args", *args],
        env=dict(os.environ, ROS_DOMAIN_ID="104"), capture_output=True, timeout=60,
    )
    assert proc.returncode == 1, proc.stderr.decode()  # run_node's code for a bad start-up
    assert proc.stderr and b"Traceback" not in proc.stderr
    if "dataset_dir:=" in bad[0] and "file" in bad[0]:
        # The reason names the parameter and the path.
        message = proc.stderr.decode()
        assert "dataset_dir:" in message and bad[0].split(":=")[1] in message, message


def _spawn_recorder(tmp_path, domain_id: int, *params: str) -> subprocess.Popen:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_HOME=str(tmp_path / "ros_home"))
    cmd = [sys.executable, "-m", "policy_align_ros.nodes.recorder", "--ros-args"]
    for param in params:
        cmd += ["-p", param]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _terminate(proc: subprocess.Popen) -> tuple[int, str]:
    """SIGTERM (what a launch system or systemd sends); returns the status and stderr."""
    try:
        assert proc.poll() is None, proc.stderr.read().decode()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
        return proc.returncode, proc.stderr.read().decode()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stderr.close()


def test_sigterm_in_continuous_mode_writes_the_last_segment(tmp_path):
    dataset = tmp_path / "ds"
    q = np.random.default_rng(7).normal(size=(50, 2))
    proc = _spawn_recorder(tmp_path, 107, f"dataset_dir:={dataset}", "joints:=[a, b]",
                           "auto_split_gap_s:=600.0")
    try:
        with _ros(107) as ctx:
            harness = _Harness(ctx, None)
            try:
                harness.ready()
                for k in range(50):  # two segments: a 700 s gap in the stamps after 20
                    stamp = T0 + k * 10**7 + (700 * 10**9 if k >= 20 else 0)
                    harness.pub.publish(_msg(stamp, "ab", q[k]))
                    time.sleep(0.002)
                # The gap wrote the first; the second is only in memory (the idle flush
                # is 600 s away), so only the shutdown can write it.
                _wait(lambda: (dataset / "demo_0000").is_dir(), 20.0, "the first segment")
                time.sleep(1.0)  # let the messages arrive before the signal
            finally:
                harness.close()
    finally:
        status, err = _terminate(proc)
    assert "Traceback" not in err, err
    assert status == 0, err
    trajs, _, _ = load_dataset(dataset, gap_s=0)
    assert [len(t) for t in trajs] == [20, 30]
    np.testing.assert_array_equal(np.concatenate([t.positions for t in trajs]), q)


def test_sigterm_with_a_failing_dataset_dir_saves_to_the_fallback(tmp_path):
    # Continuous mode, the dataset directory becomes unusable
    # (replaced by a file: ENOTDIR), SIGTERM. Nothing finished may be lost, no traceback.
    dataset, moved = tmp_path / "ds", tmp_path / "ds_moved_away"
    q = np.random.default_rng(8).normal(size=(40, 2))
    proc = _spawn_recorder(tmp_path, 108, f"dataset_dir:={dataset}", "joints:=[a, b]",
                           "auto_split_gap_s:=600.0")
    try:
        with _ros(108) as ctx:
            harness = _Harness(ctx, None)
            try:
                harness.ready()
                for k in range(20):
                    harness.pub.publish(_msg(T0 + k * 10**7, "ab", q[k]))
                    time.sleep(0.002)
                # The first message after a 700 s stamp gap ends segment 1 (written).
                harness.pub.publish(_msg(T0 + 700 * 10**9, "ab", q[20]))
                _wait(lambda: (dataset / "demo_0000").is_dir(), 20.0, "the first segment")
                dataset.rename(moved)
                dataset.write_text("replaced by a file")
                for k in range(21, 40):
                    harness.pub.publish(_msg(T0 + 700 * 10**9 + k * 10**7, "ab", q[k]))
                    time.sleep(0.002)
                time.sleep(1.0)  # let the messages arrive before the signal
            finally:
                harness.close()
    finally:
        status, err = _terminate(proc)
    assert "Traceback" not in err, err
    assert status == 0, err
    fallback = tmp_path / "ros_home" / "policy_align_recorder" / "unsaved"
    assert str(fallback) in err, err  # the log names where the data went
    first, _, _ = load_dataset(moved, gap_s=0)
    second, _, _ = load_dataset(fallback, gap_s=0)
    np.testing.assert_array_equal(first[0].positions, q[:20])
    np.testing.assert_array_equal(second[0].positions, q[20:])


def test_sigkill_in_continuous_mode_keeps_every_finished_segment(tmp_path):
    dataset = tmp_path / "ds"
    q = np.random.default_rng(10).normal(size=(60, 2))
    proc = _spawn_recorder(tmp_path, 110, f"dataset_dir:={dataset}", "joints:=[a, b]",
                           "auto_split_gap_s:=600.0")
    try:
        with _ros(110) as ctx:
            harness = _Harness(ctx, None)
            try:
                harness.ready()
                for k in range(60):  # segments of 20; the third is unfinished
                    harness.pub.publish(_msg(T0 + (k // 20) * 10**12 + k * 10**7, "ab", q[k]))
                    time.sleep(0.002)
                _wait(lambda: (dataset / "demo_0001").is_dir(), 20.0, "two segments")
                time.sleep(0.5)
            finally:
                harness.close()
        assert proc.poll() is None, proc.stderr.read().decode()
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stderr.close()
    assert sorted(p.name for p in dataset.iterdir()) == ["demo_0000", "demo_0001"]
    trajs, _, report = load_dataset(dataset, gap_s=0)
    np.testing.assert_array_equal(np.concatenate([t.positions for t in trajs]), q[:40])
    assert report.messages_skipped == 0
