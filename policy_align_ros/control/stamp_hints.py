"""What a joint-state stamp far from the node clock most likely means, in words.

A stamp seconds or more away from the node clock is rarely a slow network: it is a node
on the system clock reading stamps of a simulator (seconds since the simulation
started), or a node on simulated time reading stamps of the system clock. Both reject
every joint state, and the fix is a parameter, so the refusal should name it.
"""

from __future__ import annotations

__all__ = ["CLOCK_MISMATCH_S", "CLOCK_REJECTIONS", "clock_mismatch_hint"]

#: Stamp-to-clock differences beyond this (s) are a clock mismatch, not a delay.
CLOCK_MISMATCH_S = 10.0
#: Stamp rejections (keys of ``Output.rejected``) that a clock mismatch can explain.
CLOCK_REJECTIONS = ("stamp_too_old", "stamp_in_future")


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
    if diff_s > 0:
        return (f"the stamps look like simulator time while this node runs on the system "
                f"clock (node clock - stamp = {diff_s:.1f} s): start it with "
                f"-p use_sim_time:=true (and a /clock publisher)")
    return (f"the stamps lie {-diff_s:.1f} s ahead of the node clock: the node looks like it "
            f"runs on simulator time (use_sim_time) while the stamps are system time; "
            f"use -p use_sim_time:=false, or stamp the joint states with /clock")
