"""Writing one demonstration as a rosbag2 bag of JointState messages, atomically.

Storage: bags are written with the MCAP storage plugin and metadata version 9, the
defaults of ``ros2 bag record`` since Iron (so also Jazzy), which Foxglove opens directly
and whose single append-only file has its index at the end.

Atomicity: a bag is written into a hidden temporary directory next to its final name,
every file and the directory are fsync'ed, then it is renamed into place and the parent
directory is fsync'ed. A crash at any point leaves either the complete bag or a hidden
temporary directory, which readers ignore
(:func:`~policy_align_ros.data.bags.format.is_temporary`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import uuid
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer

from policy_align_ros.data.bags.format import DEFAULT_TOPIC, JOINT_STATE, TYPESTORE
from policy_align_ros.data.messages import validate_joint_names

__all__ = ["next_demo_path", "write_joint_state_bag"]

_TMP_PREFIX = ".tmp-"
_DEMO_RE = re.compile(r"^demo_(\d+)$")
_JointState = TYPESTORE.types[JOINT_STATE]
_Header = TYPESTORE.types["std_msgs/msg/Header"]
_Time = TYPESTORE.types["builtin_interfaces/msg/Time"]
_EMPTY = np.empty(0, dtype=np.float64)
# First stamp a header cannot hold: builtin_interfaces/Time's ``sec`` is an int32.
_STAMP_LIMIT_NS = 2**31 * 1_000_000_000


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
    return TYPESTORE.serialize_cdr(msg, JOINT_STATE)


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
        ``[0, 2^31)`` s, values that are not numbers, or if ``path`` exists and ``unique``
        is not set.
    OSError
        When the bag cannot be written.

    Every error names the bag (``path``); an error of the writer keeps its type.
    """
    final = Path(path)
    try:
        return _write(final, joint_names, stamps_ns, positions, velocities, has_velocity,
                      topic, unique)
    except Exception as err:
        named = _name_the_bag(err, final)
        if named is err:
            raise
        raise named from err


def _name_the_bag(err: Exception, final: Path) -> Exception:
    """``err`` with a message that names the bag ``final``; a ValueError that does when
    its message cannot be changed.

    A recorder reports a failed write by its message, and an error from deep inside the
    writer (rosbags, numpy, the file system on the staging directory) names no bag. The
    message is changed in place, so the exception keeps its type, its errno and its
    identity (a caller can still tell a full disk from a bad value, or chain it).
    """
    text = str(err)
    if str(final) in text:
        return err
    if isinstance(err, OSError) and err.errno is not None and err.strerror:
        err.strerror = f"{err.strerror} (writing bag {final})"  # str() is made from it
    else:
        err.args = (f"{final}: {text}",)
    if str(final) in str(err):
        return err
    # A message made from other fields than args (UnicodeDecodeError's).
    return ValueError(f"{final}: {type(err).__name__}: {text}")


def _write(final: Path, joint_names: Sequence[str], stamps_ns: Sequence[int] | np.ndarray,
           positions: np.ndarray, velocities: np.ndarray | None,
           has_velocity: Sequence[bool] | np.ndarray | None, topic: str, unique: bool
           ) -> Path:
    """:func:`write_joint_state_bag`'s work; its errors may not name the bag."""
    names, stamps, q, v, flags = _checked_messages(
        final, joint_names, stamps_ns, positions, velocities, has_velocity)
    n_msgs = stamps.shape[0]
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
            conn = writer.add_connection(topic, JOINT_STATE, typestore=TYPESTORE)
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


def _checked_messages(
    final: Path,
    joint_names: Sequence[str],
    stamps_ns: Sequence[int] | np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray | None,
    has_velocity: Sequence[bool] | np.ndarray | None,
) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """The arguments of :func:`write_joint_state_bag` as arrays, checked.

    Returns names (n), stamps (N,) int64 ns, positions (N, n), velocities (N, n) or None and
    the per-message velocity flags (N,) bool; raises ValueError naming ``final``.
    """
    names = [str(j) for j in joint_names]
    # Contiguous native arrays: the serializer views each row's memory as float64 and
    # refuses a row of a reversed or transposed view (Q[:, ::-1], Q.T) or another byte
    # order. The stamps keep their dimensions (ascontiguousarray makes a scalar (1,)),
    # so that a scalar is refused below.
    stamps = np.asarray(stamps_ns, dtype=np.int64, order="C")
    q = np.ascontiguousarray(positions, dtype=np.float64)
    if stamps.ndim != 1:
        raise ValueError(f"{final}: stamps_ns must have shape (N,), got {stamps.shape}")
    n_msgs = stamps.shape[0]
    if q.shape != (n_msgs, len(names)):
        raise ValueError(
            f"{final}: positions must have shape ({n_msgs}, {len(names)}) to match stamps "
            f"and joint names, got {q.shape}"
        )
    v = None if velocities is None else np.ascontiguousarray(velocities, dtype=np.float64)
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
    return names, stamps, q, v, flags


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

