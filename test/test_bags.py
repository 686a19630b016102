"""Tests of policy_align_ros.data.bags and data.messages: rosbag2 round trips, splitting,
malformed-message accounting, foreign bags, atomic writes. ROS-free."""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from policy_align_ros.data import bags
from policy_align_ros.data.bags import (
    find_bags,
    load_dataset,
    read_joint_states,
    write_joint_state_bag,
)
from policy_align_ros.data.messages import (
    NEW,
    SAME,
    SKIP,
    JointSelector,
    StreamClock,
    validate_joint_names,
)

TS = get_typestore(Stores.ROS2_HUMBLE)
JS = TS.types["sensor_msgs/msg/JointState"]
HEADER = TS.types["std_msgs/msg/Header"]
TIME = TS.types["builtin_interfaces/msg/Time"]
T0 = 1_700_000_000 * 10**9
MS = 10**6


def _demo(rng: np.random.Generator, n_samples: int = 50, n: int = 3):
    stamps = T0 + np.cumsum(rng.integers(5, 15, n_samples)) * MS
    q = rng.normal(size=(n_samples, n))
    v = rng.normal(size=(n_samples, n))
    return stamps, q, v


def _foreign_bag(path, messages, *, storage=StoragePlugin.SQLITE3, topic="/robot/joints"):
    """Write arbitrary JointState messages (and one unrelated topic), as another tool would.

    ``messages`` are (stamp_ns, names, positions, velocities[, bag_time_ns]).
    """
    with Writer(path, version=8, storage_plugin=storage) as writer:
        conn = writer.add_connection(topic, JS.__msgtype__, typestore=TS)
        other = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=TS)
        string = TS.types["std_msgs/msg/String"]
        for item in messages:
            stamp, names, pos, vel = item[:4]
            bag_time = item[4] if len(item) > 4 else stamp
            msg = JS(
                header=HEADER(stamp=TIME(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=""),
                name=list(names),
                position=np.asarray(pos, dtype=float),
                velocity=np.asarray(vel, dtype=float),
                effort=np.empty(0),
            )
            writer.write(conn, bag_time, TS.serialize_cdr(msg, JS.__msgtype__))
            writer.write(other, bag_time, TS.serialize_cdr(string(data="x"), string.__msgtype__))


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    stamps, q, v = _demo(rng)
    path = write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q, v)
    trajs, names, report = load_dataset(path, gap_s=0)
    assert names == ["a", "b", "c"]
    assert len(trajs) == 1
    np.testing.assert_array_equal(trajs[0].positions, q)
    np.testing.assert_array_equal(trajs[0].velocities, v)
    np.testing.assert_allclose(trajs[0].times, (stamps - stamps[0]) * 1e-9, rtol=0, atol=1e-12)
    assert report.demos[0].start_ns == stamps[0]
    assert report.messages_used == len(stamps) and report.messages_skipped == 0
    # The stored header stamps are the ones given, to the nanosecond.
    read = [m[1] for m in read_joint_states(path)]
    assert read == [int(s) for s in stamps]


def test_velocities_only_when_every_message_has_them(tmp_path):
    rng = np.random.default_rng(1)
    stamps, q, v = _demo(rng, 20)
    flags = np.ones(20, dtype=bool)
    flags[7] = False
    write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q, v,
                          has_velocity=flags)
    write_joint_state_bag(tmp_path / "demo_0001", ["a", "b", "c"], stamps + 10**12, q)
    trajs, _, _ = load_dataset(tmp_path)
    assert [t.velocities is None for t in trajs] == [True, True]
    np.testing.assert_array_equal(trajs[0].positions, q)
    velocities = [m[4] for m in read_joint_states(tmp_path / "demo_0000")]
    assert len(velocities[7]) == 0
    np.testing.assert_array_equal(velocities[8], v[8])


