"""rosbag2 demonstrations of ``sensor_msgs/msg/JointState`` (ROS-free, ``rosbags``).

Units and conventions: stamps are integer nanoseconds since the epoch (header stamps,
falling back to the bag's receive time when a header stamp is zero); trajectory times
are seconds relative to the first sample of the demonstration; positions and
velocities are in the joints' units (rad, rad/s for revolute joints).

Storage: bags are written with the MCAP storage plugin and metadata version 9, the
defaults of ``ros2 bag record`` since Iron (so also Jazzy), which Foxglove opens directly
and whose single append-only file has its index at the end; reading accepts both MCAP
and sqlite3 bags (Humble's default), as bag directories or bare ``.mcap``/``.db3`` files.

Atomicity: a bag is written into a hidden temporary directory next to its final name,
every file and the directory are fsync'ed, then it is renamed into place and the parent
directory is fsync'ed. A crash at any point leaves either the complete bag or a hidden
temporary directory, which readers ignore (:func:`is_temporary`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import tempfile
import uuid
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from policy_align_ros.data.messages import (
    NEW,
    SKIP,
    SKIP_REASONS,
    JointSelector,
    StreamClock,
    validate_joint_names,
)
from policy_align_ros.learning import Trajectory

__all__ = [
    "JOINT_STATE",
    "BagOpenError",
    "DatasetReport",
    "DemoInfo",
    "find_bags",
    "is_temporary",
    "load_dataset",
    "next_demo_path",
    "read_joint_states",
    "write_joint_state_bag",
]

JOINT_STATE = "sensor_msgs/msg/JointState"
DEFAULT_TOPIC = "/joint_states"
_TMP_PREFIX = ".tmp-"
_DEMO_RE = re.compile(r"^demo_(\d+)$")
# JointState is identical in every ROS 2 distribution's store; Jazzy is the target.
_TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
_JointState = _TYPESTORE.types[JOINT_STATE]
_Header = _TYPESTORE.types["std_msgs/msg/Header"]
_Time = _TYPESTORE.types["builtin_interfaces/msg/Time"]
_EMPTY = np.empty(0, dtype=np.float64)
# First stamp a header cannot hold: builtin_interfaces/Time's ``sec`` is an int32.
_STAMP_LIMIT_NS = 2**31 * 1_000_000_000


class BagOpenError(ValueError):
    """A path that should be a bag cannot be opened as one (the message names it)."""


def is_temporary(path: Path) -> bool:
    """True for hidden entries (such as unfinished bags), which readers ignore."""
    return path.name.startswith(".")


def _fsync_path(path: Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def next_demo_path(dataset_dir: str | os.PathLike[str]) -> Path:
    """Path of the next ``demo_NNNN`` bag in a dataset directory (not created)."""
    root = Path(dataset_dir)
    used = [
        int(m.group(1))
        for entry in (root.iterdir() if root.is_dir() else ())
        if (m := _DEMO_RE.match(entry.name))
    ]
    return root / f"demo_{max(used, default=-1) + 1:04d}"


def _joint_state_cdr(
    stamp_ns: int, names: list[str], pos: np.ndarray, vel: np.ndarray
) -> memoryview:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg = _JointState(
        header=_Header(stamp=_Time(sec=sec, nanosec=nanosec), frame_id=""),
        name=names,
        position=pos,
        velocity=vel,
        effort=_EMPTY,
    )
    return _TYPESTORE.serialize_cdr(msg, JOINT_STATE)


def write_joint_state_bag(
    path: str | os.PathLike[str],
    joint_names: Sequence[str],
    stamps_ns: Sequence[int] | np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray | None = None,
    *,
    has_velocity: Sequence[bool] | np.ndarray | None = None,
    topic: str = DEFAULT_TOPIC,
    unique: bool = False,
) -> Path:
    """Write one demonstration as a rosbag2 bag, atomically and durably.

    Parameters
    ----------
    path : path-like
        Final bag directory; its parent is created if needed. It must not exist unless
        ``unique`` is set.
    joint_names : sequence of str, length n
    stamps_ns : sequence of int, shape (N,)
        Header stamps (and bag receive times) in nanoseconds since the epoch.
    positions : ndarray, shape (N, n)
        Joint positions (rad or m).
    velocities : ndarray, shape (N, n), optional
        Joint velocities (rad/s or m/s); ``None`` writes empty velocity arrays.
    has_velocity : sequence of bool, shape (N,), optional
        Which messages carry their velocity row (default: all, when ``velocities`` given).
    topic : str
        Topic name stored in the bag.
    unique : bool
        If the final name is taken, use the next free ``demo_NNNN`` name in the same
        directory instead of failing (several recorders sharing a directory).

    Returns
    -------
    Path
        The bag directory, complete and fsync'ed when this returns.

    Raises
    ------
    ValueError
        On inconsistent shapes, repeated or empty joint names, a stamp outside
        ``[0, 2^31)`` s, or if ``path`` exists and ``unique`` is not set.
    """
    final = Path(path)
    names = [str(j) for j in joint_names]
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    q = np.asarray(positions, dtype=np.float64)
    if stamps.ndim != 1:
        raise ValueError(f"{final}: stamps_ns must have shape (N,), got {stamps.shape}")
    n_msgs = stamps.shape[0]
    if q.shape != (n_msgs, len(names)):
        raise ValueError(
            f"{final}: positions must have shape ({n_msgs}, {len(names)}) to match stamps "
            f"and joint names, got {q.shape}"
        )
    v = None if velocities is None else np.asarray(velocities, dtype=np.float64)
    if v is not None and v.shape != q.shape:
        raise ValueError(f"{final}: velocities must have shape {q.shape}, got {v.shape}")
    flags = (
        np.full(n_msgs, v is not None)
        if has_velocity is None
        else np.asarray(has_velocity, dtype=bool)
    )
    if flags.shape != (n_msgs,) or (v is None and flags.any()):
        raise ValueError(f"{final}: has_velocity must be (N,) and needs velocities")
    # Checked here, not left to the writer: a repeated or empty name gives a bag whose every
    # message a reader skips, and a stamp out of range fails deep in the serializer with an
    # OverflowError or struct.error that names neither the bag nor the stamp.
    if not names:
        raise ValueError(f"{final}: joint_names must not be empty")
    try:
        validate_joint_names(names)
    except ValueError as err:
        raise ValueError(f"{final}: {err}") from None
    out_of_range = np.flatnonzero((stamps < 0) | (stamps >= _STAMP_LIMIT_NS))
    if out_of_range.size:
        k = int(out_of_range[0])
        raise ValueError(
            f"{final}: stamp {int(stamps[k])} ns of message {k} is out of range (a bag "
            f"stores times >= 0 and a header stamp at most 2^31 - 1 s)")
    if final.exists() and not unique:
        raise ValueError(f"{final}: exists already, not overwriting")
    final.parent.mkdir(parents=True, exist_ok=True)
    staging = final.parent / f"{_TMP_PREFIX}{final.name}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    # The writer names the storage file after the bag directory: written under its final
    # name inside a hidden staging directory, the finished bag holds demo_NNNN.mcap.
    tmp = staging / final.name
    try:
        staging.mkdir()
        with Writer(tmp, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            conn = writer.add_connection(topic, JOINT_STATE, typestore=_TYPESTORE)
            for k in range(n_msgs):
                vel = v[k] if flags[k] else _EMPTY
                writer.write(conn, int(stamps[k]), _joint_state_cdr(stamps[k], names, q[k], vel))
        for entry in tmp.iterdir():
            _fsync_path(entry)
        _fsync_path(tmp, directory=True)
        final = _rename_into_place(tmp, final, unique)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    # The bag is complete under its final name from here on. Failing to tidy up (the
    # dataset directory was moved away meanwhile) must not report it unwritten, or a
    # recorder would write the same demonstration a second time.
    with contextlib.suppress(OSError):
        _fsync_path(final.parent, directory=True)
    with contextlib.suppress(OSError):
        staging.rmdir()
    return final


def _rename_into_place(tmp: Path, final: Path, unique: bool) -> Path:
    for _ in range(1000):
        # os.rename would silently replace an empty directory: check first, and the
        # rename itself refuses a non-empty one if another writer won the race.
        if not final.exists():
            try:
                os.rename(tmp, final)
                return final
            except OSError as err:
                # Only another writer taking the name (a race) is worth the next name; any
                # other failure (permissions, a full disk) is the error to report.
                if not unique or err.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                    raise
        elif not unique:
            raise ValueError(f"{final}: exists already, not overwriting")
        final = next_demo_path(final.parent)
    raise ValueError(f"{final.parent}: could not find a free bag name")


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
        :func:`load_dataset`.

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
                msg = _TYPESTORE.deserialize_cdr(raw, JOINT_STATE)
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


@dataclass
class DemoInfo:
    """Where one demonstration came from.

    Attributes
    ----------
    bag : str
        Bag path.
    topic : str
        JointState topic.
    start_ns : int
        Stamp of the first sample (ns since the epoch); trajectory times are relative to it.
    n_samples : int
        Number of samples.
    name : str
        Unique name of the demonstration: the bag's name (``parent/bag`` when bags of
        different directories share a name, and for bare ``.mcap``/``.db3`` files),
        with ``#1``, ``#2``, ... appended when one bag holds several demonstrations
        (time gaps or several topics).
    """

    bag: str
    topic: str
    start_ns: int
    n_samples: int
    name: str = ""


@dataclass
class DatasetReport:
    """What :func:`load_dataset` read, used and skipped.

    Attributes
    ----------
    bags : list of str
        Bags read, in order.
    topics : list of str
        JointState topics found.
    messages_read, messages_used : int
        JointState messages decoded and accepted.
    skipped : dict of str to int
        Skipped messages by reason (:data:`SKIP_REASONS` plus ``undecodable``).
    demos_found, demos_too_short : int
        Segments found, and how many had fewer than ``min_samples`` samples.
    demos : list of DemoInfo
        The demonstrations returned, in order.
    errors : list of str
        Bags of a dataset directory that could not be opened, and bags whose reading
        stopped early (for example a truncated file; what was read before is kept).
    skipped_bags : list of (str, str)
        Every bag that gave no demonstration, with the reason (unreadable, no JointState
        topic, joints missing, every message malformed, too short).
    cut_short_bags : list of (str, str)
        Bags whose reading stopped early but that gave demonstrations (what was read
        before the damage is used), with the reason.
    repeated_bags : list of str
        Bags named more than once by the inputs (each is read once).
    available_joints : list of str
        Joint names seen in the JointState messages, in order of first appearance.
    missing_joints : list of str
        Selected joints that no JointState message carries.
    """

    bags: list[str] = field(default_factory=list)
    topics: list[str] = field(default_factory=list)
    messages_read: int = 0
    messages_used: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    demos_found: int = 0
    demos_too_short: int = 0
    demos: list[DemoInfo] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    skipped_bags: list[tuple[str, str]] = field(default_factory=list)
    cut_short_bags: list[tuple[str, str]] = field(default_factory=list)
    repeated_bags: list[str] = field(default_factory=list)
    available_joints: list[str] = field(default_factory=list)
    missing_joints: list[str] = field(default_factory=list)

    @property
    def messages_skipped(self) -> int:
        """Total number of skipped messages."""
        return sum(self.skipped.values())

    def summary(self) -> str:
        """One-line human-readable account."""
        skipped = ", ".join(f"{k}={v}" for k, v in self.skipped.items() if v) or "none"
        text = (
            f"{len(self.bags)} bag(s), {self.messages_read} JointState messages, "
            f"{self.messages_used} used, skipped: {skipped}; "
            f"{self.demos_found - self.demos_too_short} demonstration(s) "
            f"({self.demos_too_short} too short)"
        )
        if self.errors:
            text += f"; {len(self.errors)} bag(s) unreadable or cut short"
        if self.repeated_bags:
            text += f"; {len(self.repeated_bags)} bag(s) named twice, read once"
        return text

    def joint_problem(self) -> str:
        """Which selected joints are missing and which exist (empty when none is missing)."""
        if not self.missing_joints:
            return ""
        shown = ", ".join(self.available_joints[:40])
        more = len(self.available_joints) - 40
        return (f"joint(s) {', '.join(map(repr, self.missing_joints))} not found in any "
                f"JointState message; available: {shown or 'none'}"
                + (f" and {more} more" if more > 0 else ""))


class _Segment:
    """Accumulates one demonstration of one topic."""

    def __init__(self, topic: str, start_ns: int) -> None:
        self.topic = topic
        self.stamps: list[int] = []
        self.positions: list[list[float]] = []
        self.velocities: list[list[float]] = []
        self.all_velocities = True
        self.start_ns = start_ns


def load_dataset(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    joints: Sequence[str] | None = None,
    gap_s: float = 0.5,
    *,
    min_samples: int = 2,
) -> tuple[list[Trajectory], list[str], DatasetReport]:
    """Read demonstrations from rosbag2 bags and dataset directories.

    Every JointState topic of every bag is a stream: joints are matched by name, the
    stream is split into demonstrations at gaps of more than ``gap_s`` seconds (and never
    across bags or topics), and malformed messages are skipped and counted (see
    :mod:`policy_align_ros.data.messages`).

    Parameters
    ----------
    paths : path-like or iterable of path-like
        Bag directories, ``.mcap``/``.db3`` files, or dataset directories of bags.
    joints : sequence of str, optional
        Joint order of the state. Default: the joint set shared by most bags, each bag
        voting with the names of its first valid message (as a set; the order is that
        of the first bag voting for it); a tie goes to the set of the bag first in
        order. Bags whose joints do not cover it are skipped and named.
    gap_s : float
        Split threshold in seconds; ``0`` never splits.
    min_samples : int
        Demonstrations with fewer samples are dropped and counted as too short.

    Returns
    -------
    trajectories : list of Trajectory
        Positions (N_k, n), times (N_k,) in seconds from the demo's start, and velocities
        (N_k, n) when every message of the demonstration had them.
    joint_names : list of str, length n
    report : DatasetReport

    Raises
    ------
    ValueError
        On a missing path, a path that is not a bag or dataset, bad arguments, or when no
        demonstration is usable; the message names the path(s).
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    paths = list(paths)
    if not paths:
        raise ValueError("paths: no bag or dataset given")
    if not (np.isfinite(gap_s) and gap_s >= 0):
        raise ValueError(f"gap_s: must be a finite number >= 0, got {gap_s}")
    if int(min_samples) < 2:
        raise ValueError(f"min_samples: must be >= 2, got {min_samples}")
    # Bags named explicitly must open; an unreadable bag inside a dataset is reported.
    # A bag named twice (``learn demos demos``) is read once: its copy would only add an
    # identical demonstration, which collapses the kernel width of the alignment.
    sources: list[tuple[Path, bool]] = []
    seen: dict[Path, int] = {}
    repeated: list[str] = []
    for p in paths:
        for bag in find_bags(p):
            key = bag.resolve()
            explicit = bag == Path(p)
            if key in seen:
                repeated.append(str(bag))
                k = seen[key]
                sources[k] = (sources[k][0], sources[k][1] or explicit)
                continue
            seen[key] = len(sources)
            sources.append((bag, explicit))
    bags = [bag for bag, _ in sources]
    selector = JointSelector(joints)
    first_names: dict[Path, list[str]] = {}
    if joints is None:
        # Joints from the first message read would let one foreign bag that sorts first
        # reject every other bag: vote instead.
        first_names = {bag: names for bag in bags if (names := _first_names(bag))}
        chosen = _majority_joints(list(first_names.values()))
        if chosen:
            selector.set_joints(chosen)
    counts: Counter[str] = Counter({reason: 0 for reason in SKIP_REASONS})
    report = DatasetReport(bags=[str(b) for b in bags], repeated_bags=repeated)
    available: dict[str, None] = {}  # ordered set of joint names seen
    trajectories: list[Trajectory] = []
    gap_ns = round(gap_s * 1e9)

    def close(segment: _Segment | None, bag: Path) -> None:
        if segment is None or not segment.stamps:
            return
        report.demos_found += 1
        if len(segment.stamps) < min_samples:
            report.demos_too_short += 1
            return
        stamps = np.asarray(segment.stamps, dtype=np.int64)
        k = len(trajectories)
        trajectories.append(
            Trajectory(
                np.asarray(segment.positions, dtype=np.float64),
                (stamps - stamps[0]) * 1e-9,
                np.asarray(segment.velocities) if segment.all_velocities else None,
                name=f"{k} ({bag.name}{segment.topic} @ {stamps[0]} ns)",
            )
        )
        report.demos.append(DemoInfo(str(bag), segment.topic, int(stamps[0]), len(stamps)))

    for bag, explicit in sources:
        clocks: dict[str, StreamClock] = {}
        segments: dict[str, _Segment | None] = {}
        demos_before = len(trajectories)
        found_before, short_before = report.demos_found, report.demos_too_short
        bag_counts: Counter[str] = Counter()
        bag_names: dict[str, None] = {}  # ordered set of the bag's joint names
        name_lists: set[tuple[str, ...]] = set()  # real streams repeat one or two lists
        bag_read = 0
        failure = ""
        try:
            # Undecodable messages counted per bag too, or a bag of nothing else would be
            # reported as holding no JointState message at all.
            for topic, stamp, names, pos, vel, eff in read_joint_states(bag, bag_counts):
                report.messages_read += 1
                bag_read += 1
                key = tuple(names)
                if key not in name_lists and len(name_lists) < 64:
                    name_lists.add(key)
                    for name in names:
                        bag_names.setdefault(str(name), None)
                clock = clocks.get(topic)
                if clock is None:
                    clock = clocks[topic] = StreamClock(gap_ns)
                    segments[topic] = None
                    if topic not in report.topics:
                        report.topics.append(topic)
                picked = selector.select(names, pos, vel, eff)
                if isinstance(picked, str):
                    counts[picked] += 1
                    bag_counts[picked] += 1
                    continue
                outcome = clock.step(stamp)
                if outcome == SKIP:
                    counts["time_not_increasing"] += 1
                    bag_counts["time_not_increasing"] += 1
                    continue
                selector.commit(names)
                clock.accept(stamp)
                segment = segments[topic]
                if outcome == NEW:
                    close(segment, bag)
                    segment = segments[topic] = _Segment(topic, stamp)
                assert segment is not None
                segment.stamps.append(stamp)
                segment.positions.append(picked[0])
                if picked[1] is None:
                    segment.all_velocities = False
                else:
                    segment.velocities.append(picked[1])
                report.messages_used += 1
        except BagOpenError as err:
            if explicit:
                raise
            report.errors.append(str(err))
            failure = str(err).removeprefix(f"{bag}: ")
        except Exception as err:  # a damaged bag keeps what was read
            report.errors.append(f"{bag}: {err}")
            failure = f"reading stopped after {bag_read} message(s): {err}"
        counts["undecodable"] += bag_counts["undecodable"]
        for segment in segments.values():
            close(segment, bag)
        for name in bag_names:
            available.setdefault(name, None)
        if failure and len(trajectories) > demos_before:
            report.cut_short_bags.append((str(bag), failure))
        if len(trajectories) == demos_before:
            reason = failure or _no_demo_reason(
                bag_read, bag_counts, report.demos_found - found_before,
                report.demos_too_short - short_before, min_samples, selector.joints,
                list(bag_names))
            own = first_names.get(bag)
            if (not failure and own and selector.joints
                    and not set(selector.joints) <= set(own)):
                # Joints chosen by vote: say first which set this bag has instead.
                reason = (f"joints {', '.join(own)}; expected {', '.join(selector.joints)}"
                          f" ({reason})")
            report.skipped_bags.append((str(bag), reason))
    report.skipped = {k: v for k, v in counts.items() if v or k in SKIP_REASONS}
    report.available_joints = list(available)
    if joints is not None:
        report.missing_joints = [j for j in joints if j not in available]
    _name_demos(report.demos)
    if not trajectories:
        where = ", ".join(str(p) for p in paths)
        problem = report.joint_problem()
        raise ValueError(f"{where}: no usable demonstrations"
                         + (f": {problem}" if problem else "") + f" ({report.summary()})")
    assert selector.joints is not None
    return trajectories, list(selector.joints), report


