"""One finished demonstration of the recorder, and the outcome of writing it (ROS-free).

:class:`FinishedDemo` holds what :class:`~policy_align_ros.data.recording.DemoRecorder`
buffered for one demonstration, as arrays that own their data, and writes it as one
rosbag2 bag; :class:`SaveResult` is what a save at shutdown gives back, and
:class:`PendingWriteError` the error of a write that failed with the demonstration kept in
memory. Kept apart from the recorder's state machine so that each stays readable.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from policy_align_ros.data.bags.write import next_demo_path, write_joint_state_bag

__all__ = ["STILL_TOLERANCE", "FinishedDemo", "PendingWriteError", "SaveResult",
           "error_text"]

#: A demonstration whose every joint stays this close to its first sample (rad or m) is
#: one of a robot that did not move: a few counts of a 14-bit encoder (3.8e-4 rad each),
#: far below any motion worth learning from (1 mrad is 1 mm at 1 m).
STILL_TOLERANCE = 1e-3


class PendingWriteError(OSError):
    """A demonstration could not be written and is kept in memory (the message says why)."""


def error_text(err: BaseException) -> str:
    """One line saying why a write failed; the type is named when the error is unexpected.

    ``OSError`` and ``ValueError`` messages name the path and the reason already; a bare
    ``OverflowError`` message (say "int too big to convert") would be meaningless alone.
    """
    text = str(err)
    if isinstance(err, (OSError, ValueError)):
        return text or type(err).__name__
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


@dataclass(frozen=True)
class FinishedDemo:
    """One finished demonstration, ready for write_joint_state_bag (arrays own their data)."""

    joints: list[str]
    stamps: np.ndarray  # (N,) int64 ns
    positions: np.ndarray  # (N, n)
    velocities: np.ndarray | None  # (N, n) or None
    has_velocity: np.ndarray | None  # (N,) bool or None
    topic: str

    def __len__(self) -> int:
        return int(self.stamps.shape[0])

    def still(self, tolerance: float) -> bool:
        """Whether every joint stays within ``tolerance`` of its first sample."""
        return bool(np.all(np.abs(self.positions - self.positions[0]) <= tolerance))

    def write(self, dataset_dir: Path) -> Path:
        """Write it as the next ``demo_NNNN`` bag of ``dataset_dir``; the bag's path."""
        return write_joint_state_bag(
            next_demo_path(dataset_dir), self.joints, self.stamps, self.positions,
            self.velocities, has_velocity=self.has_velocity, topic=self.topic, unique=True)


@dataclass(frozen=True)
class SaveResult:
    """Outcome of saving one demonstration in :meth:`DemoRecorder.close`.

    Attributes
    ----------
    messages : int
        Messages in the demonstration.
    path : Path or None
        The bag written, or ``None`` if every directory failed (the demonstration is lost).
    fallback : bool
        Whether ``path`` is in a fallback directory rather than the dataset directory.
    errors : tuple of str
        One line per directory that failed, in the order tried.
    """

    messages: int
    path: Path | None
    fallback: bool
    errors: tuple[str, ...]