def test_dataset_split_at_gaps(tmp_path):
    rng = np.random.default_rng(2)
    stamps, q, _ = _demo(rng, 90)
    stamps = stamps.copy()
    stamps[30:] += 2 * 10**9  # 2 s pause -> split with gap 0.5 s
    stamps[60:] += 10**9  # 1 s pause -> split with 0.5 s, not with 1.5 s
    write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q)
    trajs, _, report = load_dataset(tmp_path, gap_s=0.5)
    assert [len(t) for t in trajs] == [30, 30, 30]
    np.testing.assert_array_equal(trajs[2].positions, q[60:])
    assert trajs[1].times[0] == 0.0
    assert report.demos[1].start_ns == stamps[30]
    trajs, _, _ = load_dataset(tmp_path, gap_s=1.5)
    assert [len(t) for t in trajs] == [30, 60]
    trajs, _, _ = load_dataset(tmp_path, gap_s=0)
    assert [len(t) for t in trajs] == [90]


def test_too_short_demos_are_counted(tmp_path):
    rng = np.random.default_rng(3)
    stamps, q, _ = _demo(rng, 12)
    stamps = stamps.copy()
    stamps[10:] += 5 * 10**9
    write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q)
    trajs, _, report = load_dataset(tmp_path, gap_s=0.5, min_samples=3)
    assert [len(t) for t in trajs] == [10]
    assert (report.demos_found, report.demos_too_short) == (2, 1)


def test_every_malformed_kind_is_skipped_and_counted(tmp_path):
    j = ["a", "b"]
    ok = [0.1, 0.2]
    t = [T0 + k * 10 * MS for k in range(20)]
    messages = [
        (t[0], j, ok, ok),
        (t[1], j, [0.1], []),  # length_mismatch: positions
        (t[2], j, ok, [1.0]),  # length_mismatch: velocities
        (t[3], ["a", "a"], ok, []),  # duplicate_joints
        (t[4], ["x", "y"], ok, []),  # unknown_joints
        (t[5], ["a", "x"], ok, []),  # missing_joints
        (t[6], j, [np.nan, 0.0], []),  # non_finite position
        (t[7], j, ok, [np.inf, 0.0]),  # non_finite velocity
        (t[8], j, [0.3, 0.4], []),  # valid
        (t[8], j, ok, []),  # time_not_increasing: repeated stamp
        (t[8] - 5 * MS, j, ok, []),  # time_not_increasing: backwards
        (t[9], ["b", "a"], [0.6, 0.5], []),  # valid, other order
    ]
    # Receive (bag) times keep increasing while the header stamps misbehave.
    received = [(*m, T0 + k * MS) for k, m in enumerate(messages)]
    _foreign_bag(tmp_path / "bag", received)
    trajs, names, report = load_dataset(tmp_path / "bag", gap_s=0.5)
    assert names == ["a", "b"]
    assert len(trajs) == 1
    np.testing.assert_array_equal(trajs[0].positions, [[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])
    assert trajs[0].velocities is None  # not every accepted message had velocities
    assert report.skipped == {
        "length_mismatch": 2,
        "duplicate_joints": 1,
        "unknown_joints": 1,
        "missing_joints": 1,
        "non_finite": 2,
        "time_not_increasing": 2,
    }
    assert report.messages_read == len(messages)
    assert report.messages_used == 3
    assert report.topics == ["/robot/joints"]


def test_foreign_bag_extra_joints_other_order_matched_by_name(tmp_path):
    rng = np.random.default_rng(4)
    wanted = ["arm_2", "arm_1"]
    recorded = ["gripper", "arm_1", "head", "arm_2"]
    full = rng.normal(size=(40, 4))
    stamps = [T0 + k * 20 * MS for k in range(40)]
    _foreign_bag(
        tmp_path / "foreign",
        [(s, recorded, row, row * 2) for s, row in zip(stamps, full, strict=True)],
        storage=StoragePlugin.MCAP,
    )
    trajs, names, report = load_dataset([tmp_path / "foreign"], joints=wanted)
    assert names == wanted
    np.testing.assert_array_equal(trajs[0].positions, full[:, [3, 1]])
    np.testing.assert_array_equal(trajs[0].velocities, 2 * full[:, [3, 1]])
    assert report.messages_skipped == 0
    # Without a selection, the first message's joints and order are used.
    _, names, _ = load_dataset([tmp_path / "foreign"])
    assert names == recorded


def test_zero_header_stamp_falls_back_to_bag_time(tmp_path):
    j, ok = ["a"], [1.0]
    bag_times = [T0 + k * 10 * MS for k in range(5)]
    _foreign_bag(tmp_path / "bag", [(0, j, ok, [], bt) for bt in bag_times])
    trajs, _, report = load_dataset(tmp_path / "bag")
    assert report.demos[0].start_ns == bag_times[0]
    np.testing.assert_allclose(trajs[0].times, [0, 0.01, 0.02, 0.03, 0.04])


def test_clock_reset_starts_new_demo_instead_of_skipping_the_rest(tmp_path):
    j = ["a"]
    first = [(T0 + k * 10 * MS, j, [float(k)], []) for k in range(10)]
    restarted = [(T0 - 100 * 10**9 + k * 10 * MS, j, [float(k)], []) for k in range(10)]
    _foreign_bag(tmp_path / "bag", first + restarted)
    trajs, _, report = load_dataset(tmp_path / "bag", gap_s=0.5)
    assert [len(t) for t in trajs] == [10, 10]
    assert report.skipped["time_not_increasing"] == 0


def test_dataset_ignores_temporary_and_unrelated_entries(tmp_path):
    rng = np.random.default_rng(5)
    stamps, q, _ = _demo(rng, 10)
    write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q)
    # What a writer killed mid-bag leaves: a hidden directory with a partial bag.
    partial = tmp_path / ".tmp-demo_0001-123-abcd"
    partial.mkdir()
    (partial / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9\n")
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "empty_dir").mkdir()
    assert find_bags(tmp_path) == [tmp_path / "demo_0000"]
    trajs, _, report = load_dataset(tmp_path)
    assert len(trajs) == 1 and report.bags == [str(tmp_path / "demo_0000")]


