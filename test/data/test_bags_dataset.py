"""Tests of policy_align_ros.data.bags.dataset: splitting, malformed-message accounting,
foreign bags, the joint vote and the report of skipped bags. ROS-free."""

from __future__ import annotations

import re

import numpy as np
import pytest
from jointstate_bags import JS, MS, T0, TS, _demo, _foreign_bag, _good_dataset
from rosbags.rosbag2 import StoragePlugin, Writer

from policy_align_ros.data.bags.dataset import load_dataset
from policy_align_ros.data.bags.read import BagOpenError
from policy_align_ros.data.bags.write import write_joint_state_bag


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


def test_a_restarted_clock_ends_a_demonstration_even_without_gap_splits(tmp_path):
    # A bag recorded across a simulator reset: the stamps go 3 s back and run on. Spliced,
    # the second run would be glued onto the first where its stamps pass the reset point.
    rng = np.random.default_rng(4)
    received, q, _ = _demo(rng, 90)
    stamps = received.copy()
    stamps[45:] -= 3 * 10**9  # the second half: 3 s back; received in order all the same
    _foreign_bag(tmp_path / "demo_0000", [(int(s), ["a", "b", "c"], p, [], int(r))
                                          for s, p, r in zip(stamps, q, received,
                                                             strict=True)])
    for gap in (0.0, 10.0):
        trajs, _, _ = load_dataset(tmp_path, gap_s=gap)
        # The first stamp back is skipped (it could have been one stray message).
        assert [len(t) for t in trajs] == [45, 44]
        np.testing.assert_array_equal(trajs[1].positions, q[46:])


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


def test_clock_reset_starts_new_demo_instead_of_skipping_the_rest(tmp_path):
    j = ["a"]
    first = [(T0 + k * 10 * MS, j, [float(k)], []) for k in range(10)]
    restarted = [(T0 - 100 * 10**9 + k * 10 * MS, j, [float(k)], []) for k in range(10)]
    _foreign_bag(tmp_path / "bag", first + restarted)
    trajs, _, report = load_dataset(tmp_path / "bag", gap_s=0.5)
    assert [len(t) for t in trajs] == [10, 10]
    assert report.skipped["time_not_increasing"] == 0


def test_load_dataset_errors_name_the_path(tmp_path):
    missing = tmp_path / "nope"
    with pytest.raises(ValueError, match="nope"):
        load_dataset(missing)
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(ValueError, match=r"file\.txt"):
        load_dataset(tmp_path / "file.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="empty"):
        load_dataset(tmp_path / "empty")
    broken = tmp_path / "broken" / "demo_0000"
    broken.mkdir(parents=True)
    (broken / "metadata.yaml").write_text("not: [a bag")
    with pytest.raises(BagOpenError, match=re.escape(str(broken))):
        load_dataset(broken)
    _foreign_bag(tmp_path / "bad", [(T0 + k * MS, ["a"], [np.nan], []) for k in range(5)])
    with pytest.raises(ValueError, match=r"bad\b.*\bnon_finite=5\b"):
        load_dataset(tmp_path / "bad")
    with pytest.raises(ValueError, match="gap_s"):
        load_dataset(tmp_path / "bad", gap_s=-1)


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
    assert [bag for bag, _ in report.skipped_bags] == [str(truncated)]
    with pytest.raises(BagOpenError, match=re.escape(str(truncated))):
        load_dataset(truncated)  # named explicitly: an error


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
    assert len(trajs) == 4
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
    assert "undecodable=7" in reason
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
    assert [e.split(": ")[0] for e in report.errors] == [str(cut)]  # could not be opened
    assert all(repr(j) in reasons[str(tmp_path / "other")] for j in ("j0", "j1", "knee"))
    assert report.demos_too_short == 1  # the one demonstration of "short"
    assert report.missing_joints == []
    with pytest.raises(ValueError, match=r"'nope'.*\bj0, j1, j2, knee\b"):
        load_dataset(tmp_path, joints=["j0", "nope"])


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
    assert re.search(r"\bx1, x2\b.*\bj1, j2\b", reason)  # its joints, those chosen
    # Explicit joints keep their behaviour: the foreign bag's own reason.
    trajs, names, report = load_dataset(tmp_path, joints=["j1", "j2"])
    assert names == ["j1", "j2"] and len(trajs) == 8
    reason = dict(report.skipped_bags)[str(tmp_path / "bad_foreign")]
    assert all(repr(j) in reason for j in ("j1", "j2", "x1", "x2"))
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
    # Each names its own joints, then the set chosen, in a's order.
    assert re.search(r"\bj1, j2\b.*\bp, q\b", reasons[str(tmp_path / "b")])
    assert re.search(r"\bj2, j1, j3\b.*\bp, q\b", reasons[str(tmp_path / "e")])
    # Bags of the same other joints get the same reason: a summary says it once for both.
    assert reasons[str(tmp_path / "b")] == reasons[str(tmp_path / "d")]
    from policy_align_ros.data.learn import _grouped

    grouped = _grouped([{"bag": bag, "reason": why} for bag, why in report.skipped_bags])
    assert sorted(map(sorted, grouped.values())) == [
        [str(tmp_path / "b"), str(tmp_path / "d")], [str(tmp_path / "e")]]


def test_zero_byte_mcap_in_a_dataset_is_named(tmp_path):
    _good_dataset(tmp_path, n_bags=2)
    (tmp_path / "empty.mcap").write_bytes(b"")
    trajs, _, report = load_dataset(tmp_path)
    assert len(trajs) == 2
    assert [bag for bag, _ in report.skipped_bags] == [str(tmp_path / "empty.mcap")]
    with pytest.raises(BagOpenError, match=r"empty\.mcap"):
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


def test_a_bag_without_joint_states_is_named_with_its_topics(tmp_path):
    bag = tmp_path / "tf_only"
    string, tf = TS.types["std_msgs/msg/String"], "tf2_msgs/msg/TFMessage"
    with Writer(bag, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        chatter = writer.add_connection("/chatter", string.__msgtype__, typestore=TS)
        writer.add_connection("/tf", tf, typestore=TS)
        for k in range(3):
            writer.write(chatter, T0 + k * MS, TS.serialize_cdr(string(data="x"),
                                                               string.__msgtype__))
    with pytest.raises(ValueError) as err:
        load_dataset(bag)
    # The error itself (what the CLI and the learner print) lists the bag's topics.
    assert "/chatter" in str(err.value) and "/tf" in str(err.value)
    assert "std_msgs/msg/String" in str(err.value)
    # In a dataset the other bags still count and this one is named with its topics.
    good = tmp_path / "set"
    _good_dataset(good, n_bags=2)
    (good / "tf_only").symlink_to(bag, target_is_directory=True)
    _, _, report = load_dataset(good)
    reasons = dict(report.skipped_bags)
    assert "/chatter" in reasons[str(good / "tf_only")]
