"""Finding rosbag2 bags and decoding their ``sensor_msgs/msg/JointState`` messages.

Reading accepts both MCAP and sqlite3 bags (Humble's default), as bag directories or bare
``.mcap``/``.db3`` files; an ``.mcap`` a killed recorder left without its footer is read
up to its last complete record. Stamps are integer nanoseconds since the epoch.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader, ReaderError

from policy_align_ros.data.bags.format import JOINT_STATE, TYPESTORE, is_temporary

__all__ = ["BagOpenError", "bag_topics", "find_bags", "finished_mcap_copy",
           "read_joint_states"]


class BagOpenError(ValueError):
    """A path that should be a bag cannot be opened as one (the message names it)."""


def find_bags(path: str | os.PathLike[str]) -> list[Path]:
    """Bags named by a path: the bag itself, or the bags inside a dataset directory.

    Parameters
    ----------
    path : path-like
        A rosbag2 bag directory (with ``metadata.yaml``), a bare ``.mcap`` / ``.db3``
        file, or a dataset directory whose sub-directories are bags.

    Returns
    -------
    list of Path
        Sorted by name; hidden (temporary) entries are ignored. In a dataset directory,
        bare ``.mcap``/``.db3`` files are bags too, and so are the storage files of a
        sub-directory without ``metadata.yaml`` (what a killed ``ros2 bag record``
        leaves; :func:`read_joint_states` reads an ``.mcap`` left without its footer up to
        its last complete record); empty or damaged ones are reported by
        :func:`~policy_align_ros.data.bags.dataset.load_dataset`.

    Raises
    ------
    ValueError
        If the path does not exist, or is neither a bag nor a directory holding bags.
    """
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: no such file or directory")
    if p.is_file():
        if p.suffix in (".mcap", ".db3"):
            return [p]
        raise ValueError(f"{p}: not a rosbag2 bag (expected a bag directory, .mcap or .db3)")
    if (p / "metadata.yaml").is_file():
        return [p]
    bags: list[Path] = []
    for entry in sorted(p.iterdir()):
        if is_temporary(entry):
            continue
        if entry.is_file() and entry.suffix in (".mcap", ".db3"):
            # Read (or, if empty or damaged, reported by load_dataset), never silently
            # dropped: a stray storage file is most likely a demonstration.
            bags.append(entry)
        elif entry.is_dir() and (entry / "metadata.yaml").is_file():
            bags.append(entry)
        elif entry.is_dir():
            # A killed ``ros2 bag record`` leaves its .mcap but no metadata.yaml; rosbags
            # reads a bare storage file on its own, so each one is a bag.
            bags.extend(
                f for f in sorted(entry.iterdir())
                if f.is_file() and f.suffix in (".mcap", ".db3") and not is_temporary(f)
            )
    if not bags:
        raise ValueError(f"{p}: not a rosbag2 bag, and contains no rosbag2 bags")
    return bags


def read_joint_states(
    bag: str | os.PathLike[str], counts: Counter[str] | None = None
) -> Iterator[tuple[str, int, list[str], np.ndarray, np.ndarray, np.ndarray]]:
    """Decoded JointState messages of every JointState topic of one bag, in bag order.

    Parameters
    ----------
    bag : path-like
        Bag directory or bare storage file. A bare ``.mcap`` without its footer (a
        recorder killed before it closed the file) is read up to its last complete
        record (:func:`finished_mcap_copy`).
    counts : Counter, optional
        Incremented under ``undecodable`` for messages that fail to deserialize.

    Yields
    ------
    (topic, stamp_ns, names, positions, velocities, efforts)
        ``stamp_ns`` is the header stamp, or the bag time when the header stamp is zero.

    Raises
    ------
    BagOpenError
        A ``ValueError`` naming the path, if the bag cannot be opened.
    """
    path = Path(bag)
    with contextlib.ExitStack() as stack:
        try:
            if path.is_file() and path.stat().st_size == 0:
                raise BagOpenError(f"{path}: empty file")
            reader = _open_reader(path, stack)
        except (ReaderError, FileNotFoundError, OSError, KeyError) as err:
            raise BagOpenError(f"{path}: cannot open as a rosbag2 bag: {err}") from None
        yield from _joint_states(reader, counts)


def bag_topics(bag: str | os.PathLike[str]) -> list[tuple[str, str, int]]:
    """The topics of one bag: ``(topic, message type, message count)`` in bag order.

    Empty when the bag cannot be opened (its reader reports why).
    """
    path = Path(bag)
    topics: list[tuple[str, str, int]] = []
    with contextlib.ExitStack() as stack:
        try:
            reader = _open_reader(path, stack)
        except Exception:  # noqa: BLE001 - only a hint for an error message
            return []
        try:
            for conn in reader.connections:
                topics.append((conn.topic, conn.msgtype, int(conn.msgcount)))
        finally:
            reader.close()
    return topics


def _open_reader(path: Path, stack: contextlib.ExitStack) -> Reader:
    """An open reader of ``path``; a bare MCAP file that a killed recorder left without
    its footer is read up to its last complete record, from a copy (see
    :func:`finished_mcap_copy`)."""
    reader = Reader(path)
    try:
        reader.open()
    except ReaderError as err:
        if not (path.suffix == ".mcap" and "end magic" in str(err)):
            raise
        copy = finished_mcap_copy(path, Path(stack.enter_context(
            tempfile.TemporaryDirectory(prefix="policy_align_mcap_"))))
        if copy is None:
            raise
        reader = Reader(copy)
        reader.open()
    return reader


def finished_mcap_copy(path: Path, directory: Path) -> Path | None:
    """A copy in ``directory`` of the MCAP file ``path`` cut after its last complete
    record and given the footer a finished file has (no summary), or None when it holds
    no complete record after its header.

    ``ros2 bag record`` writes the summary and the footer when it closes: killed (power
    loss, SIGKILL) it leaves a file that readers refuse ("end magic invalid"), although
    every chunk it wrote before is complete. The records are walked by their length
    prefixes (opcode u8, length u64); the chunk it was filling when it died is lost.
    """
    magic = b"\x89MCAP0\r\n"
    size = path.stat().st_size
    with path.open("rb") as f:
        if f.read(8) != magic:
            return None
        end, complete = 8, 0
        while True:
            head = f.read(9)
            if len(head) < 9:
                break
            op, length = head[0], int.from_bytes(head[1:], "little")
            if op in (0x02, 0x0F) or end + 9 + length > size:  # footer, data end, cut
                break
            f.seek(length, os.SEEK_CUR)
            end += 9 + length
            complete += op != 0x01  # not the header
        if not complete:
            return None
        copy = directory / path.name
        f.seek(0)
        with copy.open("wb") as out:
            left = end
            while left:
                block = f.read(min(left, 1 << 20))
                out.write(block)
                left -= len(block)
            # Data End (no CRC), then a footer without summary: readers scan the records.
            out.write(b"\x0f" + (4).to_bytes(8, "little") + bytes(4))
            out.write(b"\x02" + (20).to_bytes(8, "little") + bytes(20) + magic)
    return copy


def _joint_states(reader: Reader, counts: Counter[str] | None
                  ) -> Iterator[tuple[str, int, list[str], np.ndarray, np.ndarray, np.ndarray]]:
    """The decoded JointState messages of an open ``reader`` (see read_joint_states)."""
    try:
        conns = [c for c in reader.connections if c.msgtype == JOINT_STATE]
        if not conns:
            return
        for conn, bag_ns, raw in reader.messages(connections=conns):
            try:
                msg = TYPESTORE.deserialize_cdr(raw, JOINT_STATE)
            except Exception:  # any decoding failure is one bad message
                if counts is not None:
                    counts["undecodable"] += 1
                continue
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            yield (
                conn.topic,
                stamp or bag_ns,
                msg.name,
                msg.position,
                msg.velocity,
                msg.effort,
            )
    finally:
        reader.close()
