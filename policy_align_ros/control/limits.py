"""Joint-limit rules of the control law: speed limits, velocity bounds, scale and ramp.

Units: joint positions ``q`` in rad (or m for prismatic joints), velocities in rad/s,
accelerations in rad/s^2, periods ``dt`` in s. One scale factor for a whole command keeps
its direction, hence ``A(q) qdot = 0``; clipping joints one by one would not.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = [
    "DEFAULT_JOINT_LIMIT_MARGIN",
    "DEFAULT_STATE_LIMIT_MARGIN",
    "ROUNDOFF",
    "braking_scale",
    "clearance_scale",
    "goal_in_margin",
    "inner_limits",
    "joint_velocity_bounds",
    "limit_locks",
    "position_outside_limits",
    "ramp_toward",
    "speed_limits",
    "velocity_scale",
]

#: Commands smaller than this (rad/s) are round-off: they are sent as exact zeros.
ROUNDOFF = 1e-12

#: How far (rad) a measured joint position may lie outside its URDF limits and still be
#: believed: encoders, calibration and the braking overshoot of one period put real
#: states a little outside, a wrong joint map or a broken driver far outside.
DEFAULT_STATE_LIMIT_MARGIN = 0.1

#: Default distance (rad) inside the URDF limits at which braking brings joints to rest
#: (MoveIt Servo's ``joint_limit_margins``): room for tracking errors and the
#: controller's own overshoot before the hardware's hard stops.
DEFAULT_JOINT_LIMIT_MARGIN = 0.05


def inner_limits(lower: np.ndarray, upper: np.ndarray, margin: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The limits the control law works on: ``[lower + m, upper - m]``.

    Parameters
    ----------
    lower, upper : ndarray, shape (n,)
        URDF limits (rad or m); infinite entries (continuous joints) stay infinite.
    margin : float
        ``m`` (units of the limits), >= 0. On a joint whose range is narrower than
        ``2 m`` the margin shrinks to a quarter of the range, so ``lower < upper`` stays
        true (a joint with ``lower == upper`` keeps its limits).

    Returns
    -------
    lower, upper : ndarray, shape (n,)
    """
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    with np.errstate(invalid="ignore"):
        span = upper - lower
        m = np.where(np.isfinite(span), np.minimum(float(margin), 0.25 * span), float(margin))
    m = np.maximum(m, 0.0)
    return lower + m, upper - m


def position_outside_limits(
    q: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    margin: float,
    names: list[str],
) -> str:
    """Which measured positions are implausible: outside the limits by more than ``margin``.

    Parameters
    ----------
    q : ndarray, shape (n,)
        Measured joint positions (rad, or m for prismatic joints).
    lower, upper : ndarray, shape (n,)
        Joint limits (URDF); infinite entries (continuous joints) never flag.
    margin : float
        Allowed excursion beyond a limit (same units as ``q``), >= 0.
    names : list of str, length n
        Joint names, for the message.

    Returns
    -------
    str
        Empty when every position is plausible; else a sentence naming the joint furthest
        outside, its value and its limits, and how many joints are outside.
    """
    q = np.asarray(q, dtype=float)
    excess = np.maximum(lower - q, q - upper)
    bad = np.flatnonzero(excess > margin)
    if bad.size == 0:
        return ""
    i = int(bad[np.argmax(excess[bad])])
    text = (f"{names[i]} at {q[i]:.6g} rad, outside its URDF limits "
            f"[{lower[i]:.4g}, {upper[i]:.4g}] by more than state_limit_margin "
            f"{margin:g} rad")
    if bad.size > 1:
        text += f" ({bad.size} joints outside: {', '.join(names[j] for j in bad)})"
    return text


