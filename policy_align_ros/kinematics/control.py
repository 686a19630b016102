"""The executor's control law, ROS-free: ``qdot = s * N(q) pi_hat(q)``.

Notation and units: ``q`` joint positions (rad), ``pi_hat(q)`` the learnt unconstrained
policy (rad/s), ``A(q)`` the stacked constraint matrix (k, n) of the configured constraints,
``N = I - pinv(A) A`` its null-space projector, ``dt`` the control period (s).

Two safety rules shape the command:

* a joint sitting on a position limit and pushed outwards is *locked*, i.e. a unit row is
  appended to ``A`` and the policy is projected again, so the remaining joints still follow
  the policy within the constraints instead of the whole robot stalling;
* the projected velocity is scaled by one factor ``s in [0, 1]`` so that no joint exceeds
  its maximum speed and no joint crosses a limit within one period. One factor for the
  whole vector keeps the direction, hence ``A(q) qdot = 0``; clipping joints one by one
  would not.

Anything that prevents a safe command (non-finite state, no policy, a policy returning
non-finite values) gives zeros and a reason.

:class:`ArmedController` wraps a :class:`ControlStep` with what makes it safe to leave
running next to a real robot, all on time stamps passed in (integer nanoseconds of the
caller's clock, a ROS node clock in the executor), so it runs and is tested without a
graph and honours simulated time:

* *arming*: commands follow the policy only between :meth:`ArmedController.arm` (refused
  without a model or with stale joint states) and the next disarm, which a disable, a
  model swap or any fault causes; nothing re-arms on its own;
* *acceleration ramp*: each joint's command changes by at most ``max_acceleration * dt``
  per step (:func:`ramp_toward`: ramp first, then project onto the constraints' null
  space). A disarm ramps the command down to zero the same way; only untrustworthy or
  lost joint states (and a clock jumping backwards) stop it at once, because without a
  trusted ``q`` there is no safe command to ramp through;
* *staleness*: joint states count as fresh by their arrival time and by their header
  stamp; zero stamps, stamps too old or too far in the future, and stamps going backwards
  are untrustworthy.

Two more rules act inside :meth:`ControlStep.evaluate`, hence before the ramp:

* *extrapolation guard* (:class:`ExtrapolationGuard`): with ``d(q)`` the distance of the
  state to the demonstrated data in spacings of the training data, ``d_max`` the
  parameter ``max_extrapolation`` and ``b`` the band, a command that leads further out
  (``grad d . qdot > 0``) is scaled by ``g = clip(1 - (d - d_max) / b, 0, 1)``; motion
  back in is never scaled. ``b`` is at least the stopping distance at ``max_velocity``
  and ``max_acceleration`` (in spacings), so a joint ramping down from full speed at
  ``d_max`` stops inside the band;
* *drift correction*: position-type constraints (``hold`` a frame) latch the frame's
  position ``p_ref`` when the controller arms, and the command gets
  ``qdot_c = B^T (B B^T + l^2 I)^{-1} (-k clamp(p - p_ref))`` with ``B = A_h N_o`` (the
  held rows ``A_h`` on the null space ``N_o`` of the other constraints and locked
  joints, so the correction respects them), gain ``k`` (1/s), the error clamped to
  ``drift_clamp_m`` in norm and damping ``l`` (m/rad). Euler integration of commands with
  ``A qdot = 0`` drifts at second order; this pulls the frame back. A constraint matrix
  whose smallest singular value falls below ``min_singular_value`` (m/rad for frame rows)
  cannot be trusted: the step returns zero with the reason and the controller ramps down.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from policy_align_ros.kinematics.projection import nullspace_projector, projector_from_svd

__all__ = [
    "DEFAULT_DRIFT_CLAMP_M",
    "DEFAULT_DRIFT_GAIN",
    "DEFAULT_MAX_EXTRAPOLATION",
    "DEFAULT_MIN_SINGULAR_VALUE",
    "ArmedController",
    "ControlStep",
    "DistanceFn",
    "ExtrapolationGuard",
    "Output",
    "SupportDistance",
    "STAMP_REJECTIONS",
    "constrained_command",
    "joint_velocity_bounds",
    "limit_locks",
    "model_permutation",
    "project_with_locks",
    "ramp_toward",
    "speed_limits",
    "velocity_scale",
]

PolicyFn = Callable[[np.ndarray], np.ndarray]

#: ``distance(q (n,)) -> (d, grad)``: see :class:`ExtrapolationGuard`.
DistanceFn = Callable[[np.ndarray], tuple[float, "np.ndarray | None"]]

#: Default ``max_extrapolation`` (spacings). Measured with quadratic-potential
#: demonstrations on the executor's 18 Talos joints (K = 3 ... 100 demonstrations of 100
#: samples, starts ~ N(q_0, 0.1 I), free or with random hand planes, 3 seeds x 200 new
#: runs each): the farthest state of a run from new starts of the same distribution lay
#: at most 5.1 spacings from the support (p99 4.8, K = 3); 6 leaves such runs unscaled.
DEFAULT_MAX_EXTRAPOLATION = 6.0
#: Smallest band of the guard (spacings), whatever the stopping distance.
MIN_BAND = 1.0
#: Default drift-correction gain ``k`` (1/s): a held frame's error decays as exp(-k t).
DEFAULT_DRIFT_GAIN = 5.0
#: Default clamp of the held frame's error in the correction (m): at most ``k`` times
#: this (m/s) of correcting motion, so a large error (a frame pushed away) is not
#: corrected with a jump.
DEFAULT_DRIFT_CLAMP_M = 0.01
#: Damping ``l`` of the correction's pseudo-inverse (m/rad): bounds the joint speed per
#: m/s of correction by ``1 / (2 l)`` near singular configurations.
HOLD_DAMPING = 0.01
#: Default smallest singular value of the constraint matrix (m/rad for frame rows)
#: below which the executor stops. Over 2000 random Talos postures (std 0.5 rad about
#: neutral, 18 joints) a held hand plus a plane on the other hand had at least 0.008.
DEFAULT_MIN_SINGULAR_VALUE = 0.005


class SupportDistance:
    """``d(q)`` and its gradient for a model learnt on joint positions (the guard's input).

    Parameters
    ----------
    model : PolicyAlign
        Fitted or loaded, with support states (its ``support_query``).
    permutation : array_like of int, shape (n,), optional
        From :func:`model_permutation`: ``q[permutation]`` is ``q`` in model order.

    Notes
    -----
    With ``x = q[permutation]``, ``s`` the nearest support state and ``h`` the spacing
    (``model.support_spacing_``), ``d = |x - s| / h`` and ``grad d = (x - s) / (|x - s|
    h)`` mapped back to controller order; ``|grad d| = 1 / h``.
    """

    def __init__(self, model, permutation: np.ndarray | None = None) -> None:
        spacing = float(getattr(model, "support_spacing_", float("nan")))
        if not (math.isfinite(spacing) and spacing > 0.0):
            raise ValueError("model: has no support states (support_spacing_ missing)")
        self.model = model
        self.spacing = spacing
        n = int(model.n_features_in_)
        self.permutation = (np.arange(n) if permutation is None
                            else np.asarray(permutation, dtype=int))

    def __call__(self, q: np.ndarray) -> tuple[float, np.ndarray | None]:
        """``(d, grad)`` at ``q`` (n,) in controller order (spacings, spacings per rad)."""
        p = self.permutation
        x = np.asarray(q, dtype=float)[p]
        d, nearest = self.model.support_query(x[None, :])
        diff = x - nearest[0]
        r = float(np.linalg.norm(diff))
        if r == 0.0:
            return 0.0, None
        grad = np.empty_like(x)
        grad[p] = diff / (r * self.spacing)
        return float(d[0]), grad


class ExtrapolationGuard:
    """Scales down commands that lead away from the demonstrated data.

    Parameters
    ----------
    distance : callable ``distance(q) -> (d, grad)``
        The contract: ``q`` (n,) joint positions in controller order (rad); ``d`` (float,
        >= 0) the distance of the model's state at ``q`` to the demonstrated data in
        spacings of the training data (``PolicyAlign.support_query``, which measures in
        ``support_spacing_``); ``grad`` (n,) the gradient of ``d`` with respect to ``q``
        in controller order (spacings per rad), or None where ``d`` has no direction
        (on a support state). For a joint-space model use :class:`SupportDistance`; for
        a task-space state ``x = phi(q)`` with Jacobian ``J`` (m, n) and nearest support
        state ``s``, ``grad = J^T (x - s) / (|x - s| h)``. It may raise ValueError (the
        step then gives zero with the reason).
    max_extrapolation : float
        ``d_max`` (spacings, > 0): the scale is 1 up to it.
    min_band : float
        Smallest band (spacings, > 0).

    Notes
    -----
    The scale is ``g = clip(1 - (d - d_max) / b, 0, 1)`` for a command ``v`` with
    ``grad . v > 0``, else 1, and ``g v`` is sent: one factor for the whole command
    keeps its direction, so ``A v = 0`` still holds. The band is
    ``b = max(min_band, |grad| |v_max| max(v_max) / (2 a))``: a command of at most
    ``v_max`` per joint (2-norm ``|v_max|``) braked by a ramp at ``a`` per joint stops
    within ``max(v_max) / a`` s, over at most ``|v_max| max(v_max) / (2 a)`` rad, which
    moves ``d`` by at most ``|grad|`` times that: the stopping distance at
    ``max_velocity`` in spacings. With no acceleration limit ``b = min_band``.
    """

    def __init__(self, distance: DistanceFn, max_extrapolation: float = DEFAULT_MAX_EXTRAPOLATION,
                 min_band: float = MIN_BAND) -> None:
        self.distance = distance
        self.max_extrapolation = max_extrapolation
        if not (math.isfinite(min_band) and min_band > 0.0):
            raise ValueError(f"min_band: must be finite and > 0, got {min_band}")
        self.min_band = float(min_band)

    @property
    def max_extrapolation(self) -> float:
        """``d_max`` in spacings."""
        return self._max

    @max_extrapolation.setter
    def max_extrapolation(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"max_extrapolation: must be finite and > 0, got {value}")
        self._max = value

    def band(self, grad_norm: float, max_velocity: np.ndarray,
             max_acceleration: float | None) -> float:
        """Band ``b`` (spacings) for ``|grad d| = grad_norm`` (spacings per rad).

        Raises ValueError when the stopping distance is not finite (an infinite
        ``max_velocity``).
        """
        if max_acceleration is None or not grad_norm > 0.0:
            return self.min_band
        vmax = np.asarray(max_velocity, dtype=float)
        stop = grad_norm * float(np.linalg.norm(vmax)) * float(vmax.max()) / (
            2.0 * max_acceleration)
        if not math.isfinite(stop):
            # No finite stopping distance (a joint without speed limit): no safe band.
            raise ValueError("band needs finite max_velocity and gradient")
        return max(self.min_band, stop)

    def scale(self, q: np.ndarray, v: np.ndarray, max_velocity: np.ndarray,
              max_acceleration: float | None) -> tuple[float, float]:
        """Scale ``g`` in [0, 1] for command ``v`` (n,) at ``q`` (n,), and ``d``.

        Raises
        ------
        ValueError
            When the distance is not finite or its gradient has the wrong shape.
        """
        d, grad = self.distance(q)
        d = float(d)
        if not (math.isfinite(d) and d >= 0.0):
            raise ValueError(f"extrapolation distance not finite ({d})")
        if d <= self._max or grad is None:
            return 1.0, d
        grad = np.asarray(grad, dtype=float)
        if grad.shape != np.shape(v) or not np.all(np.isfinite(grad)):
            raise ValueError("extrapolation distance gradient not finite or of wrong shape")
        if float(grad @ v) <= 0.0:
            return 1.0, d  # back towards the data, or along it: never scaled
        b = self.band(float(np.linalg.norm(grad)), max_velocity, max_acceleration)
        return float(np.clip(1.0 - (d - self._max) / b, 0.0, 1.0)), d


class ConstraintModel(Protocol):
    """Anything giving ``A(q)`` of shape (k, n), k >= 0, given an intended ``qdot``."""

    def matrix(self, q: np.ndarray, qdot: np.ndarray | None = None) -> np.ndarray: ...


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
    ``max_acceleration``, a joint heading for a limit at distance ``r`` is held to
    ``sqrt(max_acceleration r)`` (the rules of :func:`velocity_scale`, below, for every
    joint and both directions, so a command within these bounds is not scaled there).

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
    hi = np.where(q >= upper - tol, 0.0, np.inf)
    lo = np.where(q <= lower + tol, 0.0, -np.inf)
    if dt is not None:
        with np.errstate(invalid="ignore"):
            hi = np.minimum(hi, np.maximum(upper - q, 0.0) / dt)
            lo = np.maximum(lo, -np.maximum(q - lower, 0.0) / dt)
    if max_acceleration is not None:
        with np.errstate(invalid="ignore"):
            hi = np.minimum(hi, np.sqrt(max_acceleration * np.maximum(upper - q, 0.0)))
            lo = np.maximum(lo, -np.sqrt(max_acceleration * np.maximum(q - lower, 0.0)))
    if max_velocity is not None:
        vmax = np.broadcast_to(np.asarray(max_velocity, dtype=float), (n,))
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
        Units of ``q`` per s^2. When given, a joint heading for a limit at distance ``r``
        is also held to ``sqrt(max_acceleration * r)``, the speed from which braking at
        half that deceleration stops it at the limit: the other half is left to the
        acceleration ramp, which lags a falling target.

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
    if max_acceleration is not None:
        np.minimum(bound, np.sqrt(max_acceleration * room), out=bound)
    s = float((bound / speed).min())
    return 1.0 if s >= 1.0 else max(s, 0.0)


def constrained_command(
    q: np.ndarray,
    pi: np.ndarray,
    A: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    max_velocity: np.ndarray,
    dt: float,
    max_acceleration: float | None = None,
) -> np.ndarray:
    """Project ``pi`` onto the constraints' null space, lock limit joints, then scale.

    Parameters
    ----------
    q : ndarray, shape (n,)
        Current joint positions.
    pi : ndarray, shape (n,)
        Unconstrained policy at ``q`` (units of ``q`` per second).
    A : ndarray, shape (k, n)
        Constraint matrix at ``q`` (k >= 0).
    lower, upper, max_velocity : ndarray, shape (n,)
        Joint limits and speed limits.
    dt : float
        Control period (s).
    max_acceleration : float, optional
        Braking limit near joint limits (see :func:`velocity_scale`).

    Returns
    -------
    ndarray, shape (n,)
        ``s N' pi`` with ``N'`` the projector of ``A`` stacked with unit rows of the locked
        joints, so ``A qdot = 0`` up to round-off, no speed limit is exceeded and no joint
        crosses a limit within ``dt``.
    """
    v, _ = project_with_locks(q, pi, A, lower, upper)
    return velocity_scale(q, v, dt, lower, upper, max_velocity, max_acceleration) * v


def project_with_locks(
    q: np.ndarray,
    pi: np.ndarray,
    A: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    projector: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``N' pi`` and ``N'``: the projector of ``A`` plus unit rows of the locked joints.

    Parameters
    ----------
    q, pi : ndarray, shape (n,)
        Positions and the velocity to project (units of ``q`` per second).
    A : ndarray, shape (k, n)
        Constraint matrix at ``q`` (k >= 0).
    lower, upper : ndarray, shape (n,)
        Joint limits.
    projector : ndarray, shape (n, n), optional
        ``nullspace_projector(A)`` when the caller has it already (saves an SVD).

    Returns
    -------
    v : ndarray, shape (n,)
        The projected velocity, exactly 0 on locked joints.
    projector : ndarray, shape (n, n)
        ``N'``, so that a later command can be projected onto the same space.
    """
    n = q.shape[0]
    P = nullspace_projector(A, n) if projector is None else projector
    v = P @ pi
    locked = np.zeros(n, dtype=bool)
    # Each pass locks at least one more joint, so this ends after at most n passes.
    for _ in range(n):
        new = limit_locks(q, v, lower, upper) & ~locked
        if not np.any(new):
            break
        locked |= new
        P = nullspace_projector(np.vstack([A, np.eye(n)[locked]]))
        v = P @ pi
    v[locked] = 0.0  # exact zeros where the projection leaves round-off
    return v, P


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
    target = target`` (``target`` from :func:`project_with_locks` with the same ``P``, or
    zero). A target with a part outside that null space (a drift correction, which moves
    a held frame on purpose) gets that part at once: ``A c = A target`` at every
    ``alpha``, so the held frame moves as the correction says while the rest ramps.

    The projection itself may force a change: ``P previous - previous`` is the part of
    the previous command that the current constraints forbid (a constraint that has just
    become active, or changed). On a joint where that forced change alone exceeds
    ``max_delta`` the bound becomes the forced change, since the constraint wins; the
    caller can report it from the returned ``forced``.

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
        target, < 1 = acceleration-limited).
    forced : ndarray, shape (n,)
        ``P previous + (I - P) target - previous`` (rad/s).
    """
    base = projector @ previous
    outside = target - projector @ target
    if np.any(np.abs(outside) > _ROUNDOFF):
        base = base + outside
    forced = base - previous
    d = target - base
    # Per joint, the largest alpha with |forced_i + alpha d_i| <= bound_i; bound_i >=
    # |forced_i|, so alpha = 0 is always allowed and the minimum is >= 0.
    bound = np.maximum(max_delta, np.abs(forced))
    size = np.abs(d)
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(size > 0.0, (bound - np.sign(d) * forced) / size, np.inf)
    alpha = float(np.clip(np.min(room, initial=np.inf), 0.0, 1.0))
    if alpha == 1.0:
        return target.copy(), 1.0, forced
    return base + alpha * d, alpha, forced


def model_permutation(model_joints: Sequence[str] | None, joints: Sequence[str]) -> np.ndarray:
    """Indices ``p`` such that ``q[p]`` is ``q`` (ordered as ``joints``) in model order.

    Parameters
    ----------
    model_joints : sequence of str or None
        The joint names the model was trained on (None: trust the order of ``joints``).
    joints : sequence of str
        The controller's joint order.

    Returns
    -------
    ndarray of int, shape (n,)

    Raises
    ------
    ValueError
        If the two sets of names differ; the message lists the missing and extra names.
    """
    joints = list(joints)
    if model_joints is None:
        return np.arange(len(joints))
    model_joints = list(model_joints)
    missing = [j for j in model_joints if j not in joints]
    extra = [j for j in joints if j not in model_joints]
    if missing or extra or len(model_joints) != len(joints):
        raise ValueError(
            "model joints do not match the configured joints: "
            f"model needs {missing or 'nothing more'}, configured but not in the model "
            f"{extra or 'none'}"
        )
    index = {name: i for i, name in enumerate(joints)}
    return np.array([index[name] for name in model_joints], dtype=int)


class ControlStep:
    """One executor control step: joint positions in, joint velocity command out.

    Parameters
    ----------
    lower, upper : array_like, shape (n,)
        Joint position limits.
    max_velocity : array_like, shape (n,)
        Per-joint speed limits (> 0).
    dt : float
        Control period (s), used to stop joints before their limits.
    constraints : sequence of objects with ``matrix(q) -> (k, n)``
        Constraints in force; none means unconstrained. Those with a
        ``hold_position(q) -> p (k,)`` method (position constraints, and the parts of a
        stacked constraint that are) hold their frame where it was at :meth:`latch`.
    policy : callable, optional
        ``policy(X)`` with X of shape (1, n) in model joint order, returning (1, n) in rad/s
        (for example ``PolicyAlign.policy``). None means no model: commands are zeros.
    permutation : array_like of int, shape (n,), optional
        From :func:`model_permutation`; identity when omitted.
    max_acceleration : float, optional
        rad/s^2; when given, joints heading for a position limit are slowed in time to
        brake at that rate (see :func:`velocity_scale`), and the extrapolation guard's band
        covers the stopping distance at that rate. The step itself has no memory beyond
        the held references: limiting the change between steps is
        :class:`ArmedController`'s job.
    guard : ExtrapolationGuard, optional
        Scales down commands leading away from the demonstrated data; None: off.
    drift_gain : float
        ``k`` of the drift correction of held frames (1/s, >= 0; 0 = off).
    drift_clamp_m : float
        Clamp of a held frame's error in the correction (m, > 0).
    min_singular_value : float
        Smallest singular value of the constraint matrix below which the step refuses to
        command (units of its rows, m/rad for frame rows; >= 0, 0 = never).

    Attributes
    ----------
    extrapolation_scale : float
        The guard's scale at the last :meth:`evaluate` (1 without a guard).
    extrapolation_distance : float
        ``d`` (spacings) at the last :meth:`evaluate`; NaN without a guard.
    """

    def __init__(
        self,
        lower: np.ndarray,
        upper: np.ndarray,
        max_velocity: np.ndarray,
        dt: float,
        constraints: Sequence[ConstraintModel] = (),
        policy: PolicyFn | None = None,
        permutation: np.ndarray | None = None,
        max_acceleration: float | None = None,
        guard: ExtrapolationGuard | None = None,
        drift_gain: float = DEFAULT_DRIFT_GAIN,
        drift_clamp_m: float = DEFAULT_DRIFT_CLAMP_M,
        min_singular_value: float = DEFAULT_MIN_SINGULAR_VALUE,
    ) -> None:
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        n = self.lower.shape[0]
        self.max_velocity = np.broadcast_to(np.asarray(max_velocity, dtype=float), (n,)).copy()
        if np.any(~(self.max_velocity > 0.0)):
            raise ValueError("max_velocity: must be > 0 for every joint")
        if not dt > 0.0:
            raise ValueError(f"dt: must be > 0, got {dt}")
        self.dt = float(dt)
        self.constraints = list(constraints)
        self.policy = policy
        self.permutation = (
            np.arange(n) if permutation is None else np.asarray(permutation, dtype=int)
        )
        self.max_acceleration = max_acceleration
        self.guard = guard
        self.drift_gain = drift_gain
        self.drift_clamp_m = drift_clamp_m
        self.min_singular_value = min_singular_value
        self.extrapolation_scale = 1.0
        self.extrapolation_distance = float("nan")
        self._zeros = np.zeros(n)
        self._eye = np.eye(n)

    @property
    def n_joints(self) -> int:
        """Number of controlled joints ``n``."""
        return self.lower.shape[0]

    # -- settings -------------------------------------------------------------------
    @property
    def constraints(self) -> list[ConstraintModel]:
        """Constraints in force; setting them forgets the held references."""
        return self._constraints

    @constraints.setter
    def constraints(self, value: Sequence[ConstraintModel]) -> None:
        self._constraints = list(value)
        flat: list = []
        stack = list(reversed(self._constraints))
        while stack:
            c = stack.pop()
            parts = getattr(c, "parts", None)
            if parts is not None:
                stack.extend(reversed(list(parts)))
            else:
                flat.append(c)
        self._flat = flat
        self._holds = [i for i, c in enumerate(flat) if hasattr(c, "hold_position")]
        self._unilateral = [i for i, c in enumerate(flat) if getattr(c, "unilateral", False)]
        # Latched at the next latch() or, failing that, at the next evaluate().
        self._references: dict[int, np.ndarray] = {}

    @property
    def drift_gain(self) -> float:
        """Drift-correction gain ``k`` (1/s).

        A new value re-latches the held frames where they are (at the next
        :meth:`evaluate`): the correction is applied outside the acceleration ramp, so a
        larger gain on a drifted frame would step the command at once.
        """
        return self._drift_gain

    @drift_gain.setter
    def drift_gain(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"drift_gain: must be finite and >= 0, got {value}")
        if hasattr(self, "_drift_gain") and value != self._drift_gain:
            self._references = {}
        self._drift_gain = value

    @property
    def drift_clamp_m(self) -> float:
        """Clamp of a held frame's error in the correction (m); a new value re-latches
        the held frames, as :attr:`drift_gain` does."""
        return self._drift_clamp

    @drift_clamp_m.setter
    def drift_clamp_m(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"drift_clamp_m: must be finite and > 0, got {value}")
        if hasattr(self, "_drift_clamp") and value != self._drift_clamp:
            self._references = {}
        self._drift_clamp = value

    @property
    def min_singular_value(self) -> float:
        """Near-singularity threshold of the constraint matrix."""
        return self._min_sv

    @min_singular_value.setter
    def min_singular_value(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"min_singular_value: must be finite and >= 0, got {value}")
        self._min_sv = value

    @property
    def holding(self) -> bool:
        """Whether any constraint holds a frame (drift correction applies)."""
        return bool(self._holds)

    def latch(self, q: np.ndarray) -> None:
        """Take the held frames' positions at ``q`` (n,) as their references."""
        q = np.asarray(q, dtype=float)
        self._references = {i: np.asarray(self._flat[i].hold_position(q), dtype=float)
                            for i in self._holds}

    def hold_errors(self, q: np.ndarray) -> np.ndarray:
        """``p - p_ref`` of all held frames at ``q`` (n,), stacked (k_h,), in m.

        Frames not latched yet count as on their reference.
        """
        q = np.asarray(q, dtype=float)
        out = []
        for i in self._holds:
            p = np.asarray(self._flat[i].hold_position(q), dtype=float)
            ref = self._references.get(i)
            out.append(np.zeros_like(p) if ref is None else p - ref)
        return np.concatenate(out) if out else np.zeros(0)

    def constraint_matrix(self, q: np.ndarray, pi: np.ndarray | None = None) -> np.ndarray:
        """All constraint rows at ``q`` stacked, shape (k, n).

        ``pi`` (n,) is the intended velocity, which unilateral constraints (barriers) use
        to act only against motion towards them.
        """
        return self._stack(self._blocks(q, pi))[0]

    def _blocks(self, q: np.ndarray, pi: np.ndarray | None,
                also: Sequence[np.ndarray] = ()) -> list[np.ndarray]:
        """The rows (k_i, n) of every constraint at ``q``.

        A unilateral barrier is active when ``pi`` approaches it, or any velocity of
        ``also`` does (the command that the other constraints and the limit locks made of
        ``pi`` may approach a barrier that ``pi`` itself recedes from).
        """
        n = self.n_joints
        blocks = [np.asarray(c.matrix(q, pi), dtype=float).reshape(-1, n) for c in self._flat]
        return self._grown(q, blocks, also)

    def _grown(self, q: np.ndarray, blocks: list[np.ndarray],
               also: Sequence[np.ndarray]) -> list[np.ndarray]:
        """``blocks`` (one per constraint) with every inactive barrier that a velocity of
        ``also`` approaches made active (the blocks of all others are the same objects).
        Only those barriers are evaluated again: the other constraints' Jacobians do not
        depend on the velocity."""
        out = list(blocks)
        for i in self._unilateral:
            for v in also:
                if out[i].shape[0]:
                    break
                block = np.asarray(self._flat[i].matrix(q, v), dtype=float)
                if block.size:
                    out[i] = block.reshape(-1, self.n_joints)
        return out

    def _stack(self, blocks: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray | None]:
        """The rows of ``blocks`` stacked (k, n), and the mask of the held frames' rows."""
        if not blocks:
            return np.zeros((0, self.n_joints)), None
        A = np.vstack(blocks)
        if not self._holds:
            return A, None
        mask = np.zeros(A.shape[0], dtype=bool)
        start = 0
        holds = set(self._holds)
        for i, block in enumerate(blocks):
            if i in holds:
                mask[start:start + block.shape[0]] = True
            start += block.shape[0]
        return A, mask

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, str]:
        """Command for positions ``q`` (n,) in controller order.

        Returns
        -------
        qdot : ndarray, shape (n,)
            Velocity command in rad/s; zeros when no safe command exists.
        reason : str
            Empty on a normal command, else why the command is zero.
        """
        qdot, reason, _ = self.evaluate(q)
        return qdot, reason

    def evaluate(self, q: np.ndarray, previous: np.ndarray | None = None
                 ) -> tuple[np.ndarray, str, np.ndarray]:
        """As :meth:`__call__`, plus the projector ``N'`` (n, n) the command lies in.

        A unilateral barrier blocks the command when the policy, the command made of it,
        or ``previous`` (n,), the last command sent, which a ramp blends in, approaches
        it.

        ``N'`` projects onto the null space of the constraints and the locked joints at
        ``q`` (the identity when the command is zero for a reason), so a ramp can project
        the previous command onto the same space (:func:`ramp_toward`). The command is
        ``g s (N' pi + qdot_c)``: the projected policy plus the drift correction, scaled
        by ``s`` for speed and position limits and by the guard's ``g``; only
        ``qdot_c`` leaves ``N'``.
        """
        if self.policy is None:
            return self._zeros.copy(), "no model loaded", self._eye
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_joints,) or not np.all(np.isfinite(q)):
            return self._zeros.copy(), "joint positions missing or not finite", self._eye
        p = self.permutation
        try:
            pi_model = np.asarray(self.policy(q[p][None, :]), dtype=float).reshape(-1)
        except Exception as err:  # noqa: BLE001 - any failure is "no safe command"
            return self._zeros.copy(), f"policy failed: {type(err).__name__}: {err}", self._eye
        if pi_model.shape != (self.n_joints,) or not np.all(np.isfinite(pi_model)):
            return self._zeros.copy(), "policy output not finite", self._eye
        pi = np.empty(self.n_joints)
        pi[p] = pi_model
        # Active set of the unilateral barriers: one that the command approaches joins,
        # and the command is made again, until none joins (at most one round per barrier).
        blocks = self._blocks(q, pi, [] if previous is None else [np.asarray(previous,
                                                                               dtype=float)])
        A, held = self._stack(blocks)
        while True:
            problem, P0 = self._enforceable(A)
            if problem:
                return self._zeros.copy(), problem, self._eye
            if held is None or self._drift_gain == 0.0:
                v, P = project_with_locks(q, pi, A, self.lower, self.upper, P0)
            else:
                v, P = self._with_correction(q, pi, A, held, P0)
            if not self._unilateral:
                break
            # pi and the earlier commands were tested already: only v can add a barrier.
            grown = self._grown(q, blocks, [v])
            if all(g is b for g, b in zip(grown, blocks, strict=True)):
                break
            blocks = grown
            A, held = self._stack(blocks)
        s = velocity_scale(q, v, self.dt, self.lower, self.upper, self.max_velocity,
                           self.max_acceleration)
        v = s * v
        if self.guard is not None:
            try:
                g, d = self.guard.scale(q, v, self.max_velocity, self.max_acceleration)
            except ValueError as err:
                return self._zeros.copy(), f"extrapolation guard: {err}", self._eye
            self.extrapolation_scale, self.extrapolation_distance = g, d
            if g < 1.0:
                v = g * v
        return v, "", P

    def _enforceable(self, A: np.ndarray) -> tuple[str, np.ndarray | None]:
        """Why ``A`` (k, n) cannot be enforced (not finite, or :meth:`_singular`), empty
        when it can, and its projector when computed on the way."""
        if not np.all(np.isfinite(A)):
            return "constraint matrix not finite", None
        return self._singular(A)

    def _singular(self, A: np.ndarray) -> tuple[str, np.ndarray | None]:
        """Why ``A`` (k, n) is too close to singular to be enforced (empty when it is
        not), and its null-space projector when computed on the way (else None)."""
        k, n = A.shape
        if k == 0:
            return "", self._eye
        if self._min_sv == 0.0:
            return "", None
        if k > n:
            smallest, P = 0.0, None
        else:
            # One SVD for both the check and the projector.
            _, sv, vt = np.linalg.svd(A, full_matrices=False)
            smallest = float(sv[-1])
            P = projector_from_svd(sv, vt)
        if smallest >= self._min_sv:
            return "", P
        return (f"constraint matrix near-singular: smallest singular value {smallest:.3g} "
                f"< min_singular_value {self._min_sv:g} ({k} rows on {n} joints)"), None

    def _with_correction(self, q: np.ndarray, pi: np.ndarray, A: np.ndarray,
                         held: np.ndarray, P0: np.ndarray | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
        """``N' pi + qdot_c`` and ``N'``: the projected policy plus the drift correction.

        ``qdot_c = B^T (B B^T + l^2 I)^{-1} (-k clamp(e))`` with ``B = A_h N_o``, ``A_h``
        the held rows, ``N_o`` the projector of the other rows and the locked joints and
        ``e`` the held frames' errors, each clamped to ``drift_clamp_m`` in norm. A joint
        that the sum pushes out of its limit is locked too (then both parts are
        recomputed), as in :func:`project_with_locks`. ``P0``, when given, is the
        projector of ``A`` alone (computed by the near-singularity check on the way).
        """
        n = self.n_joints
        if len(self._references) < len(self._holds):
            missing = [i for i in self._holds if i not in self._references]
            for i in missing:
                self._references[i] = np.asarray(self._flat[i].hold_position(q), dtype=float)
        errors = []
        for i in self._holds:
            e = np.asarray(self._flat[i].hold_position(q), dtype=float) - self._references[i]
            size = float(np.linalg.norm(e))
            errors.append(e * (self._drift_clamp / size) if size > self._drift_clamp else e)
        task = -self._drift_gain * np.concatenate(errors)
        A_h, A_o = A[held], A[~held]
        locked = np.zeros(n, dtype=bool)
        lam2 = HOLD_DAMPING**2
        for _ in range(n + 1):
            lock_rows = self._eye[locked]
            P = (P0 if P0 is not None and not locked.any()
                 else nullspace_projector(np.vstack([A, lock_rows]), n))
            v = P @ pi
            v[locked] = 0.0
            P_o = nullspace_projector(np.vstack([A_o, lock_rows]), n)
            B = A_h @ P_o
            correction = B.T @ np.linalg.solve(B @ B.T + lam2 * np.eye(B.shape[0]), task)
            correction[locked] = 0.0
            total = v + correction
            new = limit_locks(q, total, self.lower, self.upper) & ~locked
            if not np.any(new):
                return total, P
            locked |= new
        return total, P

    def constraint_problem(self, q: np.ndarray) -> str:
        """Why the constraints at ``q`` (n,) cannot be enforced; empty when they can.

        The check :meth:`evaluate` makes every step, on the rows in force with the robot
        at rest (barriers inactive): a spec whose rows cannot be met (a frame that the
        controlled joints do not move) is refused at enable instead of disarming the
        first step.
        """
        try:
            A = self.constraint_matrix(q, self._zeros)
        except Exception as err:  # noqa: BLE001 - a refusal, never an escaping error
            return f"constraints failed: {type(err).__name__}: {err}"
        return self._enforceable(A)[0]

    def hold_projector(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray | None:
        """Projector (n, n) for a command ``qdot`` (n,) at ``q`` (n,) without the policy.

        What a ramp towards zero projects onto: the constraints at ``q`` (barriers judged
        by ``qdot``) and the joints that ``qdot`` pushes out of their limits. None when the
        constraint matrix is not finite.
        """
        A = self.constraint_matrix(q, qdot)
        if not np.all(np.isfinite(A)):
            return None
        return project_with_locks(q, qdot, A, self.lower, self.upper)[1]


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
        Set by :meth:`ArmedController.joint_state` when it refused the state for its
        stamp: one of :data:`STAMP_REJECTIONS` (the log line has the details).
    extrapolation_scale : float
        The extrapolation guard's scale at the last evaluated step (1: not scaling).
    """

    command: np.ndarray | None
    zero_reason: str
    ramp_scale: float
    events: list[tuple[str, str]] = field(default_factory=list)
    rejected: str = ""
    extrapolation_scale: float = 1.0


#: Keys of :attr:`Output.rejected`: stamp zero, earlier than the last one, older than
#: ``state_timeout_s + max_clock_skew_s``, later than the clock by ``max_clock_skew_s``.
STAMP_REJECTIONS: tuple[str, ...] = ("zero_stamp", "stamp_backwards", "stamp_too_old",
                                     "stamp_in_future")

#: Commands smaller than this (rad/s) are round-off: they are sent as exact zeros.
_ROUNDOFF = 1e-12

#: Minimum time between two reports of a constraint forcing a larger change (ns).
_FORCED_REPORT_NS = 1_000_000_000


class ArmedController:
    """Arming, staleness and acceleration ramps around a :class:`ControlStep`.

    Times are integer nanoseconds of the caller's clock (the executor node's clock, so
    simulated time works); nothing here reads a clock. Per control period the caller
    passes the latest valid joint state (:meth:`joint_state`), reports broken ones
    (:meth:`reject_state`) and calls :meth:`tick`; every call returns an :class:`Output`
    whose ``command``, when not None, must be published at once. A tick sooner than one
    period after the last published command may change it by the acceleration bound
    times the time in between only, so calling :meth:`tick` more often (one step per
    joint state of a driver faster than the period) cannot exceed ``max_acceleration``.

    Parameters
    ----------
    step : ControlStep
        The control law (policy, constraints, limits, period ``dt`` in s).
    max_acceleration : float
        Per-joint acceleration bound of the command (rad/s^2), > 0.
    state_timeout_s : float
        Joint states older than this (by arrival, or by stamp beyond the allowed skew)
        are stale (s), > 0.
    max_clock_skew_s : float
        Allowed offset between the joint states' stamps and this clock (s), >= 0.
    joint_names : sequence of str, optional
        Names used in log lines (controller order).

    Attributes
    ----------
    armed : bool
        Whether commands follow the policy.
    command : ndarray, shape (n,)
        The last command published (rad/s).
    faulted : bool
        Whether the last disarm was caused by a fault (joint states, clock, policy output)
        rather than requested; cleared when armed again.
    context : str
        Appended to arm and disarm log lines (the caller puts the model and the
        constraint specs there).
    ramp_scale : float
        ``alpha`` of the last step (:func:`ramp_toward`; 1 = on target).
    extrapolation_scale : float
        The extrapolation guard's scale at the last step that followed the policy.
    """

    def __init__(
        self,
        step: ControlStep,
        max_acceleration: float,
        state_timeout_s: float,
        max_clock_skew_s: float = 0.0,
        joint_names: Sequence[str] | None = None,
    ) -> None:
        self.step = step
        self.max_acceleration = max_acceleration
        self.state_timeout_s = state_timeout_s
        self.max_clock_skew_s = max_clock_skew_s
        n = step.n_joints
        self.joint_names = (list(joint_names) if joint_names is not None
                            else [f"joint {i}" for i in range(n)])
        self.armed = False
        self.faulted = False
        self.command = np.zeros(n)
        self.context = ""
        self.zero_reason = "not enabled yet"
        self.ramp_scale = 1.0
        self.extrapolation_scale = 1.0
        # Nothing left to publish: disarmed and the zero command has gone out.
        self._silent = True
        self._q: np.ndarray | None = None
        self._stamp_ns: int | None = None
        self._arrival_ns: int | None = None
        self._last_now_ns: int | None = None
        self._forced_reported_ns: int | None = None
        self._published_ns: int | None = None  # when the last ramped command went out
        self._forced_suppressed = 0
        self._events: list[tuple[str, str]] = []

    # -- settings -------------------------------------------------------------------
    @property
    def max_acceleration(self) -> float:
        """Acceleration bound (rad/s^2); also the step's braking limit near joint limits."""
        return self.step.max_acceleration

    @max_acceleration.setter
    def max_acceleration(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"max_acceleration: must be finite and > 0, got {value}")
        self.step.max_acceleration = value

    @property
    def state_timeout_s(self) -> float:
        """Joint-state timeout (s)."""
        return self._timeout_ns / 1e9

    @state_timeout_s.setter
    def state_timeout_s(self, value: float) -> None:
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"state_timeout_s: must be finite and > 0, got {value}")
        self._timeout_ns = round(value * 1e9)

    @property
    def max_clock_skew_s(self) -> float:
        """Allowed stamp-to-clock offset (s)."""
        return self._skew_ns / 1e9

    @max_clock_skew_s.setter
    def max_clock_skew_s(self, value: float) -> None:
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"max_clock_skew_s: must be finite and >= 0, got {value}")
        self._skew_ns = round(value * 1e9)

    @property
    def max_delta(self) -> float:
        """Largest change of a joint's command in one step (rad/s)."""
        return self.max_acceleration * self.step.dt

    @property
    def last_q(self) -> np.ndarray | None:
        """The last accepted joint positions (n,), or None since a fault or at start."""
        return self._q

    @property
    def publishing(self) -> bool:
        """Whether :meth:`tick` still publishes (armed, or ramping down to zero)."""
        return not self._silent

    # -- joint states ---------------------------------------------------------------
    def joint_state(self, q: np.ndarray, stamp_ns: int, now_ns: int) -> Output:
        """Take a validated joint state ``q`` (n,) stamped ``stamp_ns``, received ``now_ns``.

        A stamp that is zero, older than ``state_timeout_s + max_clock_skew_s``, more than
        ``max_clock_skew_s`` in the future or earlier than the last one makes the state
        untrustworthy: the command goes to zero at once and the controller disarms. A
        stamp equal to the last one is ignored (a repeat is no news).
        """
        jumped = self._clock(now_ns)
        if jumped is not None:
            return jumped
        stamp_ns = int(stamp_ns)
        last = self._stamp_ns
        if last is not None and stamp_ns == last:
            return self._output(None)
        key, problem = "", ""
        if stamp_ns <= 0:
            key, problem = "zero_stamp", "joint state without a header stamp"
        elif now_ns - stamp_ns > self._timeout_ns + self._skew_ns:
            key = "stamp_too_old"
            problem = (f"joint state stamp {(now_ns - stamp_ns) / 1e9:.3f} s old "
                       f"(> state_timeout_s + max_clock_skew_s)")
        elif stamp_ns - now_ns > self._skew_ns:
            key = "stamp_in_future"
            problem = (f"joint state stamp {(stamp_ns - now_ns) / 1e9:.3f} s in the future "
                       f"(> max_clock_skew_s)")
        elif last is not None and stamp_ns < last:
            key = "stamp_backwards"
            problem = f"joint state stamp went backwards by {(last - stamp_ns) / 1e9:.3f} s"
        if problem:
            out = self.reject_state(problem)
            out.rejected = key
            return out
        self._q = np.asarray(q, dtype=float)
        self._stamp_ns = stamp_ns
        self._arrival_ns = int(now_ns)
        return self._output(None)

    def reject_state(self, reason: str) -> Output:
        """A broken joint state (NaN, duplicate names, bad lengths, bad stamp) arrived.

        The last good state is forgotten, so arming needs a fresh valid one, and the
        command goes to zero at once.
        """
        self._forget_state()
        return self.fault(reason)

    def state_problem(self, now_ns: int) -> str:
        """Why the joint states are not fresh at ``now_ns``; empty when they are."""
        if self._q is None:
            return "no valid joint state received"
        age = now_ns - self._arrival_ns
        if age > self._timeout_ns:
            return f"joint states stale: last received {age / 1e9:.3f} s ago"
        age = now_ns - self._stamp_ns
        if age > self._timeout_ns + self._skew_ns:
            return f"joint states stale: last stamp {age / 1e9:.3f} s old"
        return ""

    def _forget_state(self) -> None:
        self._q = None
        self._stamp_ns = None
        self._arrival_ns = None

    def _clock(self, now_ns: int) -> Output | None:
        """Check that the clock runs forwards; a jump back (restarted sim) disarms."""
        last = self._last_now_ns
        self._last_now_ns = int(now_ns)
        if last is None or now_ns >= last:
            return None
        self._forget_state()
        self._forced_reported_ns = None
        return self.fault(f"clock jumped back by {(last - now_ns) / 1e9:.3f} s "
                          f"(restarted simulation?)")

    # -- arming ---------------------------------------------------------------------
    def arm_refusal(self, now_ns: int) -> str:
        """Why :meth:`arm` at ``now_ns`` would be refused; empty when it would arm.

        No side effects, so a caller can check before a slower step (the executor node
        asks the controller for its joint order only when arming would go ahead).
        """
        if self.step.policy is None:
            return "no model loaded"
        return self.state_problem(now_ns) or self.step.constraint_problem(self._q)

    def arm(self, now_ns: int) -> tuple[bool, str, Output]:
        """Request to follow the policy.

        Returns
        -------
        (accepted, reason, output)
            Refused, with the reason, without a model or with stale joint states.
        """
        jumped = self._clock(now_ns)
        refusal = self.arm_refusal(now_ns)
        if refusal:
            return False, refusal, jumped or self._output(None)
        if self.armed:
            return True, "already enabled", self._output(None)
        self.armed = True
        self.faulted = False
        self._silent = False
        self.zero_reason = ""
        # Held frames stay where they are at enable; drift is measured from here.
        self.step.latch(self._q)
        # The ramp starts from the last command sent (zero, or partway down a ramp).
        self._log("info", "armed: following the policy")
        return True, "enabled", self._output(None)

    def disarm(self, reason: str) -> Output:
        """Stop following the policy and ramp the command down to zero (``reason`` logged)."""
        if self.armed:
            self.armed = False
            self.zero_reason = reason
            self._log("info", f"disarmed: {reason}; ramping down at "
                              f"{self.max_acceleration:g} rad/s^2")
        return self._output(None)

    def fault(self, reason: str) -> Output:
        """Zero command at once and disarm (nothing to publish when already silent)."""
        if self._silent:
            return self._output(None)
        was_armed = self.armed
        self.armed = False
        self.faulted = True
        self._silent = True
        self.zero_reason = reason
        self.ramp_scale = 1.0
        self.command = np.zeros(self.step.n_joints)
        self._log("warning", f"{'disarmed' if was_armed else 'ramp-down cut short'}: "
                             f"{reason}; zero command at once")
        return self._output(self.command.copy())

    def set_policy(self, policy: PolicyFn | None, permutation: np.ndarray | None = None,
                   reason: str = "model swap") -> Output:
        """Swap the model; an armed controller disarms and ramps down (``reason``)."""
        out = self.disarm(reason)
        self.step.policy = policy
        self.step.permutation = (np.arange(self.step.n_joints) if permutation is None
                                 else np.asarray(permutation, dtype=int))
        return out

    # -- the control period ---------------------------------------------------------
    def tick(self, now_ns: int) -> Output:
        """One control period at ``now_ns``: the command to publish, if any."""
        jumped = self._clock(now_ns)
        if jumped is not None:
            return jumped
        if self._silent:
            return self._output(None)
        problem = self.state_problem(now_ns)
        if problem:
            return self.fault(problem)
        q = self._q
        step = self.step
        previous = self.command
        projector = None
        if self.armed:
            try:
                target, reason, projector = step.evaluate(q, previous)
            except Exception as err:  # noqa: BLE001 - e.g. an SVD that did not converge
                target, projector = np.zeros(step.n_joints), None
                reason = f"control step failed: {type(err).__name__}: {err}"
            self.extrapolation_scale = step.extrapolation_scale
            if reason:
                # The policy cannot be trusted here, but q and the constraints still
                # can: ramp down like a disable. (disarm() hands its log line back in
                # an Output; keep it for this tick's.)
                logged = self.disarm(reason).events
                self._events.extend(logged)
                self.faulted = True
        if not self.armed:
            target = np.zeros(step.n_joints)
            try:
                projector = step.hold_projector(q, previous)
            except Exception as err:  # noqa: BLE001 - the ramp down needs none of it
                return self.fault(f"constraints failed: {type(err).__name__}: {err}")
            if projector is None:
                return self.fault("constraint matrix not finite")
        limit = self.max_delta
        if self._published_ns is not None:
            since = max(0, now_ns - self._published_ns) / 1e9
            limit = self.max_acceleration * min(step.dt, since)
        command, alpha, forced = ramp_toward(previous, target, projector, limit)
        # Round-off of the projection (1e-17 rad/s on a joint locked at its limit) would
        # read as "pushed outwards" below and stop every joint.
        command[np.abs(command) < _ROUNDOFF] = 0.0
        # Safety net, rarely active: the projection of the previous command may exceed a
        # speed limit, or it may head for a position limit faster than the target did. A
        # speed limit lowered at run time is reached by the ramp, not in one step: a joint
        # that was already faster keeps its last speed as its bound while it slows down.
        speed_bound = np.maximum(step.max_velocity, np.abs(previous))
        s = velocity_scale(q, command, step.dt, step.lower, step.upper, speed_bound)
        if s < 1.0:
            command = s * command
        self._report_forced(command - previous, forced, s, now_ns, limit)
        self.command = command
        self._published_ns = now_ns
        self.ramp_scale = alpha
        if not self.armed and not np.any(command):
            self._silent = True
            self._log("info", f"command at zero ({self.zero_reason})")
        return self._output(command.copy())

    def _report_forced(self, change: np.ndarray, forced: np.ndarray, s: float,
                       now_ns: int, limit: float) -> None:
        size_all = np.abs(change)
        size = float(size_all.max(initial=0.0))
        if size <= limit * (1.0 + 1e-9) + 1e-12:
            return
        worst = int(np.argmax(size_all))
        # Throttled on the caller's clock: a barrier can stay in contact for many steps.
        last = self._forced_reported_ns
        if last is not None and now_ns - last < _FORCED_REPORT_NS:
            self._forced_suppressed += 1
            return
        cause = ("speed or position limit" if s < 1.0 else
                 "newly active or changed constraint")
        more = (f" ({self._forced_suppressed} more since the last report)"
                if self._forced_suppressed else "")
        self._forced_reported_ns = int(now_ns)
        self._forced_suppressed = 0
        self._events.append(("warning", (
            f"{cause} forces a command change of {size:.4g} rad/s on "
            f"{self.joint_names[worst]} in one step (ramp allows {limit:.4g}; largest "
            f"forced part {float(np.max(np.abs(forced))):.4g}){more}")))

    def _log(self, level: str, text: str) -> None:
        self._events.append((level, f"{text}{'; ' + self.context if self.context else ''}"))

    def _output(self, command: np.ndarray | None) -> Output:
        events, self._events = self._events, []
        return Output(command, self.zero_reason, self.ramp_scale, events,
                      extrapolation_scale=self.extrapolation_scale)
