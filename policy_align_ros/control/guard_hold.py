"""The extrapolation guard holding an armed robot at the data's edge, reported, ROS-free.

The guard is a soft boundary (:mod:`policy_align_ros.control.guard`): a command leading
further out of the demonstrated data is scaled to zero at ``max_extrapolation`` spacings
(plus a band) or ``max_extrapolation_rad`` rad from it, while the controller stays armed,
so that motion back in resumes by itself. Its control law is not changed here. But a
robot held there for good looks healthy on every output (armed, no zero cause, level
OK) although it will not move again: a UR10 under a constraint never demonstrated moved
for 1.2 s and then stood still for 15 s with ``extrapolation_distance`` 1.40 spacings,
far below ``max_extrapolation`` 6, because ``max_extrapolation_rad`` bound, which no
output named. So:

* :func:`guard_hold` says, from the controller's last step, whether the guard holds the
  command at (near) zero, which of the two limits binds there, the distance in that
  limit's units and the fix; the executor's ``/diagnostics`` then gives the cause
  :data:`~policy_align_ros.control.causes.ZeroCause.EXTRAPOLATION_HOLD` and that reason
  (:func:`~policy_align_ros.control.status.arming_status`);
* :class:`GuardHoldLog` gives the log line once when a hold begins, not every cycle.

A hold and a stall never describe the same moment: a held command is below the stall
detector's smallest counted speed (:data:`~policy_align_ros.control.stall.
STALL_MIN_SPEED`), so a robot standing still at the edge is not taken for a blocked one,
and a hold is reported only while armed, so a stall's disarm is reported alone.
"""

from __future__ import annotations

from dataclasses import dataclass

from policy_align_ros.control.armed import ArmedController

__all__ = ["HOLD_LOG_INTERVAL_NS", "HOLD_SCALE", "GuardHold", "GuardHoldLog", "guard_hold"]

#: The guard's scale at or below which it holds the command: 1 % of the policy's speed
#: (at most 0.005 rad/s under the default 0.5 rad/s limit), the robot does not move.
HOLD_SCALE = 0.01
#: Shortest time between two log lines of a hold beginning (ns of the caller's clock):
#: noise at the edge may end and begin a hold many times a second.
HOLD_LOG_INTERVAL_NS = 10_000_000_000


@dataclass(frozen=True)
class GuardHold:
    """The extrapolation guard holding the command at zero.

    Attributes
    ----------
    limit : str
        The parameter whose edge holds the robot: ``"max_extrapolation"`` (spacings) or
        ``"max_extrapolation_rad"`` (rad).
    distance : float
        The distance to the nearest training state in that parameter's unit.
    value : float
        The parameter's value.
    edge : float
        Where the guard scales a command leading out to zero, in that unit (the value plus
        the band, or the stopping distance when longer).
    distance_spacings, distance_rad : float
        The distance in both units (spacings of the training data; rad, joint-space
        2-norm, to first order for a model learnt on frame positions).
    text : str
        All that in words, with the fix (the ``zero_reason`` on ``/diagnostics``).
    """

    limit: str
    distance: float
    value: float
    edge: float
    distance_spacings: float
    distance_rad: float
    text: str


def guard_hold(controller: ArmedController) -> GuardHold | None:
    """The hold of ``controller``'s extrapolation guard at its last step: armed, with a
    guard whose scale was at most :data:`HOLD_SCALE`; None otherwise."""
    step = controller.step
    guard = step.guard
    if (not controller.armed or guard is None
            or not controller.extrapolation_scale <= HOLD_SCALE):
        return None
    d, rad, norm = guard.last_distance, guard.last_distance_rad, guard.last_grad_norm
    if not norm > 0.0:  # the scale is 1 where d has no direction: no hold to describe
        return None
    edge, limit = guard.edge(norm, step.max_velocity, step.max_acceleration)
    if limit == "max_extrapolation_rad":
        distance, value, edge = rad, guard.max_extrapolation_rad, edge / norm
        where = (f"{rad:.2f} rad from the nearest training state (max_extrapolation_rad "
                 f"{value:g} rad, edge {edge:.2f} rad; {d:.2f} spacings, within "
                 f"max_extrapolation {guard.max_extrapolation:g})")
    else:
        distance, value = d, guard.max_extrapolation
        where = (f"{d:.2f} spacings of the training data from the nearest training state "
                 f"(max_extrapolation {value:g}, edge {edge:.2f} spacings; {rad:.2f} rad)")
    text = (f"held at the edge of the demonstrated data by the extrapolation guard: {where}; "
            f"the policy leads further out, so the command stays zero (still armed: motion "
            f"back in resumes). To go on, raise {limit} or record demonstrations through "
            f"this region")
    return GuardHold(limit, distance, value, edge, d, rad, text)


class GuardHoldLog:
    """The log line of a guard hold, once when it begins.

    Call :meth:`update` after every step; it returns the line when a hold begins, at most
    once per ``interval_ns`` of the caller's clock, and nothing while it lasts.

    Parameters
    ----------
    interval_ns : int
        Shortest time between two lines (ns).
    """

    def __init__(self, interval_ns: int = HOLD_LOG_INTERVAL_NS) -> None:
        self.interval_ns = int(interval_ns)
        self.holding = False
        self._logged_ns: int | None = None

    def update(self, controller: ArmedController, now_ns: int) -> list[tuple[str, str]]:
        """``[("warning", text)]`` when the guard of ``controller`` has just begun holding
        at ``now_ns`` (ns) and no line went out in the last ``interval_ns``; else ``[]``."""
        hold = guard_hold(controller)
        began = hold is not None and not self.holding
        self.holding = hold is not None
        if not began:
            return []
        if self._logged_ns is not None and now_ns - self._logged_ns < self.interval_ns:
            return []
        self._logged_ns = int(now_ns)
        return [("warning", hold.text)]