def goal_in_margin(goal: np.ndarray, lower: np.ndarray, upper: np.ndarray, margin: float,
                   names: Sequence[str]) -> str:
    """Which joints of a learnt goal lie within ``margin`` of their limits, or beyond them.

    The control law brakes joints to rest ``margin`` inside their limits
    (:func:`inner_limits`), so a run toward such a goal stops short of it: by up to
    ``margin`` on each of those joints, however well the policy was learnt.

    Parameters
    ----------
    goal : ndarray, shape (n,)
        Joint positions (rad, or m for prismatic joints), in the order of ``names``.
    lower, upper : ndarray, shape (n,)
        URDF limits; infinite entries (continuous joints) never flag.
    margin : float
        The executor's ``joint_limit_margin`` (units of the limits), >= 0.
    names : sequence of str, length n

    Returns
    -------
    str
        Empty when every joint of the goal lies inside; else a sentence naming those that
        do not, with their values and limits, and what to change.
    """
    goal = np.asarray(goal, dtype=float)
    lo, hi = inner_limits(lower, upper, margin)
    bad = np.flatnonzero(~((goal >= lo) & (goal <= hi)))
    if bad.size == 0:
        return ""
    joints = ", ".join(f"{names[i]} at {goal[i]:.4g} (limits [{lower[i]:.4g}, "
                       f"{upper[i]:.4g}])" for i in bad)
    return (f"the learnt goal puts {joints} within joint_limit_margin {margin:g} of a "
            f"limit: runs stop up to {margin:g} short of it there (demonstrate a goal "
            "inside the limits, or lower joint_limit_margin)")


def limit_locks(
    q: np.ndarray,
    v: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    tol: float = 1e-9,
) -> np.ndarray:
    """Joints at (or beyond) a position limit whose velocity points outwards.

    Parameters
    ----------
    q, v : ndarray, shape (n,)
        Positions and candidate velocities.
    lower, upper : ndarray, shape (n,)
        Joint limits.
    tol : float
        Distance to a limit (units of ``q``) counted as touching it.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    return ((q >= upper - tol) & (v > 0.0)) | ((q <= lower + tol) & (v < 0.0))


def _pick(values: np.ndarray | float, index: np.ndarray) -> np.ndarray | float:
    """``values[index]`` for an array, ``values`` itself for a scalar (broadcasts)."""
    return values[index] if getattr(values, "ndim", 0) else values


def speed_limits(urdf_limits: np.ndarray, max_velocity: float) -> np.ndarray:
    """Per-joint speed limits (n,) in rad/s: ``max_velocity`` or the URDF's when lower.

    URDFs often give 0 for "no limit", so non-positive URDF entries are ignored.
    """
    urdf = np.where(urdf_limits > 0.0, urdf_limits, np.inf)
    return np.minimum(urdf, float(max_velocity))


def joint_velocity_bounds(q: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                          max_velocity: np.ndarray | float | None = None,
                          dt: float | None = None, max_acceleration: float | None = None,
                          tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint bounds ``lo <= qdot <= hi`` (rad/s) from position and speed limits.

    A joint at (or beyond) a limit may not move further out (bound 0 on that side).
    With ``dt``, a joint may also not cross a limit within one period
    (``(upper - q) / dt``); with ``max_velocity``, ``|qdot_j| <= max_velocity_j``; with
    ``max_acceleration`` ``a``, a joint heading for a limit at distance ``r`` is held to
    ``min(sqrt(a r), r / (2 dt), a r / V)`` with ``V`` the largest finite
    ``max_velocity``: the rules of :func:`velocity_scale` (:func:`braking_scale`) for a
    command whose fastest joint is at most ``V``, so a command within these bounds is
    not scaled there.

    Parameters
    ----------
    q, lower, upper : numpy.ndarray, shape (n,)
        Joint positions and limits (rad or m; infinite limits allowed).
    max_velocity : float or numpy.ndarray (n,), optional
        Speed limits (> 0, may be inf), rad/s.
    dt : float, optional
        Period, s.
    max_acceleration : float, optional
        rad/s^2.
    tol : float
        Distance to a limit (units of ``q``) counted as touching it.

    Returns
    -------
    lo, hi : numpy.ndarray, shape (n,)
        ``lo <= 0 <= hi``, rad/s.
    """
    n = q.shape[0]
    vmax = (None if max_velocity is None
            else np.broadcast_to(np.asarray(max_velocity, dtype=float), (n,)))
    hi = np.where(q >= upper - tol, 0.0, np.inf)
    lo = np.where(q <= lower + tol, 0.0, -np.inf)
    if dt is not None:
        with np.errstate(invalid="ignore"):
            hi = np.minimum(hi, np.maximum(upper - q, 0.0) / dt)
            lo = np.maximum(lo, -np.maximum(q - lower, 0.0) / dt)
    if max_acceleration is not None:
        with np.errstate(invalid="ignore"):
            up, down = np.maximum(upper - q, 0.0), np.maximum(q - lower, 0.0)
            hi = np.minimum(hi, np.sqrt(max_acceleration * up))
            lo = np.maximum(lo, -np.sqrt(max_acceleration * down))
            if dt is not None:
                hi = np.minimum(hi, up / (2.0 * dt))
                lo = np.maximum(lo, -down / (2.0 * dt))
            peak = np.inf if vmax is None else float(vmax.max())
            if np.isfinite(peak):
                # s = 1 in braking_scale for any command whose fastest joint is <= peak.
                hi = np.minimum(hi, max_acceleration * up / peak)
                lo = np.maximum(lo, -max_acceleration * down / peak)
    if vmax is not None:
        hi = np.minimum(hi, vmax)
        lo = np.maximum(lo, -vmax)
    return lo, hi


