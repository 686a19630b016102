"""The learn pipeline's arguments, checked before any data is read (ROS-free).

:func:`~policy_align_ros.data.pipeline.learn_pipeline`, ``policy-align learn`` and the
``learner`` node share these rules, so that a bad value is refused with the same message,
naming the parameter, wherever it is given: the kernel width rule or value
(:func:`parse_sigma`), the state (:func:`state_name`) and its frames on the robot
(:func:`check_state_frames`), the share held out (:data:`HOLDOUT_RANGE`) and a file to
write (:func:`check_writable`).
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

from policy_align_ros.learning.state_spec import parse_state_spec

__all__ = ["HOLDOUT_RANGE", "SIGMA_RULES", "check_state_frames", "check_writable",
           "parse_sigma", "state_name"]

#: Allowed ``holdout_fraction`` (``--holdout``), shared by the CLI and the learner node:
#: at least half of the distinct demonstrations always train the model.
HOLDOUT_RANGE = (0.0, 0.5)
#: The named kernel-width rules (PolicyAlign's ``sigma``).
SIGMA_RULES = ("narrow", "medium", "wide")


def parse_sigma(text: str | float) -> str | float:
    """``"narrow" | "medium" | "wide"`` or a positive sigma^2 (squared state units).

    Raises
    ------
    ValueError
        For anything else, naming the value.
    """
    if isinstance(text, str) and text.strip().lower() in SIGMA_RULES:
        return text.strip().lower()
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(
            f"sigma: expected narrow, medium, wide or a positive number, got {text!r}"
        ) from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"sigma: sigma^2 must be positive and finite, got {text!r}")
    return value


def state_name(state: str) -> str:
    """Normalised state spec: ``"joints"`` or ``"frames:F1,F2"`` (frames checked).

    Raises
    ------
    ValueError
        For any other text, an empty or a repeated frame.
    """
    frames = parse_state_spec(state)
    return "joints" if frames is None else "frames:" + ",".join(frames)


def check_state_frames(state: str, robot: str | None) -> None:
    """A ``frames:`` state's robot and frames (``state`` as :func:`state_name` gives it),
    before any data is read; nothing for ``"joints"``. Pinocchio is imported only here,
    so that joint states need none.

    Raises
    ------
    ValueError
        Naming ``robot`` when there is none or it does not load, ``state`` for a frame the
        robot does not have (with the closest names).
    """
    frames = parse_state_spec(state)
    if frames is None:
        return
    if not robot:
        raise ValueError("robot: a frames: state needs the robot (example-robot-data name "
                         "or URDF path) whose kinematics give the frame positions")
    from policy_align_ros.kinematics.robot import check_frames

    try:
        check_frames(robot, frames)
    except ValueError as err:
        text = str(err)
        raise ValueError(f"state: {text.removeprefix('frame: ')}" if text.startswith("frame: ")
                         else text) from None


def check_writable(path: str | Path, what: str = "model_path") -> None:
    """Fail before a long fit when the file ``path`` could not be written (``ValueError``
    naming ``what``, the parameter or option that gave it): a directory, under a file, or
    in a directory where no file can be created (no permission, a read-only or virtual
    file system). Missing parent directories are fine: they are created on writing."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{what}: {path} is a directory, expected a file name")
    ancestor = path.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ValueError(f"{what}: {ancestor} is not a directory, cannot write {path}")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise ValueError(f"{what}: no permission to write in {ancestor}")
    try:  # root passes os.access on /sys and /proc: create and remove a file to know
        with tempfile.TemporaryFile(dir=ancestor):
            pass
    except OSError as err:
        raise ValueError(f"{what}: cannot create a file in {ancestor} "
                         f"({err.strerror or err})") from None
