"""ROS 2 integration tests of the ``recorder`` node: recording, splitting, skipped messages
(domain ids 101, 102, 103, 105, 111, 114, 115, 218).

Each test owns an ``rclpy.Context`` with its own ``domain_id`` and shuts it down.
"""

from __future__ import annotations

import time

import numpy as np
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from recorder_rig import T0, _ab_recorder, _Harness, _msg, _ros, _wait
from std_srvs.srv import Trigger

from policy_align_ros.data import load_dataset, read_joint_states
from policy_align_ros.nodes.recorder import RecorderNode


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
            assert not empty.success and not (tmp_path / "ds" / "demo_0000").exists()
            assert harness.call(harness.start).success
            again = harness.call(harness.start)
            assert not again.success and recorder.recorder.active  # the first one goes on
            for msg in order:
                harness.pub.publish(msg)
                time.sleep(0.002)
            _wait(lambda: recorder.recorder.accepted
                  + sum(recorder.recorder.skipped.values()) == len(order), 10.0, "all messages")
            result = recorder.set_parameters([Parameter("joints", value=["a", "b", "c"])])
            assert not result[0].successful and "joints" in result[0].reason
            assert recorder.get_parameter("joints").value == ["a", "b"]
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


def test_stop_without_start_refuses_and_a_still_demonstration_is_written_with_a_warning(
        tmp_path):
    still = [_msg(T0 + k * 10_000_000, ["a", "b"], [0.3, -0.2]) for k in range(5)]
    moving = [_msg(T0 + 10**9 + k * 10_000_000, ["a", "b"], [0.3 + 0.1 * k, -0.2])
              for k in range(5)]
    with _ab_recorder(218, tmp_path / "ds") as (harness, rec):
        # Nothing to stop: refused, nothing written, and the recorder is not started.
        response = harness.call(harness.stop)
        assert not response.success and rec.written == [] and not rec.active
        answers = []
        for messages in (still, moving):
            assert harness.call(harness.start).success
            target = rec.accepted + len(messages)
            for msg in messages:
                harness.pub.publish(msg)
            _wait(lambda t=target: rec.accepted >= t, 10.0, "the messages")
            answers.append(harness.call(harness.stop))
    # Both written (a recorder never drops data); the still one with a warning after its
    # path, the other with its path alone.
    assert [a.success for a in answers] == [True, True]
    first, second = rec.written
    assert rec.still_bags == [first]
    assert answers[0].message.startswith(f"{first}; ") and answers[1].message == str(second)
    assert len(load_dataset(first, gap_s=0)[0][0].positions) == len(still)


def test_a_demonstration_across_a_clock_reset_is_refused_and_not_written(tmp_path):
    # A simulator reset mid-demonstration: the stamps jump 2 s back and run on.
    before = [_msg(T0 + k * 10_000_000, ["a", "b"], [0.01 * k, 0.0]) for k in range(300)]
    after = [_msg(T0 + 10**9 + k * 10_000_000, ["a", "b"], [0.0, 0.01 * k])
             for k in range(300)]
    with _ab_recorder(103, tmp_path / "ds") as (harness, rec):
        assert harness.call(harness.start).success
        for msg in before + after:
            harness.pub.publish(msg)
        _wait(lambda: rec.accepted + sum(rec.skipped.values()) >= 600, 10.0, "the messages")
        response = harness.call(harness.stop)
    assert not response.success and rec.discarded == 1 and rec.written == []
    assert not (tmp_path / "ds" / "demo_0000").exists()
