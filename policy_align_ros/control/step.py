"""One control step, ROS-free: ``qdot = s N(q) pi_hat(q)``.

Notation and units: ``q`` joint positions (rad), ``pi_hat(q)`` the learnt unconstrained
policy (rad/s), ``A(q)`` the stacked constraint matrix (k, n) of the configured constraints,
``N = I - pinv(A) A`` its null-space projector, ``dt`` the control period (s).

* a joint sitting on a position limit and pushed outwards is *locked*, i.e. a unit row is
  appended to ``A`` and the policy is projected again, so the remaining joints still follow
  the policy within the constraints instead of the whole robot stalling
  (:func:`~policy_align_ros.control.locked_projection.project_with_locks`);
* the projected velocity is scaled by one factor ``s in [0, 1]`` so that no joint exceeds
  its maximum speed and no joint crosses a limit within one period
  (:func:`~policy_align_ros.control.limits.velocity_scale`); with ``max_acceleration``
  joints are braked in time to come to rest at their limits, which lie
  ``joint_limit_margin`` inside the URDF's, and frames before the barriers they approach
  (:func:`~policy_align_ros.control.limits.clearance_scale`);
* the extrapolation guard (:mod:`policy_align_ros.control.guard`) scales down commands
  leading away from the demonstrated data;
* *drift correction*: position-type constraints (``hold`` a frame) latch the frame's
  position ``p_ref`` when the controller arms, and the command gets
  ``qdot_c = B^T (B B^T + l^2 I)^{-1} (-k clamp(p - p_ref))`` with ``B = A_h N_o`` (the
  held rows ``A_h`` on the null space ``N_o`` of the other constraints and locked
  joints, so the correction respects them), gain ``k`` (1/s), the error clamped to
  ``drift_clamp_m`` in norm and damping ``l`` (m/rad). Euler integration of commands with
  ``A qdot = 0`` drifts at second order; this pulls the frame back. A constraint matrix
  whose smallest singular value falls below ``min_singular_value`` (m/rad for frame rows)
  cannot be trusted: the step returns zero with the reason.

Anything that prevents a safe command (non-finite state, no policy, a policy returning
non-finite values) gives zeros, a reason in words and its
:class:`~policy_align_ros.control.causes.ZeroCause`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from policy_align_ros.control.causes import ZeroCause
from policy_align_ros.control.guard import ExtrapolationGuard
from policy_align_ros.control.limits import (
    clearance_scale,
    inner_limits,
    joint_velocity_bounds,
    limit_locks,
    velocity_scale,
)
from policy_align_ros.control.locked_projection import project_with_locks
from policy_align_ros.control.model_checks import GoalReach, forced_model_refusal
from policy_align_ros.control.turns import nearest_turn
from policy_align_ros.kinematics.constraints import ConstraintModel
from policy_align_ros.kinematics.projection import nullspace_projector, projector_from_svd

__all__ = [
    "DEFAULT_DRIFT_CLAMP_M",
    "DEFAULT_DRIFT_GAIN",
    "DEFAULT_MIN_SINGULAR_VALUE",
    "HOLD_DAMPING",
    "ControlStep",
    "PolicyFn",
]

#: ``policy(X (1, n)) -> (1, n)`` in rad/s, rows in model joint order.
PolicyFn = Callable[[np.ndarray], np.ndarray]

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
#: below which the executor stops: below what a held hand plus a plane on the other hand
#: reach over random Talos postures.
DEFAULT_MIN_SINGULAR_VALUE = 0.005


class ControlStep:
    """One executor control step: joint positions in, joint velocity command out.

    Parameters
    ----------
    lower, upper : array_like, shape (n,)
        Joint position limits (URDF).
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
        From :func:`~policy_align_ros.control.joint_order.model_permutation`; identity
        when omitted.
    max_acceleration : float, optional
        rad/s^2; when given, joints heading for a position limit are slowed in time to
        brake at that rate (see :func:`velocity_scale`), and the extrapolation guard's band
        covers the stopping distance at that rate. The step itself has no memory beyond
        the held references: limiting the change between steps is
        :class:`~policy_align_ros.control.armed.ArmedController`'s job.
    guard : ExtrapolationGuard, optional
        Scales down commands leading away from the demonstrated data; None: off.
    drift_gain : float
        ``k`` of the drift correction of held frames (1/s, >= 0; 0 = off).
    drift_clamp_m : float
        Clamp of a held frame's error in the correction (m, > 0).
    min_singular_value : float
        Smallest singular value of the constraint matrix below which the step refuses to
        command (units of its rows, m/rad for frame rows; >= 0, 0 = never).
    joint_limit_margin : float
        Distance (rad, >= 0) inside ``[lower, upper]`` at which joints come to rest: the
        step brakes and locks joints at :attr:`control_lower` and :attr:`control_upper`
        (:func:`~policy_align_ros.control.limits.inner_limits`).

    Attributes
    ----------
    extrapolation_scale : float
        The guard's scale at the last :meth:`evaluate` (1 without a guard).
    extrapolation_distance : float
        ``d`` (spacings) at the last :meth:`evaluate`; NaN without a guard.
    turn_centres : ndarray, shape (n,), or None
        Continuous joints' angles are moved by whole turns to within half a turn of these
        (rad; NaN for the other joints) before anything else sees them
        (:mod:`~policy_align_ros.control.turns`); None: as measured.
    model_refusals : tuple of str
        Why ``learn`` refused the model in force, which was written only because it was
        forced (:func:`~policy_align_ros.control.model_checks.model_refusals`); empty for
        a model that passed. :meth:`model_check` refuses to arm such a model unless
        ``allow_forced_model``.
    allow_forced_model : bool
        Whether a forced model may be armed (the executor's parameter of that name).
    goal_reach : GoalReach or None
        The learnt goal's distance to the data, measured by the guard when the model was
        loaded (for the report of a goal beyond the guard's reach); None without one.
    stop_check : ArmingStopCheck or None
        The loaded model's fold-stop check, run at each arming
        (:mod:`~policy_align_ros.control.stop_check`); None: nothing to check.
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
        joint_limit_margin: float = 0.0,
    ) -> None:
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.joint_limit_margin = joint_limit_margin
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
        self.turn_centres: np.ndarray | None = None
        self.model_refusals: tuple[str, ...] = ()
        self.allow_forced_model = False
        self.goal_reach: GoalReach | None = None
        self.stop_check = None
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
    def joint_limit_margin(self) -> float:
        """Distance (rad) inside the URDF limits at which braking brings joints to rest."""
        return self._margin

    @joint_limit_margin.setter
    def joint_limit_margin(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"joint_limit_margin: must be finite and >= 0, got {value}")
        self._margin = value
        self._inner = inner_limits(self.lower, self.upper, value)

    @property
    def control_lower(self) -> np.ndarray:
        """The lower limits the step brakes and locks at (n,): ``lower`` plus the margin."""
        return self._inner[0]

    @property
    def control_upper(self) -> np.ndarray:
        """The upper limits the step brakes and locks at (n,): ``upper`` less the margin."""
        return self._inner[1]

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
        # Barriers whose approach is braked (those that report their clearance).
        self._barriers = [i for i in self._unilateral if hasattr(flat[i], "clearance")]
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

    def velocity_bounds(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joint velocity bounds (rad/s, each (n,)) at ``q`` that this step scales
        commands to: speed limits, and braking in time before the limits at
        :attr:`control_lower` and :attr:`control_upper`
        (:func:`~policy_align_ros.control.limits.joint_velocity_bounds`); a task-space
        policy keeps to them."""
        return joint_velocity_bounds(q, self.control_lower, self.control_upper,
                                     self.max_velocity, self.dt, self.max_acceleration)

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

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, str, ZeroCause | None]:
        """Command for positions ``q`` (n,) in controller order.

        Returns
        -------
        qdot : ndarray, shape (n,)
            Velocity command in rad/s; zeros when no safe command exists.
        reason : str
            Empty on a normal command, else why the command is zero (for people).
        cause : ZeroCause or None
            None on a normal command, else why the command is zero (for programs).
        """
        qdot, reason, cause, _ = self.evaluate(q)
        return qdot, reason, cause

    def evaluate(self, q: np.ndarray, previous: np.ndarray | None = None
                 ) -> tuple[np.ndarray, str, ZeroCause | None, np.ndarray]:
        """As :meth:`__call__`, plus the projector ``N'`` (n, n) the command lies in.

        A unilateral barrier blocks the command when the policy, the command made of it,
        or ``previous`` (n,), the last command sent, which a ramp blends in, approaches
        it.

        ``N'`` projects onto the null space of the constraints and the locked joints at
        ``q`` (the identity when the command is zero for a reason), so a ramp can project
        the previous command onto the same space
        (:func:`~policy_align_ros.control.limits.ramp_toward`). The command is
        ``g s (N' pi + qdot_c)``: the projected policy plus the drift correction, scaled
        by ``s`` for speed and position limits and by the guard's ``g``; only
        ``qdot_c`` leaves ``N'``.
        """
        if self.policy is None:
            return self._zero("no model loaded", ZeroCause.NO_MODEL)
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_joints,) or not np.all(np.isfinite(q)):
            return self._zero("joint positions missing or not finite", ZeroCause.STATE_INVALID)
        q = nearest_turn(q, self.turn_centres)
        p = self.permutation
        try:
            pi_model = np.asarray(self.policy(q[p][None, :]), dtype=float).reshape(-1)
        except Exception as err:  # noqa: BLE001 - any failure is "no safe command"
            return self._zero(f"policy failed: {type(err).__name__}: {err}",
                              ZeroCause.POLICY_FAILED)
        if pi_model.shape != (self.n_joints,) or not np.all(np.isfinite(pi_model)):
            return self._zero("policy output not finite", ZeroCause.POLICY_NOT_FINITE)
        pi = np.empty(self.n_joints)
        pi[p] = pi_model
        # Active set of the unilateral barriers: one that the command approaches joins,
        # and the command is made again, until none joins (at most one round per barrier).
        blocks = self._blocks(q, pi, [] if previous is None else [np.asarray(previous,
                                                                               dtype=float)])
        A, held = self._stack(blocks)
        while True:
            cause, problem, P0 = self._enforceable(A)
            if cause is not None:
                return self._zero(problem, cause)
            if held is None or self._drift_gain == 0.0:
                v, P = project_with_locks(q, pi, A, *self._inner, P0)
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
        s = velocity_scale(q, v, self.dt, *self._inner, self.max_velocity,
                           self.max_acceleration)
        if self._barriers and self.max_acceleration is not None:
            # Inactive barriers only: the projection has removed the approach to the others.
            free = [self._flat[i] for i in self._barriers if not blocks[i].shape[0]]
            s = min(s, clearance_scale(q, v, free, self.dt, self.max_acceleration))
        v = s * v
        if self.guard is not None:
            try:
                g, d = self.guard.scale(q, v, self.max_velocity, self.max_acceleration)
            except ValueError as err:
                return self._zero(f"extrapolation guard: {err}", ZeroCause.EXTRAPOLATION_GUARD)
            self.extrapolation_scale, self.extrapolation_distance = g, d
            if g < 1.0:
                v = g * v
        return v, "", None, P

    def _zero(self, reason: str, cause: ZeroCause
              ) -> tuple[np.ndarray, str, ZeroCause, np.ndarray]:
        """What :meth:`evaluate` returns when no safe command exists."""
        return self._zeros.copy(), reason, cause, self._eye

    def _enforceable(self, A: np.ndarray
                     ) -> tuple[ZeroCause | None, str, np.ndarray | None]:
        """Why ``A`` (k, n) cannot be enforced (not finite, or :meth:`_singular`): cause
        and words, (None, "") when it can; and its projector when computed on the way."""
        if not np.all(np.isfinite(A)):
            return ZeroCause.CONSTRAINTS_NOT_FINITE, "constraint matrix not finite", None
        return self._singular(A)

    def _singular(self, A: np.ndarray) -> tuple[ZeroCause | None, str, np.ndarray | None]:
        """Why ``A`` (k, n) is too close to singular to be enforced ((None, "") when it is
        not), and its null-space projector when computed on the way (else None)."""
        k, n = A.shape
        if k == 0:
            return None, "", self._eye
        if self._min_sv == 0.0:
            return None, "", None
        if k > n:
            smallest, P = 0.0, None
        else:
            # One SVD for both the check and the projector.
            _, sv, vt = np.linalg.svd(A, full_matrices=False)
            smallest = float(sv[-1])
            P = projector_from_svd(sv, vt)
        if smallest >= self._min_sv:
            return None, "", P
        if k > n:
            return (ZeroCause.CONSTRAINTS_NEAR_SINGULAR,
                    f"the constraints over-constrain the robot: {k} constraint rows on {n} "
                    f"joints (more rows than joints leave no motion that keeps them all); "
                    f"remove a constraint from the constraints parameter", None)
        return (ZeroCause.CONSTRAINTS_NEAR_SINGULAR,
                f"constraint matrix near-singular: smallest singular value {smallest:.3g} "
                f"< min_singular_value {self._min_sv:g} ({k} rows on {n} joints)", None)

    def _with_correction(self, q: np.ndarray, pi: np.ndarray, A: np.ndarray,
                         held: np.ndarray, P0: np.ndarray | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
        """``N' pi + qdot_c`` and ``N'``: the projected policy plus the drift correction.

        ``qdot_c = B^T (B B^T + l^2 I)^{-1} (-k clamp(e))`` with ``B = A_h N_o``, ``A_h``
        the held rows, ``N_o`` the projector of the other rows and the locked joints and
        ``e`` the held frames' errors, each clamped to ``drift_clamp_m`` in norm. A joint
        that the sum pushes out of its limit is locked too (then both parts are
        recomputed), as in
        :func:`~policy_align_ros.control.locked_projection.project_with_locks`. ``P0``,
        when given, is the projector of ``A`` alone (computed by the near-singularity
        check on the way).
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
            new = limit_locks(q, total, *self._inner) & ~locked
            if not np.any(new):
                return total, P
            locked |= new
        return total, P

    def model_check(self) -> tuple[ZeroCause | None, str]:
        """Why the model in force may not be armed, as ``(cause, reason)``: none loaded,
        or one that ``learn`` refused and wrote only because it was forced
        (:attr:`model_refusals`) while :attr:`allow_forced_model` is off; ``(None, "")``
        when it may."""
        if self.policy is None:
            return ZeroCause.NO_MODEL, "no model loaded"
        if self.model_refusals and not self.allow_forced_model:
            return ZeroCause.FORCED_MODEL, forced_model_refusal(self.model_refusals)
        return None, ""

    def constraint_check(self, q: np.ndarray) -> tuple[ZeroCause | None, str]:
        """Why the constraints at ``q`` (n,) cannot be enforced, as ``(cause, reason)``;
        ``(None, "")`` when they can.

        The check :meth:`evaluate` makes every step, on the rows in force with the robot
        at rest (barriers inactive): a spec whose rows cannot be met (a frame that the
        controlled joints do not move) is refused at enable instead of disarming the
        first step.
        """
        try:
            A = self.constraint_matrix(q, self._zeros)
        except Exception as err:  # noqa: BLE001 - a refusal, never an escaping error
            return (ZeroCause.CONSTRAINTS_FAILED,
                    f"constraints failed: {type(err).__name__}: {err}")
        return self._enforceable(A)[:2]

    def hold_projector(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray | None:
        """Projector (n, n) for a command ``qdot`` (n,) at ``q`` (n,) without the policy.

        What a ramp towards zero projects onto: the constraints at ``q`` (barriers judged
        by ``qdot``) and the joints that ``qdot`` pushes out of their limits. None when the
        constraint matrix is not finite.
        """
        A = self.constraint_matrix(q, qdot)
        if not np.all(np.isfinite(A)):
            return None
        return project_with_locks(q, qdot, A, *self._inner)[1]
