"""Recording joint-state demonstrations into a dataset directory (ROS-free).

:class:`DemoRecorder` receives decoded ``sensor_msgs/msg/JointState`` messages as plain
values (``stamp_ns`` in integer nanoseconds, joint ``names``, ``positions`` in rad or m,
``velocities`` in rad/s or m/s, optional ``efforts``), validates them with the rules of
:mod:`policy_align_ros.data.messages`, buffers the current demonstration and writes it as
one rosbag2 bag (:func:`policy_align_ros.data.bags.write.write_joint_state_bag`) when it ends.

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

Failed writes lose nothing. The dataset directory is created and probed for writing when
it is set (:func:`~policy_align_ros.data.dataset_dir.check_dataset_dir`), and a
demonstration whose write fails later (full disk, EFBIG, the directory replaced or made
read-only) is kept in memory as the *pending* demonstration, at most one:
:meth:`DemoRecorder.start` is refused while it exists, a continuous recording pauses
(messages counted in ``lost_while_pending``), and :meth:`DemoRecorder.stop` or
:meth:`DemoRecorder.retry_pending` writes it once the directory works again.
:meth:`DemoRecorder.close` writes whatever is left, into a fallback directory
(:func:`~policy_align_ros.data.dataset_dir.default_fallback_dirs`) if the dataset
directory still fails. Any exception of the bag writer counts as a failed write, not only
``OSError``: an unexpected one (a bug, an ``OverflowError`` on a value a bag cannot hold)
must not lose the demonstration or escape into a node's callbacks either.

Header stamps before the epoch (negative, e.g. ``sec = -1`` from a publisher whose clock
was never set) are skipped as ``time_negative``: a bag stores times as unsigned integers.

A bag in which the robot stood still (every joint within ``still_tolerance`` of its first
sample) is written all the same, since a recorder never drops data, and listed in
``still_bags``; :attr:`DemoRecorder.stoppable` says whether a stop has anything to end.
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

from policy_align_ros.data.bags.format import DEFAULT_TOPIC
from policy_align_ros.data.dataset_dir import check_dataset_dir
from policy_align_ros.data.finished_demo import (
    STILL_TOLERANCE,
    FinishedDemo,
    PendingWriteError,
    SaveResult,
    error_text,
)
from policy_align_ros.data.messages import (
    NEW,
    SKIP,
    SKIP_REASONS,
    JointSelector,
    StreamClock,
    validate_joint_names,
)

__all__ = [
    "STILL_TOLERANCE",
    "DemoRecorder",
    "PendingWriteError",
    "SaveResult",
    "validate_gap",
]


def validate_gap(auto_split_gap_s: float) -> float:
    """Check a split gap in seconds (``0`` = manual mode); returns it as a float."""
    gap = float(auto_split_gap_s)
    if not (np.isfinite(gap) and gap >= 0.0):
        raise ValueError(f"auto_split_gap_s: must be a finite number >= 0, got {gap}")
    return gap


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
    max_stamp_ahead_s : float
        A stamp more than this many seconds after the receive clock given to :meth:`add`
        (``clock_ns``) is skipped as ``time_in_future``: accepted, it would make every
        later, correctly stamped message of a manual demonstration "not increasing", so
        one stray stamp would lose the rest of the demonstration.
    still_tolerance : float
        A demonstration whose every joint stays within this of its first sample (rad or
        m) is written and listed in ``still_bags``: the robot did not move.

    Attributes
    ----------
    skipped : Counter
        Skipped messages by reason (see :data:`SKIP_REASONS`, plus ``time_in_future``,
        ``time_negative``, ``clock_reset`` and ``after_clock_reset`` once they happen),
        over the lifetime.
    accepted : int
        Valid messages recorded over the lifetime.
    written : list of Path
        Bags written, in order.
    still_bags : list of Path
        Those of them in which the robot did not move (``still_tolerance``).
    dropped : int
        Demonstrations dropped for having fewer than ``min_messages`` messages.
    discarded : int
        Manual demonstrations discarded at ``stop`` because the stamps jumped back by
        :data:`~policy_align_ros.data.messages.CLOCK_RESET_S` or more during them.
    last_discard : str
        Why the last ``stop`` discarded its demonstration ("" when it did not).
    lost_while_pending : int
        Messages not recorded because a continuous recording was paused while a pending
        demonstration waited to be written.
    last_foreign : tuple of str or None
        The joint names of the last message skipped as ``unknown_joints`` or
        ``missing_joints`` (:func:`~policy_align_ros.data.messages.describe_foreign` says
        what it lacks); None while there is none.
    """

    def __init__(
        self,
        dataset_dir: str | os.PathLike[str],
        *,
        joints: Sequence[str] | None = None,
        auto_split_gap_s: float = 0.0,
        topic: str = DEFAULT_TOPIC,
        min_messages: int = 2,
        max_stamp_ahead_s: float = 1.0,
        still_tolerance: float = STILL_TOLERANCE,
    ) -> None:
        self.dataset_dir = check_dataset_dir(dataset_dir)
        ahead = float(max_stamp_ahead_s)
        if not (np.isfinite(ahead) and ahead >= 0.0):
            raise ValueError(f"max_stamp_ahead_s: must be a finite number >= 0, got {ahead}")
        self._max_ahead_ns = round(ahead * 1e9)
        still = float(still_tolerance)
        if not (np.isfinite(still) and still >= 0.0):
            raise ValueError(f"still_tolerance: must be a finite number >= 0, got {still}")
        self.still_tolerance = still
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
        self.still_bags: list[Path] = []
        self.dropped = 0
        self.discarded = 0
        self.last_discard = ""
        self._spoiled = ""  # why the current manual demonstration cannot be kept
        self.lost_while_pending = 0
        self.last_foreign: tuple[str, ...] | None = None
        self._pending: FinishedDemo | None = None
        self._pending_error = ""
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

    def set_auto_split_gap(self, auto_split_gap_s: float) -> Path | None:
        """Change the split gap (seconds, ``0`` = manual); applies to the next message.

        Switching a continuous recording to manual mode ends its current demonstration
        and writes it: it was recorded to be kept, and manual mode drops an unfinished
        demonstration at :meth:`close`. Recording stays on (as a manual demonstration).

        Returns
        -------
        Path or None
            The bag written by the switch, if any.

        Raises
        ------
        ValueError
            A gap that is not a finite number >= 0 (nothing changes).
        PendingWriteError
            The switch's write failed; the gap is changed and the demonstration pending.
        """
        gap = validate_gap(auto_split_gap_s)
        with self._lock:
            ending = self.auto_split_gap_s > 0 and gap == 0 and self._pending is None
            self.auto_split_gap_s = gap
            self._clock.gap_ns = round(gap * 1e9)
            if gap:  # a continuous recording splits at a reset instead of being spoiled
                self._spoiled = ""
            return self._write_current() if ending else None

    def set_dataset_dir(self, dataset_dir: str | os.PathLike[str]) -> None:
        """Change the directory of the next bags (checked as by check_dataset_dir)."""
        path = check_dataset_dir(dataset_dir)
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

    @property
    def pending(self) -> int:
        """Messages of the demonstration waiting to be written (0: none is pending)."""
        pending = self._pending
        return 0 if pending is None else len(pending)

    @property
    def stoppable(self) -> bool:
        """Whether :meth:`stop` has a demonstration to end: one being recorded, or one
        pending. A stop without one is no empty demonstration: it was never started."""
        return self._active or self._pending is not None

    @property
    def pending_error(self) -> str:
        """Why the pending demonstration could not be written ("" when none is pending)."""
        return self._pending_error

    def _clear(self) -> None:
        self._spoiled = ""  # the demonstration it spoiled goes with the buffer
        self._stamps = array("q")
        self._positions = array("d")
        self._velocities = array("d")
        self._has_velocity = array("b")
        self._n = 0

    def start(self, now: float | None = None) -> None:
        """Start recording a demonstration.

        Parameters
        ----------
        now : float, optional
            Receive time in seconds on the clock given to :meth:`add` and
            :meth:`flush_if_idle` (a node passes its clock, so sim time applies); default
            ``time.monotonic()``.

        Raises
        ------
        RuntimeError
            If a demonstration is already being recorded, or one is pending (its write
            failed; :meth:`stop` or :meth:`retry_pending` writes it).
        """
        with self._lock:
            if self._pending is not None:
                raise RuntimeError(self._pending_message())
            if self._active:
                raise RuntimeError(
                    f"already recording a demonstration ({len(self._stamps)} messages so "
                    "far); stop it first"
                )
            self._active = True
            self._clock.reset()
            self._clear()
            self._last_rx = time.monotonic() if now is None else now

    def stop(self) -> Path | None:
        """Stop recording and write the current demonstration, or retry the pending one.

        Returns
        -------
        Path or None
            The bag written (complete and fsync'ed), or ``None`` if the demonstration had
            fewer than ``min_messages`` valid messages, or none was started (nothing is
            written; :attr:`stoppable` tells the two apart).

        Raises
        ------
        PendingWriteError
            The write failed; the demonstration is kept as the pending one and recording
            stays stopped. Calling ``stop`` again retries it.
        """
        with self._lock:
            self._active = False
            self.last_discard = ""
            if self._pending is not None:
                # While one is pending nothing else is buffered (start is refused and a
                # continuous recording pauses), so this is the only write to do.
                return self._write_pending()
            if self._spoiled:
                self.last_discard = self._spoiled
                self.discarded += 1
                self._clear()
                return None
            return self._write_current()

    def retry_pending(self) -> Path | None:
        """Write the pending demonstration, if any, into the dataset directory.

        Returns
        -------
        Path or None
            The bag written, or ``None`` when nothing was pending. A continuous recording
            resumes once it is written.

        Raises
        ------
        PendingWriteError
            It failed again (it stays pending).
        """
        with self._lock:
            if self._pending is None:
                return None
            return self._write_pending()

    def close(
        self, keep_current: bool, fallback_dirs: Sequence[str | os.PathLike[str]] = ()
    ) -> list[SaveResult]:
        """Stop for good, saving the pending demonstration and optionally the current one.

        Never raises for a failed write, whatever the exception: each demonstration goes
        to the dataset directory, else to the first fallback directory that works, and the
        outcome is returned.

        Parameters
        ----------
        keep_current : bool
            Save the demonstration being recorded (continuous mode, where the stream's last
            segment is a finished demonstration); ``False`` discards it (manual mode,
            where it was never stopped).
        fallback_dirs : sequence of path-like
            Directories tried, in order, when the dataset directory fails (created if
            needed); see
            :func:`~policy_align_ros.data.dataset_dir.default_fallback_dirs`.

        Returns
        -------
        list of SaveResult
            One per demonstration that had to be saved (pending first).
        """
        with self._lock:
            self._active = False
            demos = [] if self._pending is None else [self._pending]
            self._pending, self._pending_error = None, ""
            if keep_current and len(self._stamps) >= self.min_messages:
                demos.append(self._take_current())
            elif len(self._stamps) and keep_current:
                self.dropped += 1
            self._clear()
            results = []
            for demo in demos:
                errors: list[str] = []
                path = None
                targets = [self.dataset_dir, *(Path(d) for d in fallback_dirs)]
                for k, directory in enumerate(targets):
                    try:
                        path = demo.write(directory)
                    except Exception as err:  # any writer error (module docstring)
                        errors.append(f"{directory}: {error_text(err)}")
                        continue
                    self._written(demo, path)
                    results.append(SaveResult(len(demo), path, k > 0, tuple(errors)))
                    break
                else:
                    results.append(SaveResult(len(demo), None, False, tuple(errors)))
            return results

    def _pending_message(self) -> str:
        return (
            f"a demonstration of {len(self._pending)} messages could not be written "
            f"({self._pending_error}) and is kept in memory; make {self.dataset_dir} "
            "writable or change dataset_dir, then stop_demo writes it"
        )

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
            Current time in seconds on the clock of :meth:`add`'s ``now``; default
            ``time.monotonic()``.

        Returns
        -------
        Path or None
            The bag written, if any.

        Raises
        ------
        PendingWriteError
            The write failed; the demonstration is pending (see :meth:`retry_pending`).
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
        now: float | None = None,
        clock_ns: int | None = None,
    ) -> Path | None:
        """Record one joint-state message (ignored when not recording).

        Parameters
        ----------
        stamp_ns : int
            Header stamp in nanoseconds; a negative one is skipped as ``time_negative``.
        names : sequence of str, length m
        positions : sequence of float, length m
        velocities, efforts : sequence of float, length 0 or m
        now : float, optional
            Receive time in seconds (for :meth:`flush_if_idle`); default
            ``time.monotonic()``.
        clock_ns : int, optional
            Receive time in nanoseconds on the clock of the stamps (a node's clock); when
            given, a stamp more than ``max_stamp_ahead_s`` after it is skipped as
            ``time_in_future``. ``None`` (an unknown or not yet started clock): no check.

        Returns
        -------
        Path or None
            In continuous mode, the bag of the previous demonstration when this message
            starts a new one after a gap; otherwise ``None``.

        Raises
        ------
        PendingWriteError
            In continuous mode, writing the previous demonstration failed: it is pending
            and recording pauses until it is written.
        """
        if not self._active:
            return None
        with self._lock:
            if self._pending is not None:
                # Paused until the pending one is written: at most one is kept in memory.
                self.lost_while_pending += 1
                return None
            picked = self._selector.select(names, positions, velocities, efforts)
            if isinstance(picked, str):
                self.skipped[picked] += 1
                if picked in ("unknown_joints", "missing_joints"):
                    self.last_foreign = tuple(names)
                return None
            if stamp_ns < 0:
                # Before the epoch: a publisher whose clock was never set (sec = -1). A bag
                # stores times as unsigned integers, so the demonstration could never be
                # written; the message is malformed, like one with a NaN position.
                self.skipped["time_negative"] += 1
                return None
            if clock_ns is not None and stamp_ns - clock_ns > self._max_ahead_ns:
                self.skipped["time_in_future"] += 1
                return None
            outcome = self._clock.step(stamp_ns)
            if outcome == SKIP or self._spoiled:
                self.skipped[self._skip_reason()] += 1
                return None
            written = None
            if outcome == NEW and self._stamps:
                try:
                    written = self._write_current()
                except PendingWriteError:
                    self.lost_while_pending += 1  # this message opened the next segment
                    raise
            self._selector.commit(names)
            self._clock.accept(stamp_ns)
            self._last_rx = time.monotonic() if now is None else now
            self._append(stamp_ns, *picked)
            return written

    def _skip_reason(self) -> str:
        """Why a message whose stamp does not go forward, or comes after a clock reset, is
        skipped; a manual demonstration's reset spoils it (a continuous recording starts
        a new one there instead: :class:`StreamClock`). Caller holds the lock."""
        if self._spoiled:
            return "after_clock_reset"
        back = self._clock.restart_s
        if not back:
            return "time_not_increasing"
        last = self._clock.last_ns or 0
        self._spoiled = (f"the joint-state stamps jumped back by {back:.3f} s after "
                         f"{last / 1e9:.3f} s (a clock or simulator reset?)")
        return "clock_reset"

    def _append(self, stamp_ns: int, pos: Sequence[float], vel: Sequence[float] | None
                ) -> None:
        """Buffer one accepted message (caller holds the lock)."""
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

    def _take_current(self) -> FinishedDemo:
        """The buffered demonstration as arrays that own their data (caller holds the lock)."""
        count, n = len(self._stamps), self._n
        flags = np.frombuffer(self._has_velocity, dtype=np.int8).astype(bool)
        velocities = np.frombuffer(self._velocities, dtype=np.float64).reshape(count, n)
        joints = self._selector.joints
        assert joints is not None
        return FinishedDemo(
            joints=list(joints),
            stamps=np.frombuffer(self._stamps, dtype=np.int64).copy(),
            positions=np.frombuffer(self._positions, dtype=np.float64).reshape(count, n).copy(),
            velocities=velocities.copy() if flags.any() else None,
            has_velocity=flags if flags.any() else None,
            topic=self.topic,
        )

    def _write_current(self) -> Path | None:
        """Write and clear the buffered demonstration (caller holds the lock).

        A failed write keeps it as the pending demonstration and raises PendingWriteError.
        """
        count = len(self._stamps)
        if count == 0:
            return None
        if count < self.min_messages:
            self.dropped += 1
            self._clear()
            return None
        demo = self._take_current()
        self._clear()
        self._pending = demo
        return self._write_pending()

    def _write_pending(self) -> Path:
        """Write the pending demonstration (caller holds the lock); it stays on failure.

        Every exception of the writer becomes a PendingWriteError, so callers (and a
        node's callbacks) have one failure to handle and the demonstration is retried.
        """
        demo = self._pending
        assert demo is not None
        try:
            path = demo.write(self.dataset_dir)
        except Exception as err:  # any writer error (module docstring)
            self._pending_error = error_text(err)
            raise PendingWriteError(self._pending_message()) from err
        self._pending, self._pending_error = None, ""
        self._written(demo, path)
        return path

    def _written(self, demo: FinishedDemo, path: Path) -> None:
        """Note ``demo`` written at ``path`` (caller holds the lock)."""
        self.written.append(path)
        if demo.still(self.still_tolerance):
            self.still_bags.append(path)

