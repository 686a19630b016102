"""What a joint-state stamp far from the node clock most likely means, in words.

A stamp seconds or more away from the node clock is rarely a slow network: it is a node
on the system clock reading stamps of a simulator (seconds since the simulation
started), a node on simulated time reading stamps of the system clock, or two computers
whose clocks are not synchronised. Each rejects every joint state, and the first two are
fixed by a parameter, so the refusal should name it. Between two simulator times, stamps
behind are a restarted simulation, whose stamps start again before this node's clock
follows; stamps ahead, a ``/clock`` that stopped reaching this node.
"""

from __future__ import annotations

__all__ = ["CLOCK_MISMATCH_S", "CLOCK_REJECTIONS", "clock_mismatch_hint"]

#: Stamp-to-clock differences beyond this (s) are a clock mismatch, not a delay.
CLOCK_MISMATCH_S = 10.0
#: Times from this on (ns, the year 2001) are taken for the system clock, earlier ones for
#: a simulator's (seconds since it started).
_SYSTEM_CLOCK_NS = 1_000_000_000 * 10**9
#: Stamp rejections (keys of ``Output.rejected``) that a clock mismatch can explain.
CLOCK_REJECTIONS = ("stamp_too_old", "stamp_in_future", "stamp_backwards")


def clock_mismatch_hint(rejected: str, stamp_ns: int, now_ns: int) -> str:
    """A hint for a joint state rejected as ``rejected`` whose stamp ``stamp_ns`` lies far
    from the node clock ``now_ns`` (both ns).

    Returns
    -------
    str
        Empty unless ``rejected`` is one of :data:`CLOCK_REJECTIONS` and the two differ
        by more than :data:`CLOCK_MISMATCH_S`; otherwise the likely cause, the difference
        (node clock minus stamp) and the parameter to set.
    """
    if rejected not in CLOCK_REJECTIONS:
        return ""
    diff_s = (int(now_ns) - int(stamp_ns)) / 1e9
    if abs(diff_s) <= CLOCK_MISMATCH_S:
        return ""
    if diff_s > 0 and stamp_ns < _SYSTEM_CLOCK_NS <= now_ns:
        return (f"the stamps look like simulator time while this node runs on the system "
                f"clock (node clock - stamp = {diff_s:.1f} s): start it with "
                f"-p use_sim_time:=true (and a /clock publisher)")
    if diff_s < 0 and now_ns < _SYSTEM_CLOCK_NS <= stamp_ns:
        return (f"the stamps look like system time while this node runs on simulator time "
                f"(stamp - node clock = {-diff_s:.1f} s): start it with "
                f"-p use_sim_time:=false, or stamp the joint states with /clock")
    where = f"{abs(diff_s):.1f} s {'behind' if diff_s > 0 else 'ahead of'} the node clock"
    if stamp_ns < _SYSTEM_CLOCK_NS and now_ns < _SYSTEM_CLOCK_NS:
        if diff_s > 0:
            return (f"the stamps are {where}, both simulator time: a restarted simulation? "
                    f"~/enable again once this node's clock has followed it")
        return (f"the stamps are {where}, both simulator time: does /clock reach this node "
                f"(a stalled or missing /clock publisher)?")
    return (f"the stamps are {where}: are the clocks of the two computers synchronised, "
            f"and do both nodes agree on use_sim_time?")
