"""Recording joint-state demonstrations into a dataset directory (ROS-free).

:class:`DemoRecorder` receives decoded ``sensor_msgs/msg/JointState`` messages as plain
values (``stamp_ns`` in integer nanoseconds, joint ``names``, ``positions`` in rad or m,
``velocities`` in rad/s or m/s, optional ``efforts``), validates them with the rules of
:mod:`policy_align_ros.data.messages`, buffers the current demonstration and writes it as
one rosbag2 bag (:func:`policy_align_ros.data.bags.write_joint_state_bag`) when it ends.

Two modes:

* manual (``auto_split_gap_s == 0``): a demonstration is what arrives between
  :meth:`DemoRecorder.start` and :meth:`DemoRecorder.stop`;
* continuous (``auto_split_gap_s > 0``): while active, the stream is split into
  demonstrations wherever the stamps jump by more than the gap, or when nothing arrived
  for that long (:meth:`DemoRecorder.flush_if_idle`).

Buffering is in ``array.array`` (8 bytes a value, appended in O(n) without numpy) so a
1 kHz stream costs a few microseconds a message; writing happens when a demonstration
ends, and a bag is complete and durable when the call that wrote it returns. A process
killed mid-demonstration loses only that demonstration: earlier bags are complete, and a
bag being written at that instant stays a hidden temporary directory.
"""

from __future__ import annotations

import os
import threading
import time
from array import array
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from policy_align_ros.data.bags import DEFAULT_TOPIC, next_demo_path, write_joint_state_bag
from policy_align_ros.data.messages import (
    NEW,
    SKIP,
    SKIP_REASONS,
    JointSelector,
    StreamClock,
    validate_joint_names,
)

__all__ = ["DemoRecorder", "validate_gap", "validate_dataset_dir"]


def validate_gap(auto_split_gap_s: float) -> float:
    """Check a split gap in seconds (``0`` = manual mode); returns it as a float."""
    gap = float(auto_split_gap_s)
    if not (np.isfinite(gap) and gap >= 0.0):
        raise ValueError(f"auto_split_gap_s: must be a finite number >= 0, got {gap}")
    return gap


def validate_dataset_dir(dataset_dir: str | os.PathLike[str]) -> Path:
    """Check a dataset directory name (it is created on the first write)."""
    text = os.fspath(dataset_dir)
    if not text.strip():
        raise ValueError("dataset_dir: must not be empty")
    path = Path(text).expanduser()
    if path.exists() and not path.is_dir():
        raise ValueError(f"dataset_dir: {path} exists and is not a directory")
    return path


