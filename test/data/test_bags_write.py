"""Tests of policy_align_ros.data.bags.write: exact round trips, atomic and durable
writes, refused inputs. ROS-free."""

from __future__ import annotations

import errno
import os
import re
import struct

import numpy as np
import pytest
from jointstate_bags import _demo

from policy_align_ros.data.bags import write as bags
from policy_align_ros.data.bags.dataset import load_dataset
from policy_align_ros.data.bags.read import read_joint_states
from policy_align_ros.data.bags.write import write_joint_state_bag


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
    with pytest.raises(ValueError, match=re.escape(str(first))):
        write_joint_state_bag(first, ["a", "b", "c"], stamps, q)
    second = write_joint_state_bag(first, ["a", "b", "c"], stamps, q, unique=True)
    assert second.name == "demo_0001"
    with pytest.raises(ValueError, match=r"shape \(5, 2\)"):
        write_joint_state_bag(tmp_path / "x", ["a", "b"], stamps, q)


@pytest.mark.parametrize("joints, stamps, match", [
    # The joint, the argument, or the stamp and the index of its message.
    (["a", "a"], [1, 2], "'a'"),  # a bag every reader would skip entirely
    (["a", ""], [1, 2], "''"),
    ([], [1, 2], r"\bjoint_names\b"),
    (["a", "b"], [-5, 10], r" -5 ns\b.*\bmessage 0\b"),  # was OverflowError
    (["a", "b"], [1, 2**31 * 10**9], r"\b2147483648000000000 ns\b.*\bmessage 1\b"),
    (["a", "b"], 7, r"\bstamps_ns\b.*\(N,\)"),  # was IndexError
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
    with pytest.raises(PermissionError) as err:
        write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q, unique=True)
    assert err.value.errno == errno.EACCES
    assert not any(p.name.startswith("demo_") for p in tmp_path.iterdir())


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


@pytest.mark.parametrize("layout", ["reversed", "fortran", "big_endian", "float32",
                                    "strided_stamps"])
def test_arrays_of_any_layout_round_trip(tmp_path, layout):
    # The serializer views each row as contiguous native float64; views of other arrays
    # (reversed joints, a transpose, every other stamp) and other dtypes were refused from
    # inside rosbags, naming no bag.
    rng = np.random.default_rng(11)
    stamps, q, v = _demo(rng, 12)
    joints = ["a", "b", "c"]
    if layout == "reversed":
        joints, q, v = joints[::-1], q[:, ::-1], v[:, ::-1]
    elif layout == "fortran":
        q, v = np.asfortranarray(q), np.asfortranarray(v)
    elif layout == "big_endian":
        q, v = q.astype(">f8"), v.astype(">f8")
    elif layout == "float32":
        q, v = q.astype(np.float32), v.astype(np.float32)
    else:
        stamps = np.repeat(stamps, 2)[::2]
    assert layout == "float32" or not (q.flags.c_contiguous and stamps.flags.c_contiguous
                                       and q.dtype.isnative)
    path = write_joint_state_bag(tmp_path / "demo_0000", joints, stamps, q, v)
    trajs, names, _ = load_dataset(path, gap_s=0)
    assert names == joints
    np.testing.assert_array_equal(trajs[0].positions, np.asarray(q, dtype=np.float64))
    np.testing.assert_array_equal(trajs[0].velocities, np.asarray(v, dtype=np.float64))
    assert [m[1] for m in read_joint_states(path)] == [int(s) for s in stamps]


def test_errors_from_inside_the_writer_name_the_bag_and_keep_their_type(tmp_path, monkeypatch):
    rng = np.random.default_rng(12)
    stamps, q, _ = _demo(rng, 5)
    bag = tmp_path / "demo_0000"
    # Values that are no numbers.
    with pytest.raises(ValueError) as err:
        write_joint_state_bag(bag, ["a", "b", "c"], stamps, np.full((5, 3), "x"))
    assert str(bag) in str(err.value)
    # A serializer error of its own type and an OSError keep their type, errno and
    # identity; one whose message is not its arguments is a ValueError caused by it.
    real = bags._joint_state_cdr
    for error, kind in ((struct.error("bad"), struct.error),
                        (OSError(errno.ENOSPC, "No space left on device"), OSError),
                        (OSError("disk on fire"), OSError),
                        (UnicodeDecodeError("utf-8", b"\xff", 0, 1, "bad"), ValueError)):
        def failing(*args, error=error):
            raise error

        monkeypatch.setattr(bags, "_joint_state_cdr", failing)
        with pytest.raises(kind) as err:
            write_joint_state_bag(bag, ["a", "b", "c"], stamps, q)
        assert str(bag) in str(err.value)
        assert err.value is error if kind is not ValueError else err.value.__cause__ is error
        assert getattr(err.value, "errno", None) == getattr(error, "errno", None)
    monkeypatch.setattr(bags, "_joint_state_cdr", real)
    assert list(tmp_path.iterdir()) == []  # nothing left behind