def test_crash_mid_write_leaves_no_partial_bag(tmp_path, monkeypatch):
    rng = np.random.default_rng(6)
    stamps, q, _ = _demo(rng, 30)
    write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q)
    real = bags._joint_state_cdr
    calls = {"n": 0}

    def failing(*args):
        calls["n"] += 1
        if calls["n"] > 10:
            raise OSError("disk on fire")
        return real(*args)

    monkeypatch.setattr(bags, "_joint_state_cdr", failing)
    with pytest.raises(OSError, match="disk on fire"):
        write_joint_state_bag(tmp_path / "demo_0001", ["a", "b", "c"], stamps, q)
    assert calls["n"] == 11  # the failure really happened mid-write
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo_0000"]
    trajs, _, _ = load_dataset(tmp_path)
    assert len(trajs) == 1


def test_crash_between_close_and_rename_is_invisible(tmp_path, monkeypatch):
    rng = np.random.default_rng(7)
    stamps, q, _ = _demo(rng, 10)

    def no_rename(src, dst):
        raise OSError("killed before rename")

    monkeypatch.setattr(bags.os, "rename", no_rename)
    with pytest.raises(OSError, match="killed before rename"):
        write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q)
    assert list(tmp_path.iterdir()) == []


def test_dataset_moved_away_right_after_the_rename_still_reports_the_bag_written(
        tmp_path, monkeypatch):
    # The race a recorder met in CI: the bag was complete under its final name, the dataset
    # directory was then replaced by a file, and tidying up failed. Reporting that write as
    # failed made the recorder write the same demonstration again, into its fallback.
    rng = np.random.default_rng(10)
    stamps, q, _ = _demo(rng, 6)
    dataset, moved = tmp_path / "ds", tmp_path / "moved"
    real = bags._rename_into_place

    def rename_then_move_the_dataset(tmp, final, unique):
        path = real(tmp, final, unique)
        dataset.rename(moved)
        dataset.write_text("replaced by a file")
        return path

    monkeypatch.setattr(bags, "_rename_into_place", rename_then_move_the_dataset)
    path = write_joint_state_bag(dataset / "demo_0000", ["a", "b", "c"], stamps, q)
    assert path == dataset / "demo_0000"
    trajs, _, _ = load_dataset(moved / "demo_0000", gap_s=0)
    np.testing.assert_array_equal(trajs[0].positions, q)