def _first_names(bag: Path) -> list[str]:
    """Joint names of the bag's first valid JointState message (empty if none/unreadable)."""
    probe = JointSelector(None)
    try:
        for _, _, names, pos, vel, eff in read_joint_states(bag):
            if not isinstance(probe.select(names, pos, vel, eff), str):
                return [str(n) for n in names]
    except Exception:  # the main pass reports unreadable and damaged bags
        pass
    return []


def _majority_joints(sets: list[list[str]]) -> list[str] | None:
    """The joint set most bags share (order of its first bag; ties: the first seen)."""
    votes: Counter[frozenset[str]] = Counter()
    order: dict[frozenset[str], list[str]] = {}
    for names in sets:
        key = frozenset(names)
        votes[key] += 1
        order.setdefault(key, names)
    if not votes:
        return None
    best = max(votes.values())
    # dicts keep insertion order, so the first set reaching the maximum is the earliest.
    return next(order[k] for k in order if votes[k] == best)


def _no_demo_reason(
    n_read: int,
    counts: Counter[str],
    found: int,
    too_short: int,
    min_samples: int,
    joints: Sequence[str] | None,
    names: list[str],
) -> str:
    """Why a bag that opened gave no demonstration (one line).

    ``n_read`` counts the decoded messages; ``counts["undecodable"]`` those that were not.
    """
    undecodable = counts["undecodable"]
    if n_read == 0 and not undecodable:
        return f"no {JOINT_STATE} messages"
    if found and found == too_short:
        return (f"{found} demonstration(s), all shorter than {min_samples} samples")
    parts = [f"{reason}={n}" for reason, n in counts.items() if n]
    text = f"all {n_read + undecodable} JointState message(s) skipped ({', '.join(parts)})"
    if joints and (counts["missing_joints"] or counts["unknown_joints"]):
        missing = [j for j in joints if j not in names]
        shown = ", ".join(names[:40]) + (f" and {len(names) - 40} more"
                                          if len(names) > 40 else "")
        text += f"; missing joint(s) {', '.join(missing)}; the bag has: {shown}"
    return text


