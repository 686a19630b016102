"""Dataset directories: where recorded demonstrations are written (ROS-free).

A dataset directory holds one rosbag2 bag per demonstration (``demo_NNNN``); it is checked
for writing when it is set, not when a demonstration ends, and demonstrations it refuses
at shutdown go to a fallback directory.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["check_dataset_dir", "default_fallback_dirs", "validate_dataset_dir"]


def validate_dataset_dir(dataset_dir: str | os.PathLike[str]) -> Path:
    """Check a dataset directory name without touching the disk (see check_dataset_dir)."""
    text = os.fspath(dataset_dir)
    if not text.strip():
        raise ValueError("dataset_dir: must not be empty")
    path = Path(text).expanduser()
    if path.exists() and not path.is_dir():
        raise ValueError(f"dataset_dir: {path} exists and is not a directory")
    return path


def check_dataset_dir(dataset_dir: str | os.PathLike[str]) -> Path:
    """Check that bags can be written into a dataset directory, creating it if needed.

    The directory is created (with its parents) and a hidden probe file is created and
    removed in it, so that a path under a file, a read-only file system or a directory
    without write permission is reported now rather than when a demonstration ends
    (``os.access`` would not do: it answers yes to root on a read-only mount).

    Returns
    -------
    Path
        The directory, ``~`` expanded.

    Raises
    ------
    ValueError
        ``dataset_dir: <path> ...`` with the operating system's reason.
    """
    path = validate_dataset_dir(dataset_dir)
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".probe-", dir=path)
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        raise ValueError(
            f"dataset_dir: cannot write into {path}: {err.strerror or err}") from None
    return path


def default_fallback_dirs() -> list[Path]:
    """Where the recorder saves at shutdown demonstrations the dataset directory refused.

    (:meth:`~policy_align_ros.data.recording.DemoRecorder.close`.)

    ``$ROS_HOME/policy_align_recorder/unsaved`` (``~/.ros`` when ``ROS_HOME`` is unset),
    then ``<temp dir>/policy_align_recorder-<uid>/unsaved``, in that order; the second one
    is often another file system (tmpfs), which helps when the first disk is full.
    """
    ros_home = Path(os.environ.get("ROS_HOME") or "~/.ros").expanduser()
    uid = os.getuid() if hasattr(os, "getuid") else 0
    return [
        ros_home / "policy_align_recorder" / "unsaved",
        Path(tempfile.gettempdir()) / f"policy_align_recorder-{uid}" / "unsaved",
    ]
