"""Why the executor's command is zero, as stable identifiers.

The controller says why its command is zero (or ramping to zero) twice: in words, for
people (``zero_reason``: log lines, ``/diagnostics``), and as one :class:`ZeroCause`, for
programs (``zero_cause``: tests, dashboards, scripts). The words may change to explain
better; the identifiers do not. Every place that sets a reason sets its cause:

* :class:`~policy_align_ros.control.step.ControlStep` returns one with its reason (no
  model, a state or a policy output that is not finite, a policy that raised, the
  extrapolation guard, constraints that are not finite or near-singular);
* :class:`~policy_align_ros.control.armed.ArmedController` sets one on every disarm
  (disabled, a model swap, a stall, stale or rejected joint states, a clock jump, a
  control step that raised, constraints that fail during a ramp down);
* its refusal to arm gives one too, the model's (none loaded, or one that learn refused
  and wrote only because it was forced: :meth:`~policy_align_ros.control.step.
  ControlStep.model_check`) included;
* the executor's status (:func:`~policy_align_ros.control.status.arming_status`) gives
  one while the controller is *armed* but its command is held at zero by the
  extrapolation guard at the data's edge
  (:func:`~policy_align_ros.control.guard_hold.guard_hold`): the controller's own cause
  stays None then (it follows the policy, which the guard scales), and
  ``/diagnostics`` says why the robot does not move.

The values of the stamp and position rejections are the keys the executor counts
rejected joint states by (``rejected_joint_states`` on ``/diagnostics``), and so are those
of the broken messages (:data:`policy_align_ros.data.messages.UNTRUSTWORTHY`).
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["NO_CAUSE", "ZeroCause"]

#: How ``/diagnostics`` spells "no cause": the command follows the policy.
NO_CAUSE = "none"


class ZeroCause(StrEnum):
    """Why the command is zero or ramping to zero; the value is the stable identifier.

    Members compare equal to their values (``ZeroCause.STALL == "stall"``), so a cause read
    back from ``/diagnostics`` is ``ZeroCause(text)``.
    """

    #: Never armed since the start.
    NOT_ENABLED = "not_enabled"
    #: Disarmed by a request (``~/enable`` false).
    DISABLED = "disabled"
    #: A new model was loaded: it is never followed without a new enable.
    MODEL_SWAP = "model_swap"
    #: No model is loaded.
    NO_MODEL = "no_model"
    #: The model in force was refused by ``learn`` and written only because it was forced
    #: (``--force``, the learner's ``force``), and ``allow_forced_model`` is off.
    FORCED_MODEL = "forced_model"
    #: No valid joint state was received since the start or the last fault.
    NO_STATE = "no_state"
    #: The joint states stopped arriving, or their stamps are too old.
    STALE_STATE = "stale_state"
    #: Joint states keep arriving, but their stamp no longer advances (a paused
    #: simulation, a driver repeating its stamp).
    FROZEN_STAMP = "frozen_stamp"
    #: The node clock ran backwards (a restarted simulation).
    CLOCK_JUMPED_BACK = "clock_jumped_back"
    #: A joint state stamped zero (unstamped).
    ZERO_STAMP = "zero_stamp"
    #: A joint state stamped earlier than the last accepted one.
    STAMP_BACKWARDS = "stamp_backwards"
    #: A joint state stamped longer ago than ``state_timeout_s + max_clock_skew_s``.
    STAMP_TOO_OLD = "stamp_too_old"
    #: A joint state stamped later than the clock by more than ``max_clock_skew_s``.
    STAMP_IN_FUTURE = "stamp_in_future"
    #: A joint position outside its limits by more than ``state_limit_margin``.
    POSITION_OUTSIDE_LIMITS = "position_outside_limits"
    #: A joint state message naming a joint twice.
    DUPLICATE_JOINTS = "duplicate_joints"
    #: A joint state message whose field lengths differ from its names'.
    LENGTH_MISMATCH = "length_mismatch"
    #: A joint state message with a NaN or infinite position or velocity.
    NON_FINITE_STATE = "non_finite"
    #: The control step was given positions of the wrong shape or not finite.
    STATE_INVALID = "state_invalid"
    #: The policy raised.
    POLICY_FAILED = "policy_failed"
    #: The policy returned NaN, inf or the wrong shape.
    POLICY_NOT_FINITE = "policy_not_finite"
    #: The extrapolation guard could not measure the distance to the data.
    EXTRAPOLATION_GUARD = "extrapolation_guard"
    #: Still armed, but the extrapolation guard holds the command at zero: the state is at
    #: the edge of the demonstrated data (``max_extrapolation`` or
    #: ``max_extrapolation_rad``) and the policy leads further out.
    EXTRAPOLATION_HOLD = "extrapolation_hold"
    #: Computing the constraint rows raised.
    CONSTRAINTS_FAILED = "constraints_failed"
    #: The constraint rows contain NaN or inf.
    CONSTRAINTS_NOT_FINITE = "constraints_not_finite"
    #: The smallest singular value of the constraint rows is below ``min_singular_value``.
    CONSTRAINTS_NEAR_SINGULAR = "constraints_near_singular"
    #: The control step raised (an SVD that did not converge, say).
    STEP_FAILED = "control_step_failed"
    #: A joint did not follow its command for ``stall_time_s``.
    STALL = "stall"
