"""What a model's state is: the text form used on the command line and in parameters.

``joints`` means the state is the joint positions (rad); ``frames:F1,F2`` means the stacked
positions (m) of the named frames, computed from joint positions with Pinocchio
(:mod:`policy_align_ros.kinematics.task_space`). Parsing the text needs no Pinocchio, so
it lives here, where the learning pipeline (``data/``) and the kinematics both reach it.
"""

from __future__ import annotations

__all__ = ["parse_state_spec"]


def parse_state_spec(spec: str) -> list[str] | None:
    """Parse a command-line state spec: ``joints`` -> None, ``frames:F1,F2`` -> frames.

    Raises
    ------
    ValueError
        For any other text or an empty / repeated frame list.
    """
    text = str(spec).strip()
    if text == "joints":
        return None
    if not text.startswith("frames:"):
        raise ValueError(f"state: expected 'joints' or 'frames:F1,F2,...', got {spec!r}")
    frames = [f.strip() for f in text[len("frames:"):].split(",")]
    if not frames or any(not f for f in frames):
        raise ValueError(f"state: empty frame name in {spec!r}")
    if len(set(frames)) != len(frames):
        raise ValueError(f"state: a frame is listed twice in {spec!r}")
    return frames
