"""The ``recorder`` node when a write fails: the demonstration is kept, retried and written
(domain ids 106, 109, 116, 117).

Each test owns an ``rclpy.Context`` with its own ``domain_id`` and shuts it down.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from rclpy.parameter import Parameter
from recorder_rig import T0, _Harness, _msg, _ros, _wait
from std_srvs.srv import Trigger

from policy_align_ros.data import load_dataset
from policy_align_ros.nodes.recorder import RecorderNode


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
            assert not failed.success and str(dataset) in failed.message
            assert recorder.recorder.pending == 30  # kept in memory
            refused = harness.call(harness.start)
            assert not refused.success and not recorder.recorder.active
            assert recorder.recorder.pending == 30
            bad = recorder.set_parameters([Parameter("dataset_dir", value=str(dataset))])
            assert not bad[0].successful and "dataset_dir" in bad[0].reason
            bad = recorder.set_parameters(
                [Parameter("dataset_dir", value=str(dataset / "below"))])
            assert not bad[0].successful and "dataset_dir" in bad[0].reason
            assert recorder.get_parameter("dataset_dir").value == str(dataset)
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
            assert rec.pending == 10  # kept in memory
            refused = node._on_start(Trigger.Request(), Trigger.Response())
            assert not refused.success and not rec.active and rec.pending == 10
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