def test_write_refuses_to_overwrite_and_unique_picks_next_name(tmp_path):
    rng = np.random.default_rng(8)
    stamps, q, _ = _demo(rng, 5)
    first = write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q)
    with pytest.raises(ValueError, match="exists"):
        write_joint_state_bag(first, ["a", "b", "c"], stamps, q)
    second = write_joint_state_bag(first, ["a", "b", "c"], stamps, q, unique=True)
    assert second.name == "demo_0001"
    with pytest.raises(ValueError, match=r"shape \(5, 2\)"):
        write_joint_state_bag(tmp_path / "x", ["a", "b"], stamps, q)


@pytest.mark.parametrize("joints, stamps, match", [
    (["a", "a"], [1, 2], "listed twice"),  # a bag every reader would skip entirely
    (["a", ""], [1, 2], "invalid joint name"),
    ([], [1, 2], "must not be empty"),
    (["a", "b"], [-5, 10], "stamp -5 ns of message 0 is out of range"),  # was OverflowError
    (["a", "b"], [1, 2**31 * 10**9], "of message 1 is out of range"),  # was struct.error
    (["a", "b"], 7, r"stamps_ns must have shape \(N,\)"),  # was IndexError
])
def test_unwritable_input_is_a_value_error_naming_the_bag(tmp_path, joints, stamps, match):
    n_msgs = np.size(stamps)
    q = np.zeros((n_msgs, len(joints)))
    with pytest.raises(ValueError, match=match) as info:
        write_joint_state_bag(tmp_path / "demo_0000", joints, stamps, q)
    assert str(tmp_path / "demo_0000") in str(info.value)
    assert list(tmp_path.iterdir()) == []  # nothing left behind, not even a staging dir


def test_a_rename_that_fails_for_another_reason_reports_that_reason(tmp_path, monkeypatch):
    # Only a name taken by another writer is worth trying the next name for; before, a
    # denied rename tried 1000 names and then blamed the names.
    rng = np.random.default_rng(9)
    stamps, q, _ = _demo(rng, 5)

    def denied(src, dst):
        raise PermissionError(errno.EACCES, "Permission denied", str(dst))

    monkeypatch.setattr(bags.os, "rename", denied)
    with pytest.raises(PermissionError, match="Permission denied"):
        write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q, unique=True)
    assert not any(p.name.startswith("demo_") for p in tmp_path.iterdir())


def test_load_dataset_errors_name_the_path(tmp_path):
    missing = tmp_path / "nope"
    with pytest.raises(ValueError, match="nope: no such file"):
        load_dataset(missing)
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(ValueError, match="file.txt: not a rosbag2 bag"):
        load_dataset(tmp_path / "file.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="empty: not a rosbag2 bag"):
        load_dataset(tmp_path / "empty")
    broken = tmp_path / "broken" / "demo_0000"
    broken.mkdir(parents=True)
    (broken / "metadata.yaml").write_text("not: [a bag")
    with pytest.raises(ValueError, match="demo_0000: cannot open"):
        load_dataset(broken)
    _foreign_bag(tmp_path / "bad", [(T0 + k * MS, ["a"], [np.nan], []) for k in range(5)])
    with pytest.raises(ValueError, match=r"bad: no usable demonstrations.*non_finite=5"):
        load_dataset(tmp_path / "bad")
    with pytest.raises(ValueError, match="gap_s"):
        load_dataset(tmp_path / "bad", gap_s=-1)


def test_joint_selector_and_clock_units():
    sel = JointSelector(["b", "a"])
    assert sel.select(["a", "b", "c"], [1.0, 2.0, 3.0], [4.0, 5.0, 6.0]) == ([2.0, 1.0],
                                                                             [5.0, 4.0])
    assert sel.select(["a", "b"], [1.0, 2.0], [], [1.0]) == "length_mismatch"
    open_sel = JointSelector(None)
    assert open_sel.select(["x"], [float("nan")]) == "non_finite"
    assert open_sel.select(["y"], [1.0]) == ([1.0], None)
    open_sel.commit(["y"])
    # The cache built while the selection was open must not leak into the fixed one.
    assert open_sel.select(["x"], [1.0]) == "unknown_joints"
    clock = StreamClock(gap_ns=100)
    assert clock.step(1000) == NEW
    clock.accept(1000)
    assert [clock.step(s) for s in (1050, 1000, 950, 1101, 850)] == [SAME, SKIP, SKIP, NEW,
                                                                     NEW]
    assert StreamClock(0).step(5) == NEW
    with pytest.raises(ValueError, match="listed twice"):
        validate_joint_names(["a", "a"])
    with pytest.raises(ValueError, match="invalid joint name"):
        validate_joint_names(["a", ""])
    assert validate_joint_names([]) is None


def test_written_bag_is_durable_before_return(tmp_path, monkeypatch):
    synced: list[str] = []
    real = os.fsync

    def spy(fd):
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        return real(fd)

    monkeypatch.setattr(bags.os, "fsync", spy)
    rng = np.random.default_rng(9)
    stamps, q, _ = _demo(rng, 5)
    path = write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q)
    assert str(tmp_path) in synced  # the rename itself is made durable
    assert any(s.endswith("metadata.yaml") for s in synced)
    assert any(s.endswith(".mcap") for s in synced)
    assert (path / "metadata.yaml").is_file()