class DemoRecorder:
    """Buffer joint-state messages and write one bag per demonstration.

    Parameters
    ----------
    dataset_dir : path-like
        Directory receiving the bags ``demo_NNNN`` (created when needed).
    joints : sequence of str, optional
        Recorded joints in order; default: those of the first accepted message, kept for
        the recorder's lifetime so that every bag of a dataset has the same joints.
    auto_split_gap_s : float
        ``0`` for manual mode, else the gap in seconds that splits a continuous recording.
    topic : str
        Topic name written into the bags.
    min_messages : int
        Demonstrations with fewer valid messages are dropped, not written.

    Attributes
    ----------
    skipped : Counter
        Skipped messages by reason (see :data:`SKIP_REASONS`), over the lifetime.
    accepted : int
        Valid messages recorded over the lifetime.
    written : list of Path
        Bags written, in order.
    dropped : int
        Demonstrations dropped for having fewer than ``min_messages`` messages.
    """

    def __init__(
        self,
        dataset_dir: str | os.PathLike[str],
        *,
        joints: Sequence[str] | None = None,
        auto_split_gap_s: float = 0.0,
        topic: str = DEFAULT_TOPIC,
        min_messages: int = 2,
    ) -> None:
        self.dataset_dir = validate_dataset_dir(dataset_dir)
        self._selector = JointSelector(joints)
        self.auto_split_gap_s = validate_gap(auto_split_gap_s)
        self._clock = StreamClock(round(self.auto_split_gap_s * 1e9))
        self.topic = topic
        if int(min_messages) < 1:
            raise ValueError(f"min_messages: must be >= 1, got {min_messages}")
        self.min_messages = int(min_messages)
        self.skipped: Counter[str] = Counter({reason: 0 for reason in SKIP_REASONS})
        self.accepted = 0
        self.written: list[Path] = []
        self.dropped = 0
        self._active = False
        self._last_rx = 0.0
        self._lock = threading.Lock()
        self._clear()

    # -- configuration ---------------------------------------------------------------
    @property
    def joints(self) -> list[str] | None:
        """Recorded joints (``None`` until fixed by the first accepted message)."""
        return self._selector.joints

    def set_joints(self, joints: Sequence[str] | None) -> None:
        """Change the recorded joints; refused while a demonstration is buffered."""
        names = validate_joint_names(joints)
        with self._lock:
            if self._stamps:
                raise ValueError("joints: cannot change while a demonstration is recorded")
            self._selector.set_joints(names)

    def set_auto_split_gap(self, auto_split_gap_s: float) -> None:
        """Change the split gap (seconds, ``0`` = manual); applies to the next message."""
        gap = validate_gap(auto_split_gap_s)
        with self._lock:
            self.auto_split_gap_s = gap
            self._clock.gap_ns = round(gap * 1e9)

    def set_dataset_dir(self, dataset_dir: str | os.PathLike[str]) -> None:
        """Change the directory of the next bags."""
        path = validate_dataset_dir(dataset_dir)
        with self._lock:
            self.dataset_dir = path

    # -- state -----------------------------------------------------------------------
    @property
    def active(self) -> bool:
        """Whether messages are being recorded."""
        return self._active

    @property
    def buffered(self) -> int:
        """Valid messages in the current, unwritten demonstration."""
        return len(self._stamps)

    def _clear(self) -> None:
        self._stamps = array("q")
        self._positions = array("d")
        self._velocities = array("d")
        self._has_velocity = array("b")
        self._n = 0

    def start(self) -> None:
        """Start recording a demonstration.

        Raises
        ------
        RuntimeError
            If a demonstration is already being recorded.
        """
        with self._lock:
            if self._active:
                raise RuntimeError(
                    f"already recording a demonstration ({len(self._stamps)} messages so "
                    "far); stop it first"
                )
            self._active = True
            self._clock.reset()
            self._clear()
            self._last_rx = time.monotonic()

    def stop(self) -> Path | None:
        """Stop recording and write the current demonstration.

        Returns
        -------
        Path or None
            The bag written (complete and fsync'ed), or ``None`` if the demonstration had
            fewer than ``min_messages`` valid messages (nothing is written).
        """
        with self._lock:
            self._active = False
            return self._write_current()

    def discard(self) -> int:
        """Stop recording and drop the current demonstration; returns its message count."""
        with self._lock:
            self._active = False
            count = len(self._stamps)
            self._clear()
            return count

    def flush_if_idle(self, now: float | None = None) -> Path | None:
        """In continuous mode, end the current demonstration if the stream went quiet.

        Parameters
        ----------
        now : float, optional
            ``time.monotonic()`` reading (seconds); default: now.

        Returns
        -------
        Path or None
            The bag written, if any.
        """
        now = time.monotonic() if now is None else now
        with self._lock:
            gap = self.auto_split_gap_s
            if not (gap and self._active and self._stamps and now - self._last_rx > gap):
                return None
            return self._write_current()

    # -- data ------------------------------------------------------------------------
    def add(
        self,
        stamp_ns: int,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float] = (),
        efforts: Sequence[float] = (),
    ) -> Path | None:
        """Record one joint-state message (ignored when not recording).

        Parameters
        ----------
        stamp_ns : int
            Header stamp in nanoseconds.
        names : sequence of str, length m
        positions : sequence of float, length m
        velocities, efforts : sequence of float, length 0 or m

        Returns
        -------
        Path or None
            In continuous mode, the bag of the previous demonstration when this message
            starts a new one after a gap; otherwise ``None``.
        """
        if not self._active:
            return None
        with self._lock:
            picked = self._selector.select(names, positions, velocities, efforts)
            if isinstance(picked, str):
                self.skipped[picked] += 1
                return None
            outcome = self._clock.step(stamp_ns)
            if outcome == SKIP:
                self.skipped["time_not_increasing"] += 1
                return None
            written = None
            if outcome == NEW and self._stamps:
                written = self._write_current()
            self._selector.commit(names)
            self._clock.accept(stamp_ns)
            self._last_rx = time.monotonic()
            pos, vel = picked
            self._stamps.append(stamp_ns)
            self._positions.extend(pos)
            self._n = len(pos)
            if vel is None:
                self._velocities.extend(pos)  # placeholder row, flagged as absent
                self._has_velocity.append(0)
            else:
                self._velocities.extend(vel)
                self._has_velocity.append(1)
            self.accepted += 1
            return written

    def _write_current(self) -> Path | None:
        """Write and clear the buffered demonstration (caller holds the lock)."""
        count = len(self._stamps)
        if count == 0:
            return None
        if count < self.min_messages:
            self.dropped += 1
            self._clear()
            return None
        stamps, n = self._stamps, self._n
        positions = np.frombuffer(self._positions, dtype=np.float64).reshape(count, n)
        velocities = np.frombuffer(self._velocities, dtype=np.float64).reshape(count, n)
        flags = np.frombuffer(self._has_velocity, dtype=np.int8).astype(bool)
        joints = self._selector.joints
        assert joints is not None
        try:
            path = write_joint_state_bag(
                next_demo_path(self.dataset_dir),
                joints,
                np.frombuffer(stamps, dtype=np.int64),
                positions,
                velocities if flags.any() else None,
                has_velocity=flags if flags.any() else None,
                topic=self.topic,
                unique=True,
            )
        finally:
            # A failed write is not retried with the same data: the stream goes on.
            self._clear()
        self.written.append(path)
        return path
