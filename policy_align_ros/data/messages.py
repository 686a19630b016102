"""Validation and segmentation of ``sensor_msgs/msg/JointState`` streams (ROS-free).

A joint-state message is handled here as plain values: a stamp in integer nanoseconds
(``stamp_ns``), the joint ``names`` and the ``positions`` (rad or m), ``velocities``
(rad/s or m/s) and ``efforts`` sequences, which may be empty as in ``sensor_msgs``.

The same rules serve the bag reader and the live recorder, so a message is skipped for
exactly one reason, the first that applies, in this order:

``length_mismatch``
    ``positions`` differ in length from ``names``, or ``velocities`` / ``efforts`` are
    neither empty nor of that length.
``duplicate_joints``
    a joint name appears twice.
``unknown_joints``
    none of the message's joints is a selected joint (for example another publisher's
    joints on the same topic).
``missing_joints``
    some, but not all, of the selected joints are present.
``non_finite``
    a selected position or velocity is NaN or inf.
``time_not_increasing``
    the stamp is not later than the last accepted one (going backwards or repeated).

Selected joints are either given or taken from the first accepted message; joints of a
message beyond the selected ones are ignored, so foreign streams with extra joints in
any order are matched by name. The per-message work is plain Python and O(n), with the
name-to-index mapping cached, so that a 1 kHz stream costs a few microseconds a message.

:meth:`JointSelector.select` (lists, for the bag reader and the recorder) and
:meth:`JointSelector.vector` (a numpy vector, for the executor and the other live nodes)
apply these same rules; they are the one JointState-to-vector conversion of the package.
Of the reasons, :data:`UNTRUSTWORTHY` mark a message that is broken (a live consumer
should stop acting on the stream), while ``unknown_joints`` and ``missing_joints`` mark a
message meant for someone else (another publisher's joints on a shared topic).
:func:`describe_skips` words the counts of skipped messages by reason for a log line.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = [
    "CLOCK_RESET_S",
    "SKIP_REASONS",
    "UNTRUSTWORTHY",
    "JointSelector",
    "StreamClock",
    "UnusableReasons",
    "describe_foreign",
    "describe_skips",
    "validate_joint_names",
]

SKIP_REASONS: tuple[str, ...] = (
    "length_mismatch",
    "duplicate_joints",
    "unknown_joints",
    "missing_joints",
    "non_finite",
    "time_not_increasing",
)

#: Skip reasons of a broken message (as opposed to one carrying other joints).
UNTRUSTWORTHY: frozenset[str] = frozenset({"length_mismatch", "duplicate_joints",
                                           "non_finite"})

#: Outcomes of :meth:`StreamClock.step`.
SAME, NEW, SKIP = 0, 1, 2
#: Stamps this many seconds or more before the last one, two in a row (one stray stamp is
#: followed by stamps ahead again), are a clock that was reset (a restarted simulation),
#: not messages out of order: a stream split at gaps starts a new segment there, and a
#: manual demonstration recorded across it is spoiled (:class:`StreamClock`).
CLOCK_RESET_S = 1.0

# Bounds the per-name-list cache; real streams have one or two distinct name lists.
_CACHE_LIMIT = 64


def describe_skips(skipped: dict[str, int], lost: int) -> str:
    """The counts of skipped messages by reason, with a hint for the clock-related ones.

    Parameters
    ----------
    skipped : dict
        Skip reason -> messages skipped
        (:attr:`~policy_align_ros.data.recording.DemoRecorder.skipped`); zeros are left out.
    lost : int
        Messages dropped while a failed write was pending
        (:attr:`~policy_align_ros.data.recording.DemoRecorder.lost_while_pending`).
    """
    detail = ", ".join(f"{k}={v}" for k, v in skipped.items() if v)
    if skipped.get("time_in_future"):
        detail += (" (time_in_future: header stamps ahead of this node's clock; are the "
                   "clocks synchronised, and use_sim_time the same on every node?)")
    if skipped.get("time_not_increasing"):
        detail += (" (time_not_increasing: a stamp repeated or before the last one; a paused "
                   "simulation repeats its stamp, a message out of order comes late)")
    if skipped.get("clock_reset") or skipped.get("after_clock_reset"):
        detail += (" (clock_reset: the stamps jumped back by a second or more, a restarted "
                   "simulation; that demonstration is discarded at stop_demo)")
    if skipped.get("time_negative"):
        detail += (" (time_negative: header stamps before 1970; does the publisher "
                   "stamp with a clock that was never set?)")
    if lost:
        detail += f"{', ' if detail else ''}paused_while_a_write_is_pending={lost}"
    return detail


def _some(names: Sequence[str], shown: int = 4) -> str:
    """The first ``shown`` of ``names``, quoted, and how many more there are."""
    names = list(names)
    if not names:
        return "none"
    text = ", ".join(map(repr, names[:shown]))
    return text + (f" and {len(names) - shown} more" if len(names) > shown else "")


def describe_foreign(joints: Sequence[str], names: Sequence[str], *,
                     carrier: str = "the message names") -> str:
    """Why a message was skipped as ``unknown_joints`` or ``missing_joints``, in words: the
    selected ``joints`` it lacks (the first few and a count) and the joint ``names`` it
    carries. A typo in a configured joint, or another publisher's joints on the same
    topic, then reads as what it is. The recorder and the executor both say it, and the
    learn pipeline of a whole bag (``carrier``: who carries the ``names``)."""
    present = set(names)
    missing = [j for j in joints if j not in present]
    if len(missing) == len(joints):
        what = f"none of the {len(joints)} joints ({_some(joints)})"
    else:
        what = f"missing {len(missing)} of the {len(joints)} joints: {_some(missing)}"
    return f"{what}; {carrier} {len(names)} joint(s): {_some(names)}"


class UnusableReasons:
    """:func:`describe_foreign` of the selected ``joints`` and a message's joint names,
    with ``fix`` appended; cached per list of names (a topic carries few), at most
    ``size`` of them."""

    def __init__(self, joints: Sequence[str], fix: str, size: int = 64) -> None:
        self.joints, self.fix, self.size = list(joints), fix, size
        self._known: dict[tuple[str, ...], str] = {}

    def __call__(self, names: Sequence[str]) -> str:
        names = tuple(names)
        if names not in self._known:
            if len(self._known) >= self.size:
                self._known.clear()
            self._known[names] = f"{describe_foreign(self.joints, names)}. {self.fix}"
        return self._known[names]


def validate_joint_names(joints: Sequence[str] | None) -> list[str] | None:
    """Check a joint selection.

    Parameters
    ----------
    joints : sequence of str or None
        Joint names in the order wanted; ``None`` or empty means "from the first message".

    Returns
    -------
    list of str or None
        The names as a list, ``None`` for an empty selection.

    Raises
    ------
    ValueError
        If a name is not a non-empty string or appears twice.
    """
    if joints is None:
        return None
    if isinstance(joints, str):
        raise ValueError(f"joints: expected a list of joint names, got the string {joints!r}")
    names = list(joints)
    if not names:
        return None
    seen: set[str] = set()
    for name in names:
        if not isinstance(name, str) or not name.strip():
            raise ValueError(f"joints: invalid joint name {name!r} (need non-empty strings)")
        if name in seen:
            raise ValueError(f"joints: joint {name!r} is listed twice")
        seen.add(name)
    return names


class JointSelector:
    """Pick the selected joints out of joint-state messages, by name.

    Parameters
    ----------
    joints : sequence of str, optional
        Selected joints in output order; ``None`` takes the names of the first accepted
        message (call :meth:`commit` with them).
    """

    def __init__(self, joints: Sequence[str] | None = None) -> None:
        self.joints: list[str] | None = validate_joint_names(joints)
        self._cache: dict[tuple[str, ...], list[int] | str] = {}
        # Index arrays for :meth:`vector`, keyed like ``_cache`` and cleared with it.
        self._arrays: dict[tuple[str, ...], np.ndarray] = {}

    def set_joints(self, joints: Sequence[str] | None) -> None:
        """Change the selection (``None``: from the next accepted message)."""
        self.joints = validate_joint_names(joints)
        self._clear()

    def _clear(self) -> None:
        self._cache.clear()
        self._arrays.clear()

    def _indices(self, names: Sequence[str]) -> list[int] | str:
        key = tuple(names)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        position = {name: i for i, name in enumerate(key)}
        result: list[int] | str
        if len(position) != len(key):
            result = "duplicate_joints"
        elif self.joints is None:
            result = list(range(len(key))) if key else "unknown_joints"
        else:
            found = [position[j] for j in self.joints if j in position]
            if not found:
                result = "unknown_joints"
            elif len(found) < len(self.joints):
                result = "missing_joints"
            else:
                result = found
        if len(self._cache) >= _CACHE_LIMIT:
            self._clear()
        self._cache[key] = result
        return result

    def select(
        self,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float] = (),
        efforts: Sequence[float] = (),
    ) -> tuple[list[float], list[float] | None] | str:
        """Validate one message and extract the selected joints.

        Parameters
        ----------
        names : sequence of str, length m
        positions : sequence of float, length m
        velocities, efforts : sequence of float, length 0 or m

        Returns
        -------
        (positions, velocities) or str
            Selected positions (length n) and velocities (length n, or ``None`` when the
            message has none), or the skip reason (one of :data:`SKIP_REASONS` except
            ``time_not_increasing``).
        """
        m = len(names)
        if len(positions) != m or len(velocities) not in (0, m) or len(efforts) not in (0, m):
            return "length_mismatch"
        idx = self._indices(names)
        if isinstance(idx, str):
            return idx
        pos = [float(positions[i]) for i in idx]
        vel = [float(velocities[i]) for i in idx] if len(velocities) else None
        isfinite = math.isfinite
        if not all(map(isfinite, pos)) or (vel is not None and not all(map(isfinite, vel))):
            return "non_finite"
        return pos, vel

    def commit(self, names: Sequence[str]) -> None:
        """Fix the selection to ``names`` if it is still open (first accepted message)."""
        if self.joints is None:
            self.joints = list(names)
            # Entries computed while the selection was open are no longer valid.
            self._clear()

    def vector(
        self,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float] = (),
        efforts: Sequence[float] = (),
    ) -> np.ndarray | str:
        """Validate one message and return the selected positions as a vector.

        Same rules and reasons as :meth:`select`, in numpy: a message's arrays
        (``array.array`` in rclpy's JointState) are read through the buffer protocol
        without a Python loop over the joints.

        Parameters
        ----------
        names : sequence of str, length m
        positions : sequence of float, length m
            rad (revolute) or m (prismatic).
        velocities, efforts : sequence of float, length 0 or m

        Returns
        -------
        ndarray, shape (n,), or str
            Selected positions in selection order (a new array), or the skip reason (one
            of :data:`SKIP_REASONS` except ``time_not_increasing``).
        """
        m = len(names)
        if len(positions) != m or len(velocities) not in (0, m) or len(efforts) not in (0, m):
            return "length_mismatch"
        key = tuple(names)
        idx = self._arrays.get(key)
        if idx is None:
            found = self._indices(key)
            if isinstance(found, str):
                return found
            idx = self._arrays[key] = np.asarray(found, dtype=np.intp)
        q = np.asarray(positions, dtype=float)[idx]
        if not np.isfinite(q).all():
            return "non_finite"
        if len(velocities) and not np.isfinite(np.asarray(velocities, dtype=float)[idx]).all():
            return "non_finite"
        return q


class StreamClock:
    """Order check and gap splitting of one stream of stamps.

    Parameters
    ----------
    gap_ns : int
        A step forward of more than ``gap_ns`` nanoseconds starts a new segment, and so
        does a jump backwards of more than ``gap_ns`` or a restarted clock
        (:attr:`restart_s`), rather than discarding the rest of the stream or splicing it
        onto what came before. ``0`` disables splitting: every step that is not forward is
        then skipped (:attr:`restart_s` tells a restart among them).

    Attributes
    ----------
    restart_s : float
        After :meth:`step`: how far back (s) the stream restarted, or 0.0. A stamp
        :data:`CLOCK_RESET_S` or more before the last one is remembered, and the next one
        that is after it and still that far back confirms the restart: one stray stamp is
        followed by stamps ahead again, and is only skipped.
    """

    def __init__(self, gap_ns: int = 0) -> None:
        if gap_ns < 0:
            raise ValueError(f"gap: must be >= 0, got {gap_ns} ns")
        self.gap_ns = int(gap_ns)
        self.last_ns: int | None = None
        self.restart_s = 0.0
        self._back_ns: int | None = None  # a first stamp far back, not yet confirmed

    def reset(self) -> None:
        """Forget the last stamp: the next message starts a segment."""
        self.last_ns = self._back_ns = None

    def step(self, stamp_ns: int) -> int:
        """Classify a stamp without accepting it (a stamp far back is remembered, to tell
        a restart from one stray stamp: :attr:`restart_s`).

        Returns
        -------
        int
            ``NEW`` (first message or a gap), ``SAME`` (continues the segment) or
            ``SKIP`` (time not increasing).
        """
        self.restart_s = 0.0
        last = self.last_ns
        if last is None:
            return NEW
        step = stamp_ns - last
        gap = self.gap_ns
        if step > 0:
            self._back_ns = None
            return NEW if gap and step > gap else SAME
        if gap and -step > gap:
            return NEW
        if -step >= round(CLOCK_RESET_S * 1e9):
            if self._back_ns is not None and self._back_ns < stamp_ns:
                self.restart_s = -step / 1e9
            self._back_ns = stamp_ns
        return NEW if gap and self.restart_s else SKIP

    def accept(self, stamp_ns: int) -> None:
        """Record the stamp of an accepted message."""
        self.last_ns = stamp_ns
        self._back_ns = None