def test_unreadable_bag_in_a_dataset_is_reported_not_fatal(tmp_path):
    rng = np.random.default_rng(10)
    stamps, q, _ = _demo(rng, 10)
    good = write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q)
    truncated = write_joint_state_bag(tmp_path / "demo_0001", ["a", "b", "c"], stamps, q)
    storage = next(truncated.glob("*.mcap"))
    storage.write_bytes(storage.read_bytes()[:100])
    trajs, _, report = load_dataset(tmp_path)
    assert len(trajs) == 1 and report.demos[0].bag == str(good)
    assert len(report.errors) == 1 and "demo_0001" in report.errors[0]
    assert "1 bag(s) unreadable" in report.summary()
    with pytest.raises(ValueError, match="demo_0001: cannot open"):
        load_dataset(truncated)  # named explicitly: an error


def test_bare_storage_file_is_a_bag(tmp_path):
    rng = np.random.default_rng(11)
    stamps, q, _ = _demo(rng, 10)
    bag = write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q)
    trajs, _, _ = load_dataset(next(bag.glob("*.mcap")))
    np.testing.assert_array_equal(trajs[0].positions, q)


def test_repeated_bags_are_read_once_and_demos_get_unique_names(tmp_path):
    rng = np.random.default_rng(4)
    for root in ("a", "b"):
        stamps, q, _ = _demo(rng)
        write_joint_state_bag(tmp_path / root / "demo_0000", ["j0", "j1", "j2"], stamps, q)
    stamps, q, _ = _demo(rng, n_samples=40)
    stamps[20:] += 5 * 10**9  # a gap: two demonstrations in one bag
    write_joint_state_bag(tmp_path / "a" / "split", ["j0", "j1", "j2"], stamps, q)
    trajs, _, report = load_dataset([tmp_path / "a", tmp_path / "a" / "split", tmp_path / "b"])
    assert report.repeated_bags == [str(tmp_path / "a" / "split")]
    assert [d.name for d in report.demos] == ["a/demo_0000", "split#1", "split#2",
                                              "b/demo_0000"]
    assert len(trajs) == 4 and "named twice, read once" in report.summary()
    assert report.skipped_bags == [] and report.available_joints == ["j0", "j1", "j2"]