def velocity_scale(
    q: np.ndarray,
    v: np.ndarray,
    dt: float,
    lower: np.ndarray,
    upper: np.ndarray,
    max_velocity: np.ndarray,
    max_acceleration: float | None = None,
) -> float:
    """Largest ``s in [0, 1]`` such that ``s v`` respects speed and position limits.

    Parameters
    ----------
    q, v : ndarray, shape (n,)
        Positions and the velocity direction (units of ``q`` per second).
    dt : float
        Period (s) over which ``q + s v dt`` must stay within ``[lower, upper]``.
    lower, upper : ndarray, shape (n,)
        Joint limits.
    max_velocity : ndarray, shape (n,)
        Per-joint speed limits (> 0, may be inf).
    max_acceleration : float, optional
        Units of ``q`` per s^2. When given, joints heading for a limit are also slowed in
        time for the acceleration ramp to bring them to rest there
        (:func:`braking_scale`).

    Returns
    -------
    float
        The scale; 0 when a joint at a limit is pushed outwards.
    """
    # Only moving joints bound the scale; indexing them first keeps this cheap (it runs
    # twice per control step).
    moving = np.flatnonzero(v)
    if moving.size == 0:
        return 1.0
    vm = v[moving]
    speed = np.abs(vm)
    qm = q[moving]
    room = np.where(vm > 0.0, _pick(upper, moving) - qm, qm - _pick(lower, moving))
    np.maximum(room, 0.0, out=room)
    bound = np.minimum(_pick(max_velocity, moving), room / dt)
    s = float((bound / speed).min())
    if max_acceleration is not None:
        s = min(s, braking_scale(room, speed, dt, max_acceleration, float(speed.max())))
    return 1.0 if s >= 1.0 else max(s, 0.0)


def braking_scale(room: np.ndarray, rate: np.ndarray, dt: float, max_acceleration: float,
                  peak: float) -> float:
    """Largest scale ``s`` of a command that a uniform ramp can brake within ``room``.

    The acceleration ramp (:func:`ramp_toward`) changes the whole command by one factor,
    so while the fastest joint (``peak``) slows down at ``a = max_acceleration`` an
    approach at ``rate`` slows down at ``a rate / peak`` only. Per approach ``i`` the
    scaled rate ``s rate_i`` is held to ``sqrt(a_i room_i)`` with ``a_i = a rate_i /
    peak`` (braking at half that deceleration stops it within ``room_i``; the other half
    is left to the ramp, which lags a falling target) and to ``room_i / (2 dt)`` (at most
    half the room is covered in one period, so the approach ends at rest instead of at
    the full speed of its last period: locking a joint, or a barrier becoming active,
    then forces no change). Both bounds are viable: from a rate within them, slowing by
    ``a_i dt`` per period stays within them.

    Parameters
    ----------
    room : ndarray, shape (k,)
        Distances to the limits approached (rad, or joint-space rad for a barrier), >= 0.
    rate : ndarray, shape (k,)
        Approach speeds of the unscaled command (rad/s), > 0.
    dt : float
        Period (s).
    max_acceleration : float
        rad/s^2.
    peak : float
        Largest joint speed of the unscaled command (rad/s), ``>= rate``.

    Returns
    -------
    float
        The scale (>= 0; may exceed 1; inf when ``k == 0``).
    """
    if room.size == 0:
        return np.inf
    s = np.minimum(room / (2.0 * dt * rate), np.sqrt(max_acceleration * room / (rate * peak)))
    return float(s.min())


