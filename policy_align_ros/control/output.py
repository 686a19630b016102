"""What one call of the armed controller asks its caller to do (ROS-free).

:class:`Output` is returned by every call of
:class:`~policy_align_ros.control.armed.ArmedController` that may change the command:
the command to publish (or none), why it is zero, and what to log.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from policy_align_ros.control.causes import ZeroCause

__all__ = ["Output"]


@dataclass
class Output:
    """What one call of :class:`ArmedController` asks its caller to do.

    Attributes
    ----------
    command : ndarray, shape (n,), or None
        Command to publish now (rad/s, controller order); None: publish nothing.
    zero_reason : str
        Why the command is zero or going to zero; empty while following the policy.
    ramp_scale : float
        Fraction of the wanted change made in the last step (1: on target).
    events : list of (str, str)
        ``(level, text)`` lines to log, level ``"info"`` or ``"warning"``.
    rejected : str
        Set by :meth:`ArmedController.joint_state` when it refused the state: one of
        :data:`STAMP_REJECTIONS` for its stamp, or :data:`IMPLAUSIBLE_POSITION` (the log
        line has the details).
    extrapolation_scale : float
        The extrapolation guard's scale at the last evaluated step (1: not scaling).
    zero_cause : ZeroCause or None
        ``zero_reason`` as a stable identifier; None while following the policy.
    """

    command: np.ndarray | None
    zero_reason: str
    ramp_scale: float
    events: list[tuple[str, str]] = field(default_factory=list)
    rejected: str = ""
    extrapolation_scale: float = 1.0
    zero_cause: ZeroCause | None = None