def test_a_bag_of_undecodable_joint_states_is_not_called_empty(tmp_path):
    # Its messages are JointStates that fail to deserialize (another definition, damage):
    # the reason said "no sensor_msgs/msg/JointState messages", sending users the wrong way.
    rng = np.random.default_rng(12)
    stamps, q, _ = _demo(rng)
    write_joint_state_bag(tmp_path / "good", ["j0", "j1", "j2"], stamps, q)
    with Writer(tmp_path / "garbled", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/joint_states", JS.__msgtype__, typestore=TS)
        for stamp in stamps[:7]:
            writer.write(conn, int(stamp), b"\x00\x01\x00\x00\xff\xff\xff")
    _, _, report = load_dataset(tmp_path)
    reason = dict(report.skipped_bags)[str(tmp_path / "garbled")]
    assert reason == "all 7 JointState message(s) skipped (undecodable=7)"
    assert report.skipped["undecodable"] == 7 and len(report.demos) == 1


def test_bags_giving_nothing_are_named_with_the_reason(tmp_path):
    rng = np.random.default_rng(5)
    stamps, q, _ = _demo(rng)
    write_joint_state_bag(tmp_path / "good", ["j0", "j1", "j2"], stamps, q)
    write_joint_state_bag(tmp_path / "other", ["knee"], stamps, q[:, :1])
    write_joint_state_bag(tmp_path / "short", ["j0", "j1", "j2"], stamps[:1], q[:1])
    cut = tmp_path / "cut"
    write_joint_state_bag(cut, ["j0", "j1", "j2"], stamps, q)
    mcap = cut / "cut.mcap"
    mcap.write_bytes(mcap.read_bytes()[:100])
    _, _, report = load_dataset(tmp_path, joints=["j0", "j1"])
    reasons = dict(report.skipped_bags)
    assert set(reasons) == {str(tmp_path / n) for n in ("other", "short", "cut")}
    assert "cannot open" in reasons[str(tmp_path / "cut")]
    assert "missing joint(s) j0, j1; the bag has: knee" in reasons[str(tmp_path / "other")]
    assert "shorter than 2 samples" in reasons[str(tmp_path / "short")]
    assert report.missing_joints == []
    with pytest.raises(ValueError, match=r"'nope' not found .*available: j0, j1, j2, knee"):
        load_dataset(tmp_path, joints=["j0", "nope"])


def _good_dataset(tmp_path, n_bags=8, joints=("j1", "j2"), seed=20):
    rng = np.random.default_rng(seed)
    for k in range(n_bags):
        stamps, q, _ = _demo(rng, 20, n=len(joints))
        write_joint_state_bag(tmp_path / f"demo_{k:04d}", list(joints), stamps, q)


def test_a_foreign_bag_sorting_first_does_not_choose_the_joints(tmp_path):
    """Joints from the first message read let bad_foreign (x1, x2) reject 8 good bags."""
    _good_dataset(tmp_path)
    rng = np.random.default_rng(21)
    stamps, q, _ = _demo(rng, 20, n=2)
    write_joint_state_bag(tmp_path / "bad_foreign", ["x1", "x2"], stamps, q)
    trajs, names, report = load_dataset(tmp_path)
    assert names == ["j1", "j2"] and len(trajs) == 8
    [(bag, reason)] = report.skipped_bags
    assert bag == str(tmp_path / "bad_foreign")
    assert reason.startswith("joints x1, x2; expected j1, j2 (all 20 JointState")
    # Explicit joints keep their behaviour: the foreign bag's own reason.
    trajs, names, report = load_dataset(tmp_path, joints=["j1", "j2"])
    assert names == ["j1", "j2"] and len(trajs) == 8
    assert "missing joint(s) j1, j2" in dict(report.skipped_bags)[str(tmp_path / "bad_foreign")]
    # The foreign joints alone are a dataset of their own.
    trajs, names, _ = load_dataset(tmp_path / "bad_foreign")
    assert names == ["x1", "x2"] and len(trajs) == 1


def test_joint_vote_tie_goes_to_the_first_bag_and_order_is_ignored(tmp_path):
    rng = np.random.default_rng(22)
    for name, joints in (("a", ["p", "q"]), ("b", ["j1", "j2"]), ("c", ["q", "p"]),
                         ("d", ["j1", "j2"]), ("e", ["j2", "j1", "j3"])):
        stamps, q, _ = _demo(rng, 10, n=len(joints))
        write_joint_state_bag(tmp_path / name, joints, stamps, q)
    # p,q: 2 votes (a, c); j1,j2: 2 votes (b, d); tie -> a's set, in a's order.
    trajs, names, report = load_dataset(tmp_path)
    assert names == ["p", "q"] and len(trajs) == 2
    reasons = dict(report.skipped_bags)
    assert reasons[str(tmp_path / "b")].startswith("joints j1, j2; expected p, q (")
    assert reasons[str(tmp_path / "e")].startswith("joints j2, j1, j3; expected p, q (")


def test_zero_byte_mcap_in_a_dataset_is_named(tmp_path):
    _good_dataset(tmp_path, n_bags=2)
    (tmp_path / "empty.mcap").write_bytes(b"")
    trajs, _, report = load_dataset(tmp_path)
    assert len(trajs) == 2
    assert report.skipped_bags == [(str(tmp_path / "empty.mcap"), "empty file")]
    with pytest.raises(ValueError, match="empty.mcap: empty file"):
        load_dataset(tmp_path / "empty.mcap")  # named explicitly: an error


def test_bags_of_one_name_in_two_datasets_get_different_names(tmp_path):
    # ds1/a/demo_0000 and ds2/a/demo_0000: the bag and its parent's names are the same.
    rng = np.random.default_rng(31)
    for ds in ("ds1", "ds2"):
        stamps, q, _ = _demo(rng, 20, n=2)
        write_joint_state_bag(tmp_path / ds / "a" / "demo_0000", ["j1", "j2"], stamps, q)
        stamps, q, _ = _demo(rng, 20, n=2)
        write_joint_state_bag(tmp_path / ds / "a" / f"{ds}_only", ["j1", "j2"], stamps, q)
    _, _, report = load_dataset([tmp_path / "ds1" / "a", tmp_path / "ds2" / "a"])
    names = sorted(d.name for d in report.demos)
    assert names == ["ds1/a/demo_0000", "ds1_only", "ds2/a/demo_0000", "ds2_only"]


def _records(data: bytes) -> list[tuple[int, int]]:
    """(opcode, offset) of the MCAP records of ``data`` after its magic."""
    out, pos = [], 8
    while pos + 9 <= len(data):
        out.append((data[pos], pos))
        pos += 9 + int.from_bytes(data[pos + 1:pos + 9], "little")
    return out


def test_an_mcap_that_a_killed_recorder_left_without_footer_is_read(tmp_path):
    # SIGKILL or power loss: no metadata.yaml, no summary, no footer, a half-written
    # record at the end. Every complete chunk is read; the file itself is not touched.
    rng = np.random.default_rng(29)
    stamps, q, _ = _demo(rng, 30, n=2)
    killed = write_joint_state_bag(tmp_path / "killed", ["j1", "j2"], stamps, q)
    (killed / "metadata.yaml").unlink()
    mcap = next(killed.glob("*.mcap"))
    data = mcap.read_bytes()
    data_end = next(pos for op, pos in _records(data) if op == 0x0F)
    cut = data[:data_end] + b"\x06\x40"
    mcap.write_bytes(cut)
    trajs, _, report = load_dataset(tmp_path)
    assert report.skipped_bags == [] and report.errors == []
    np.testing.assert_array_equal(trajs[0].positions, q)
    assert mcap.read_bytes() == cut
    # Cut inside its only chunk, nothing is complete: skipped with the reader's reason.
    _good_dataset(tmp_path, n_bags=1)
    chunk = next(pos for op, pos in _records(data) if op == 0x06)
    mcap.write_bytes(data[:chunk + 100])
    trajs, _, report = load_dataset(tmp_path)
    assert len(trajs) == 1 and report.skipped_bags[0][0] == str(mcap)
    assert "end magic" in report.skipped_bags[0][1]


def test_bag_directory_without_metadata_is_read_from_its_mcap(tmp_path):
    _good_dataset(tmp_path, n_bags=2)
    rng = np.random.default_rng(23)
    stamps, q, _ = _demo(rng, 20, n=2)
    killed = write_joint_state_bag(tmp_path / "killed", ["j1", "j2"], stamps, q)
    (killed / "metadata.yaml").unlink()
    mcap = next(killed.glob("*.mcap"))
    assert find_bags(tmp_path)[-1] == mcap
    trajs, _, report = load_dataset(tmp_path)
    assert len(trajs) == 3 and report.skipped_bags == []
    np.testing.assert_array_equal(trajs[-1].positions, q)
    assert report.demos[-1].name == f"killed/{mcap.name}"
    # An empty .mcap in such a directory is named like any other.
    (killed / "zz.mcap").write_bytes(b"")
    _, _, report = load_dataset(tmp_path)
    assert report.skipped_bags == [(str(killed / "zz.mcap"), "empty file")]