def clearance_scale(q: np.ndarray, v: np.ndarray, barriers: Sequence, dt: float,
                    max_acceleration: float) -> float:
    """Scale that brakes ``v`` (n,) in time for every barrier that it approaches.

    A barrier blocks motion towards it from its activation distance on; reaching that
    shell at speed would make the projection stop the approach within one period. So
    each barrier's clearance ``c`` (m beyond the shell, gradient ``g`` in m/rad, from its
    ``clearance(q)``) is treated like a joint limit's room: the approach ``-g.v / |g|``
    (rad/s along ``g``) over the room ``c / |g|`` (rad, to first order) enters
    :func:`braking_scale`.

    Parameters
    ----------
    q, v : ndarray, shape (n,)
        Positions (rad) and the unscaled command (rad/s).
    barriers : sequence
        Objects with ``clearance(q) -> (c, g)`` (``g`` None: no barrier there), inactive.
    dt, max_acceleration : float
        Period (s) and rad/s^2.

    Returns
    -------
    float
        The scale (>= 0; inf when no barrier is approached).
    """
    rooms, rates = [], []
    for barrier in barriers:
        c, g = barrier.clearance(q)
        if g is None:
            continue
        size = float(np.linalg.norm(g))
        rate = -float(g @ v)
        if size > 0.0 and rate > 0.0:
            rooms.append(max(c, 0.0) / size)
            rates.append(rate / size)
    if not rooms:
        return np.inf
    return braking_scale(np.array(rooms), np.array(rates), dt, max_acceleration,
                         float(np.abs(v).max()))


def ramp_toward(
    previous: np.ndarray,
    target: np.ndarray,
    projector: np.ndarray,
    max_delta: float,
) -> tuple[np.ndarray, float, np.ndarray]:
    """One acceleration-limited step from ``previous`` towards ``target``.

    Ramp first, then project: ``c = P (previous + alpha (target - previous)) + (I - P)
    target`` with the largest ``alpha in [0, 1]`` that keeps every ``|c_i - previous_i|
    <= max_delta``. One ``alpha`` for all joints keeps the step's direction, so ``c``
    satisfies the constraints whenever ``P`` projects onto their null space and ``P
    target = target`` (``target`` from
    :func:`~policy_align_ros.control.locked_projection.project_with_locks` with the same
    ``P``, or zero). A target with a part outside that null space (a drift correction, which moves
    a held frame on purpose) gets that part at once when it fits within ``max_delta``:
    ``A c = A target`` at every ``alpha``, so the held frame moves as the correction says
    while the rest ramps.

    The projection itself may force a change: ``F = P previous + (I - P) target -
    previous`` is the part of the previous command that the current constraints forbid
    (a constraint that has just become active, or changed) plus the correction. When
    ``F`` exceeds ``max_delta`` on some joint, the acceleration limit wins: the step is
    ``previous + F max_delta / max|F|`` (``alpha`` 0), a *blend* that meets the
    constraints only after ``max|F| / max_delta`` such steps. Braking keeps ``F`` of
    barriers and joint locks near zero (:func:`braking_scale`), so blends follow
    constraints added or changed at run time, or a barrier's box entered sideways.

    Parameters
    ----------
    previous, target : ndarray, shape (n,)
        Last command sent and the wanted command (rad/s).
    projector : ndarray, shape (n, n)
        ``P``, the null-space projector of the constraints in force now.
    max_delta : float
        Largest change per joint in this step (rad/s): ``max_acceleration * dt``.

    Returns
    -------
    command : ndarray, shape (n,)
        ``c`` (rad/s); exactly ``target`` when ``alpha`` is 1.
    alpha : float
        The ramp scale: the fraction of the wanted change made in this step (1 = on
        target, < 1 = acceleration-limited, 0 during a blend).
    forced : ndarray, shape (n,)
        ``F`` (rad/s).
    """
    base = projector @ previous
    outside = target - projector @ target
    if np.any(np.abs(outside) > ROUNDOFF):
        base = base + outside
    forced = base - previous
    largest = float(np.abs(forced).max(initial=0.0))
    if largest > max_delta:
        # Blend: move towards the constrained command by max_delta on the joint that
        # changes most. Each such step shrinks the forced part by max_delta, so it ends
        # within largest / max_delta periods, during which A c = 0 holds only in part.
        return previous + forced * (max_delta / largest), 0.0, forced
    d = target - base
    # Per joint, the largest alpha with |forced_i + alpha d_i| <= max_delta; |forced_i|
    # <= max_delta, so alpha = 0 is always allowed and the minimum is >= 0.
    size = np.abs(d)
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(size > 0.0, (max_delta - np.sign(d) * forced) / size, np.inf)
    alpha = float(np.clip(np.min(room, initial=np.inf), 0.0, 1.0))
    if alpha == 1.0:
        return target.copy(), 1.0, forced
    return base + alpha * d, alpha, forced
