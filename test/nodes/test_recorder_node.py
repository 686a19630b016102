"""ROS 2 integration tests of the ``recorder`` node (domain ids 100-149).

Each test owns an ``rclpy.Context`` with its own ``domain_id`` and shuts it down.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from policy_align_ros.data import load_dataset, read_joint_states
from policy_align_ros.nodes.recorder import RecorderNode
from policy_align_ros.polling import wait_for

T0 = 1_700_000_000 * 10**9
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10000,
                 reliability=ReliabilityPolicy.RELIABLE)


def _msg(stamp_ns: int, names, positions, velocities=()) -> JointState:
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg.name = list(names)
    msg.position = [float(x) for x in positions]
    msg.velocity = [float(x) for x in velocities]
    return msg


def _wait(predicate, timeout: float, what: str) -> None:
    if not wait_for(predicate, timeout):
        raise AssertionError(f"timed out after {timeout} s waiting for {what}")


class _Harness:
    """A test node (publisher, service clients) and optionally a recorder, spun in a thread."""

    def __init__(self, ctx: rclpy.Context, recorder: RecorderNode | None,
                 recorder_name: str = "/recorder") -> None:
        self.node = Node("recorder_test_client", context=ctx)
        self.pub = self.node.create_publisher(JointState, "/joint_states", QOS)
        self.start = self.node.create_client(Trigger, f"{recorder_name}/start_demo")
        self.stop = self.node.create_client(Trigger, f"{recorder_name}/stop_demo")
        self.recorder = recorder
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.node)
        if recorder is not None:
            self.executor.add_node(recorder)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def ready(self, timeout: float = 20.0) -> None:
        assert self.start.wait_for_service(timeout_sec=timeout), "no ~/start_demo"
        assert self.stop.wait_for_service(timeout_sec=timeout), "no ~/stop_demo"
        _wait(lambda: self.pub.get_subscription_count() >= 1, timeout, "the subscription")
        if self.recorder is not None:
            sub = self.recorder.subscription
            _wait(lambda: sub.get_publisher_count() >= 1, timeout, "the publisher")
        time.sleep(0.3)  # let both ends of the reliable match settle

    def call(self, client, timeout: float = 20.0) -> Trigger.Response:
        future = client.call_async(Trigger.Request())
        _wait(future.done, timeout, "a service response")
        return future.result()

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        self.thread.join(timeout=5.0)
        self.node.destroy_node()
        if self.recorder is not None:
            self.recorder.destroy_node()


@contextmanager
def _ros(domain_id: int):
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


def test_burst_1khz_for_10s_zero_loss(tmp_path):
    rng = np.random.default_rng(0)
    names = [f"joint_{i}" for i in range(22)]
    count = 10_000
    q = rng.normal(size=(count, 22))
    v = rng.normal(size=(count, 22))
    stamps = T0 + np.arange(count, dtype=np.int64) * 1_000_000
    msgs = [_msg(stamps[k], names, q[k], v[k]) for k in range(count)]
    with _ros(101) as ctx:
        recorder = RecorderNode(context=ctx, parameter_overrides=[
            Parameter("dataset_dir", value=str(tmp_path))])
        harness = _Harness(ctx, recorder)
        try:
            harness.ready()
            assert harness.call(harness.start).success
            t_start = time.perf_counter()
            for k, msg in enumerate(msgs):
                # Paced on an absolute schedule: late messages go out at once.
                delay = t_start + k * 1e-3 - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                harness.pub.publish(msg)
            _wait(lambda: recorder.recorder.buffered == count, 30.0,
                  f"{count} messages (have {recorder.recorder.buffered})")
            response = harness.call(harness.stop)
        finally:
            harness.close()
    assert response.success, response.message
    read = list(read_joint_states(response.message))
    assert len(read) == count
    assert [m[1] for m in read] == stamps.tolist()
    np.testing.assert_array_equal(np.array([m[3] for m in read]), q)
    np.testing.assert_array_equal(np.array([m[4] for m in read]), v)
    assert sum(recorder.recorder.skipped.values()) == 0


def _served(executor: SingleThreadedExecutor, future, timeout: float = 20.0):
    """Spin ``executor`` (the recorder's own) until ``future`` is done; its result."""
    deadline = time.monotonic() + timeout
    while not future.done():
        assert time.monotonic() < deadline, "timed out waiting for a service response"
        executor.spin_once(timeout_sec=0.05)
    return future.result()


def test_stop_records_the_backlog_queued_before_it(tmp_path):
    # The recorder is spun by hand, so a burst queues up in its subscription as it would
    # behind a slow write on a loaded machine. The executor takes one message per
    # subscription between other callbacks: stop_demo must still record every message
    # that arrived before it (before the drain it wrote 1 of the 300).
    count = 300
    msgs = [_msg(T0 + k * 1_000_000, ["a", "b"], [k, -k], [1.0, 2.0]) for k in range(count)]
    with _ros(111) as ctx:
        recorder = RecorderNode(context=ctx, parameter_overrides=[
            Parameter("dataset_dir", value=str(tmp_path))])
        own = SingleThreadedExecutor(context=ctx)
        own.add_node(recorder)
        harness = _Harness(ctx, None)
        try:
            assert harness.stop.wait_for_service(timeout_sec=20.0)
            _wait(lambda: recorder.subscription.get_publisher_count() >= 1, 20.0,
                  "the publisher")
            time.sleep(0.3)
            assert _served(own, harness.start.call_async(Trigger.Request())).success
            for msg in msgs:
                harness.pub.publish(msg)
            time.sleep(1.0)  # delivered into the recorder's queue, not yet taken
            assert recorder.recorder.buffered == 0
            response = _served(own, harness.stop.call_async(Trigger.Request()))
        finally:
            own.shutdown(timeout_sec=2.0)
            harness.close()
            recorder.destroy_node()
    assert response.success, response.message
    read = list(read_joint_states(response.message))
    assert [m[1] for m in read] == [T0 + k * 1_000_000 for k in range(count)]
    assert sum(recorder.recorder.skipped.values()) == 0


def test_writes_exactly_the_valid_messages_and_counts_the_rest(tmp_path):
    ok = [0.1, 0.2]
    t = [T0 + k * 10_000_000 for k in range(30)]
    valid = [_msg(t[k], ["a", "b"], [k, -k], [1.0, 2.0]) for k in range(0, 20, 2)]
    malformed = [
        _msg(t[1], ["a", "b"], [0.1]),
        _msg(t[3], ["a", "a"], ok),
        _msg(t[5], ["c", "d"], ok),
        _msg(t[7], ["a"], [0.1]),
        _msg(t[9], ["a", "b"], [float("nan"), 0.0]),
        _msg(t[2], ["a", "b"], ok),  # sent after t[10]: backwards
    ]
    order = valid[:6] + malformed + valid[6:]
    with _ros(102) as ctx:
        recorder = RecorderNode(context=ctx, parameter_overrides=[
            Parameter("dataset_dir", value=str(tmp_path / "ds")),
            Parameter("joints", value=["a", "b"])])
        harness = _Harness(ctx, recorder)
        try:
            harness.ready()
            empty = harness.call(harness.stop)
            assert not empty.success and "nothing written" in empty.message
            assert harness.call(harness.start).success
            again = harness.call(harness.start)
            assert not again.success and "already recording" in again.message
            for msg in order:
                harness.pub.publish(msg)
                time.sleep(0.002)
            _wait(lambda: recorder.recorder.accepted
                  + sum(recorder.recorder.skipped.values()) == len(order), 10.0, "all messages")
            result = recorder.set_parameters([Parameter("joints", value=["a", "b", "c"])])
            assert not result[0].successful and "while a demonstration" in result[0].reason
            response = harness.call(harness.stop)
            assert response.success
            assert response.message == str(tmp_path / "ds" / "demo_0000")
            result = recorder.set_parameters([Parameter("auto_split_gap_s", value=-1.0)])
            assert not result[0].successful
            result = recorder.set_parameters([Parameter("dataset_dir", value=" ")])
            assert not result[0].successful and "dataset_dir" in result[0].reason
        finally:
            harness.close()
    assert dict(recorder.recorder.skipped) == {
        "length_mismatch": 1, "duplicate_joints": 1, "unknown_joints": 1,
        "missing_joints": 1, "non_finite": 1, "time_not_increasing": 1,
    }
    trajs, names, _ = load_dataset(response.message, gap_s=0)
    assert names == ["a", "b"]
    np.testing.assert_array_equal(trajs[0].positions, [[k, -k] for k in range(0, 20, 2)])


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


def test_continuous_mode_splits_when_the_stream_pauses(tmp_path):
    q = np.random.default_rng(5).normal(size=(40, 2))
    with _ros(105) as ctx:
        recorder = RecorderNode(context=ctx, parameter_overrides=[
            Parameter("dataset_dir", value=str(tmp_path)),
            Parameter("auto_split_gap_s", value=0.3)])
        harness = _Harness(ctx, recorder)
        try:
            harness.ready()
            assert recorder.recorder.active  # continuous mode records from start-up
            for k in range(20):
                harness.pub.publish(_msg(T0 + k * 10**7, "ab", q[k]))
                time.sleep(0.002)
            # The idle timer closes the first demonstration while the stream is quiet.
            _wait(lambda: len(recorder.recorder.written) == 1, 10.0, "the idle split")
            for k in range(20, 40):
                harness.pub.publish(_msg(T0 + 5 * 10**9 + k * 10**7, "ab", q[k]))
                time.sleep(0.002)
            _wait(lambda: recorder.recorder.buffered == 20, 10.0, "the second demo")
            recorder.shutdown()  # a clean shutdown keeps the last segment
        finally:
            harness.close()
    trajs, _, _ = load_dataset(tmp_path, gap_s=0)
    assert [len(t) for t in trajs] == [20, 20]
    np.testing.assert_array_equal(np.concatenate([t.positions for t in trajs]), q)


def test_failed_write_is_kept_refused_and_written_after_a_fix(tmp_path, monkeypatch):
    from policy_align_ros.nodes import recorder as recorder_module

    # Only stop_demo writes it here (the timer's retry has its own test).
    monkeypatch.setattr(recorder_module, "_RETRY_PERIOD_S", 1e6)
    dataset = tmp_path / "ds"
    q = np.random.default_rng(6).normal(size=(30, 2))
    with _ros(106) as ctx:
        recorder = RecorderNode(context=ctx, parameter_overrides=[
            Parameter("dataset_dir", value=str(dataset))])
        harness = _Harness(ctx, recorder)
        try:
            harness.ready()
            assert harness.call(harness.start).success
            for k in range(30):
                harness.pub.publish(_msg(T0 + k * 10**7, "ab", q[k]))
                time.sleep(0.002)
            _wait(lambda: recorder.recorder.buffered == 30, 10.0, "30 messages")
            dataset.rmdir()
            dataset.write_text("the directory was replaced by a file")  # ENOTDIR
            failed = harness.call(harness.stop)
            assert not failed.success
            assert "writing failed" in failed.message and "kept in memory" in failed.message
            refused = harness.call(harness.start)
            assert not refused.success and "could not be written" in refused.message
            bad = recorder.set_parameters([Parameter("dataset_dir", value=str(dataset))])
            assert not bad[0].successful and "dataset_dir" in bad[0].reason
            bad = recorder.set_parameters(
                [Parameter("dataset_dir", value=str(dataset / "below"))])
            assert not bad[0].successful and "cannot write into" in bad[0].reason
            good = recorder.set_parameters(
                [Parameter("dataset_dir", value=str(tmp_path / "fixed"))])
            assert good[0].successful, good[0].reason
            written = harness.call(harness.stop)
            assert written.success, written.message
            assert written.message == str(tmp_path / "fixed" / "demo_0000")
            assert harness.call(harness.start).success  # nothing pending any more
        finally:
            harness.close()
    trajs, _, _ = load_dataset(tmp_path / "fixed", gap_s=0)
    np.testing.assert_array_equal(trajs[0].positions, q)


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


def test_pending_demo_is_retried_by_the_timer_and_recording_resumes(tmp_path, monkeypatch):
    # Continuous mode: a full disk (EFBIG) at a split keeps the segment; once the disk
    # accepts writes again the timer writes it and recording resumes by itself.
    import errno

    from policy_align_ros.data.bags import write as bags
    from policy_align_ros.nodes import recorder as recorder_module

    monkeypatch.setattr(recorder_module, "_RETRY_PERIOD_S", 0.0)  # every timer tick
    real, full = bags._joint_state_cdr, [False]

    def cdr(*args):
        if full[0]:
            raise OSError(errno.EFBIG, "File too large")
        return real(*args)

    monkeypatch.setattr(bags, "_joint_state_cdr", cdr)
    q = np.random.default_rng(9).normal(size=(40, 2))
    with _ros(109) as ctx:
        recorder = RecorderNode(context=ctx, parameter_overrides=[
            Parameter("dataset_dir", value=str(tmp_path)),
            Parameter("auto_split_gap_s", value=600.0)])
        harness = _Harness(ctx, recorder)
        rec = recorder.recorder
        try:
            harness.ready()
            for k in range(20):
                harness.pub.publish(_msg(T0 + k * 10**7, "ab", q[k]))
                time.sleep(0.002)
            _wait(lambda: rec.buffered == 20, 10.0, "the first segment")
            full[0] = True
            harness.pub.publish(_msg(T0 + 700 * 10**9, "ab", q[20]))  # split: write fails
            _wait(lambda: rec.pending == 20, 10.0, "the pending segment")
            assert not harness.call(harness.start).success  # refused while pending
            bad = recorder.set_parameters([Parameter("dataset_dir", value=5)])
            assert not bad[0].successful
            full[0] = False
            _wait(lambda: rec.pending == 0, 10.0, "the retry")
            assert rec.active and len(rec.written) == 1
            for k in range(21, 40):
                harness.pub.publish(_msg(T0 + 700 * 10**9 + k * 10**7, "ab", q[k]))
                time.sleep(0.002)
            _wait(lambda: rec.buffered == 19, 10.0, "the second segment")
            recorder.shutdown()
        finally:
            harness.close()
    assert rec.lost_while_pending == 1  # the message that ended the segment during the outage
    trajs, _, _ = load_dataset(tmp_path, gap_s=0)
    np.testing.assert_array_equal(trajs[0].positions, q[:20])
    np.testing.assert_array_equal(trajs[1].positions, q[21:])


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


def test_idle_split_follows_sim_time(tmp_path):
    # With use_sim_time the idle split waits for /clock, however long the wall clock runs.
    from rosgraph_msgs.msg import Clock

    q = np.random.default_rng(11).normal(size=(10, 2))
    with _ros(114) as ctx:
        recorder = RecorderNode(context=ctx, parameter_overrides=[
            Parameter("dataset_dir", value=str(tmp_path)),
            Parameter("auto_split_gap_s", value=1.0),
            Parameter("use_sim_time", value=True)])
        harness = _Harness(ctx, recorder)
        clock_pub = harness.node.create_publisher(Clock, "/clock", 10)
        rec = recorder.recorder

        def tick(seconds: int) -> None:
            msg = Clock()
            msg.clock.sec = seconds
            clock_pub.publish(msg)

        try:
            harness.ready()
            _wait(lambda: clock_pub.get_subscription_count() >= 1, 20.0, "/clock subscriber")
            tick(100)
            _wait(lambda: recorder.get_clock().now().nanoseconds == 100 * 10**9, 20.0,
                  "sim time 100 s")
            for k in range(10):
                harness.pub.publish(_msg(T0 + k * 10**7, "ab", q[k]))
                time.sleep(0.002)
            _wait(lambda: rec.buffered == 10, 10.0, "10 messages")
            time.sleep(1.5)  # > auto_split_gap_s of wall time, no sim time
            assert rec.written == [] and rec.buffered == 10
            tick(102)
            _wait(lambda: len(rec.written) == 1, 10.0, "the idle split at sim time 102 s")
        finally:
            harness.close()
    trajs, _, _ = load_dataset(tmp_path, gap_s=0)
    np.testing.assert_array_equal(trajs[0].positions, q)


def test_negative_stamps_are_skipped_and_finished_demos_survive(tmp_path, monkeypatch):
    # A good segment, a publisher with an unset clock (sec = -1), good again: a negative
    # stamp must not reach a split (an OverflowError out of the callback) nor shutdown().
    monkeypatch.setenv("ROS_HOME", str(tmp_path / "ros_home"))
    q = np.random.default_rng(12).normal(size=(15, 2))
    with _ros(115) as ctx:
        node = RecorderNode(context=ctx, parameter_overrides=[
            Parameter("dataset_dir", value=str(tmp_path / "ds")),
            Parameter("joints", value=["a", "b"]), Parameter("auto_split_gap_s", value=0.5)])
        try:
            now = node.get_clock().now().nanoseconds
            for k in range(5):
                node._on_joint_state(_msg(now - 10**9 + k * 10**7, "ab", q[k]))
            for k in range(5, 10):
                negative = _msg(-10**9 + k * 10**7, "ab", q[k])
                assert negative.header.stamp.sec == -1
                node._on_joint_state(negative)
            for k in range(10, 15):  # the 1 s gap to the first segment splits it off
                node._on_joint_state(_msg(now + k * 10**7, "ab", q[k]))
            rec = node.recorder
            assert rec.skipped["time_negative"] == 5 and rec.accepted == 10
            assert [p.name for p in rec.written] == ["demo_0000"] and rec.pending == 0
            node._on_timer()  # the throttled warning names the reason; must not raise
            node.shutdown()  # continuous mode: writes the last segment, never raises
            assert [p.name for p in rec.written] == ["demo_0000", "demo_0001"]
        finally:
            node.destroy_node()
    trajs, _, _ = load_dataset(tmp_path / "ds", gap_s=0)
    np.testing.assert_array_equal(trajs[0].positions, q[:5])
    np.testing.assert_array_equal(trajs[1].positions, q[10:])
    assert not (tmp_path / "ros_home" / "policy_align_recorder").exists()  # no fallback


@pytest.mark.parametrize(("domain_id", "err"), [
    (116, OverflowError("int too big to convert")),
    (117, RuntimeError("rosbags writer failed")),
])
def test_unexpected_write_error_keeps_the_demo_pending_and_the_node_alive(
        tmp_path, monkeypatch, domain_id, err):
    # Any exception of the writer is a failed write: stop_demo answers success=false, the
    # demonstration stays pending, the timer retries it, and shutdown() does not raise.
    from policy_align_ros.data.bags import write as bags
    from policy_align_ros.nodes import recorder as recorder_module

    monkeypatch.setenv("ROS_HOME", str(tmp_path / "ros_home"))
    monkeypatch.setattr(recorder_module, "_RETRY_PERIOD_S", 0.0)  # every timer tick
    real, fail = bags._joint_state_cdr, [True]

    def cdr(*args):
        if fail[0]:
            raise err
        return real(*args)

    monkeypatch.setattr(bags, "_joint_state_cdr", cdr)
    q = np.random.default_rng(13).normal(size=(20, 2))
    with _ros(domain_id) as ctx:
        node = RecorderNode(context=ctx, parameter_overrides=[
            Parameter("dataset_dir", value=str(tmp_path / "ds"))])
        try:
            rec = node.recorder
            now = node.get_clock().now().nanoseconds
            assert node._on_start(Trigger.Request(), Trigger.Response()).success
            for k in range(10):
                node._on_joint_state(_msg(now + k * 10**7, "ab", q[k]))
            failed = node._on_stop(Trigger.Request(), Trigger.Response())
            assert not failed.success and type(err).__name__ in failed.message
            assert "kept in memory" in failed.message and rec.pending == 10
            refused = node._on_start(Trigger.Request(), Trigger.Response())
            assert not refused.success and "could not be written" in refused.message
            node._on_timer()  # the retry fails again: logged, not raised
            assert rec.pending == 10
            fail[0] = False
            node._on_timer()  # the retry writes it
            assert rec.pending == 0 and [p.name for p in rec.written] == ["demo_0000"]
            # A second demonstration still failing at shutdown: reported, never raised.
            assert node._on_start(Trigger.Request(), Trigger.Response()).success
            for k in range(10, 20):
                node._on_joint_state(_msg(now + k * 10**7, "ab", q[k]))
            fail[0] = True
            assert not node._on_stop(Trigger.Request(), Trigger.Response()).success
            node.shutdown()
            assert rec.pending == 0 and len(rec.written) == 1  # every directory failed
        finally:
            node.destroy_node()
    trajs, _, _ = load_dataset(tmp_path / "ds", gap_s=0)
    np.testing.assert_array_equal(trajs[0].positions, q[:10])