def _name_demos(demos: list[DemoInfo]) -> None:
    """Give every demonstration a unique, readable name (see :class:`DemoInfo`)."""
    paths = sorted({d.bag for d in demos})
    # A bare storage file's own name (``demo_0002.mcap``) rarely says where it lies: a
    # directory without metadata.yaml or a copied bag names it better.
    depth = {bag: 1 if Path(bag).suffix not in (".mcap", ".db3") else 2 for bag in paths}
    while True:
        names: dict[str, list[str]] = {}
        for bag in paths:
            names.setdefault(_tail(bag, depth[bag]), []).append(bag)
        clashing = [bag for group in names.values() if len(group) > 1 for bag in group
                    if depth[bag] < len(Path(bag).parts)]
        if not clashing:  # unique (distinct paths differ at the latest in full)
            break
        # Bags of one name in several datasets (``ds1/a/demo_0000``, ``ds2/a/demo_0000``):
        # one more parent each until they differ.
        for bag in clashing:
            depth[bag] += 1
    per_bag = Counter(d.bag for d in demos)
    index: Counter[str] = Counter()
    for d in demos:
        base = _tail(d.bag, depth[d.bag])
        index[d.bag] += 1
        d.name = base if per_bag[d.bag] == 1 else f"{base}#{index[d.bag]}"


def _tail(path: str, depth: int) -> str:
    """The last ``depth`` components of ``path``, joined by ``/`` (all of it, as given,
    from its root on)."""
    parts = Path(path).parts
    return str(Path(path)) if depth >= len(parts) else "/".join(parts[-depth:])
