"""Tests of policy_align_ros.data.bags.read: finding bags, header and bag times, bare
storage files and MCAP files a killed recorder left unfinished. ROS-free."""

from __future__ import annotations

import numpy as np
from jointstate_bags import MS, T0, _demo, _foreign_bag, _good_dataset

from policy_align_ros.data.bags.dataset import load_dataset
from policy_align_ros.data.bags.read import find_bags
from policy_align_ros.data.bags.write import write_joint_state_bag


def test_zero_header_stamp_falls_back_to_bag_time(tmp_path):
    j, ok = ["a"], [1.0]
    bag_times = [T0 + k * 10 * MS for k in range(5)]
    _foreign_bag(tmp_path / "bag", [(0, j, ok, [], bt) for bt in bag_times])
    trajs, _, report = load_dataset(tmp_path / "bag")
    assert report.demos[0].start_ns == bag_times[0]
    np.testing.assert_allclose(trajs[0].times, [0, 0.01, 0.02, 0.03, 0.04])


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


def test_bare_storage_file_is_a_bag(tmp_path):
    rng = np.random.default_rng(11)
    stamps, q, _ = _demo(rng, 10)
    bag = write_joint_state_bag(tmp_path / "demo_0000", ["a", "b", "c"], stamps, q)
    trajs, _, _ = load_dataset(next(bag.glob("*.mcap")))
    np.testing.assert_array_equal(trajs[0].positions, q)


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
    assert report.skipped_bags[0][1] in report.errors[0]  # the reader's own error


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
