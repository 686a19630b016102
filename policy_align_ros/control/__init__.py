"""The executor's control law and safety logic, ROS-free.

``qdot = s N(q) pi_hat(q)``: the learnt policy projected onto the null space of the
constraints in force, scaled for speed and position limits. Modules:

- :mod:`.limits`: speed limits, joint velocity bounds, the limit scale and the
  acceleration ramp;
- :mod:`.guard`: the extrapolation guard and its distance to the demonstrated data;
- :mod:`.guard_hold`: the guard holding an armed robot at the data's edge, reported
  (which limit binds, how far, the fix) and logged once;
- :mod:`.locked_projection`: null-space projection with joints locked on their limits;
- :mod:`.step`: one control step (:class:`ControlStep`: projection, limit locks, drift
  correction of held frames, near-singular constraints);
- :mod:`.armed`: :class:`ArmedController`, arming, joint-state stamps and ramps on the
  caller's clock;
- :mod:`.causes`: why the command is zero, as stable identifiers (:class:`ZeroCause`);
- :mod:`.joint_order`: model and controller joint orders (the controller's answer to
  the order check included);
- :mod:`.resolved_rate` and :mod:`.task_policy`: task-space policies mapped to joint
  velocities;
- :mod:`.loading`: a model file as the executor's joint-space policy (read once at
  start, and the decisions about it there: :class:`StartModel`), its guard and turns,
  installed on the controller (:func:`install_model`);
- :mod:`.model_checks`: what the executor checks about a model it loads (written only
  because learn was forced; a learnt goal beyond the guard's reach);
- :mod:`.settings`: the executor's parameter values (constraint specs included) checked,
  built into its :class:`ArmedController` and applied to it at run time;
- :mod:`.stall`: stall detection (a joint commanded to move that does not);
- :mod:`.stamp_hints`: joint-state stamps far from the node clock, explained;
- :mod:`.stop_check`: at arming, and for constraints set while armed, whether the
  model's CV folds stop the run where it stops (:class:`ArmingStopCheck`,
  :class:`ArmedRecheck`);
- :mod:`.status`: the executor's status in words (its ``/diagnostics``, its ~/enable
  answers, its notes on rejected joint states);
- :mod:`.turns`: continuous joints' angles on the turn the model was learnt on.
"""

from policy_align_ros.control.armed import (
    IMPLAUSIBLE_POSITION,
    STAMP_REJECTIONS,
    ArmedController,
    Output,
)
from policy_align_ros.control.causes import NO_CAUSE, ZeroCause
from policy_align_ros.control.guard import (
    DEFAULT_MAX_EXTRAPOLATION,
    DEFAULT_MAX_EXTRAPOLATION_RAD,
    DistanceFn,
    ExtrapolationGuard,
    FrameSupportDistance,
    SupportDistance,
)
from policy_align_ros.control.guard_hold import GuardHold, GuardHoldLog, guard_hold
from policy_align_ros.control.joint_order import (
    NO_ORDER_CHECK,
    controller_order_refusal,
    joint_order_problem,
    model_permutation,
    order_check_off,
    unchecked_order_refusal,
)
from policy_align_ros.control.limits import (
    DEFAULT_JOINT_LIMIT_MARGIN,
    DEFAULT_STATE_LIMIT_MARGIN,
    braking_scale,
    clearance_scale,
    goal_in_margin,
    inner_limits,
    joint_velocity_bounds,
    limit_locks,
    position_outside_limits,
    ramp_toward,
    speed_limits,
    velocity_scale,
)
from policy_align_ros.control.loading import (
    StartModel,
    goal_margin_problem,
    goal_reach,
    install_model,
    learnt_goal,
    load_policy,
    model_guard,
    model_load_error,
    model_turn_centres,
    no_model_fix,
)
from policy_align_ros.control.locked_projection import constrained_command, project_with_locks
from policy_align_ros.control.model_checks import (
    GoalReach,
    forced_model_refusal,
    forced_model_warning,
    model_refusals,
)
from policy_align_ros.control.resolved_rate import (
    damped_pinv,
    joint_velocity_within_limits,
    secondary_velocity,
    task_to_joint_velocity,
)
from policy_align_ros.control.settings import (
    FLOAT_SETTINGS,
    apply_setting,
    build_controller,
    constraints_from_text,
    constraints_problem,
    setting_problem,
)
from policy_align_ros.control.stall import (
    DEFAULT_STALL_TIME_S,
    Stall,
    StallDetector,
    stall_time_problem,
)
from policy_align_ros.control.stamp_hints import clock_mismatch_hint
from policy_align_ros.control.status import (
    ClockWatch,
    arming_status,
    enable_answer,
    model_text,
    rejection_note,
    untrustworthy_reason,
)
from policy_align_ros.control.step import (
    DEFAULT_DRIFT_CLAMP_M,
    DEFAULT_DRIFT_GAIN,
    DEFAULT_MIN_SINGULAR_VALUE,
    ControlStep,
)
from policy_align_ros.control.stop_check import (
    RECHECK_SHARE,
    SLICE_S,
    ArmedRecheck,
    ArmingStopCheck,
    check_in_slices,
    fold_policies,
    stop_check_answer,
    stop_check_note,
    unchanged,
)
from policy_align_ros.control.task_policy import TaskSpacePolicy, policy_for_state
from policy_align_ros.control.turns import TURN, nearest_turn, turn_centres, wrap_continuous

__all__ = [
    "ClockWatch",
    "DEFAULT_DRIFT_CLAMP_M",
    "DEFAULT_DRIFT_GAIN",
    "DEFAULT_JOINT_LIMIT_MARGIN",
    "DEFAULT_MAX_EXTRAPOLATION",
    "DEFAULT_MAX_EXTRAPOLATION_RAD",
    "DEFAULT_MIN_SINGULAR_VALUE",
    "DEFAULT_STALL_TIME_S",
    "DEFAULT_STATE_LIMIT_MARGIN",
    "FLOAT_SETTINGS",
    "IMPLAUSIBLE_POSITION",
    "NO_CAUSE",
    "NO_ORDER_CHECK",
    "RECHECK_SHARE",
    "SLICE_S",
    "STAMP_REJECTIONS",
    "TURN",
    "ArmedController",
    "ArmedRecheck",
    "ArmingStopCheck",
    "ControlStep",
    "DistanceFn",
    "ExtrapolationGuard",
    "FrameSupportDistance",
    "GoalReach",
    "GuardHold",
    "GuardHoldLog",
    "Output",
    "Stall",
    "StallDetector",
    "StartModel",
    "SupportDistance",
    "TaskSpacePolicy",
    "ZeroCause",
    "apply_setting",
    "arming_status",
    "braking_scale",
    "build_controller",
    "check_in_slices",
    "clearance_scale",
    "clock_mismatch_hint",
    "constrained_command",
    "constraints_from_text",
    "constraints_problem",
    "controller_order_refusal",
    "damped_pinv",
    "enable_answer",
    "fold_policies",
    "forced_model_refusal",
    "forced_model_warning",
    "goal_in_margin",
    "goal_margin_problem",
    "goal_reach",
    "guard_hold",
    "inner_limits",
    "install_model",
    "joint_order_problem",
    "joint_velocity_bounds",
    "joint_velocity_within_limits",
    "learnt_goal",
    "limit_locks",
    "load_policy",
    "model_guard",
    "model_load_error",
    "model_permutation",
    "model_refusals",
    "model_text",
    "model_turn_centres",
    "nearest_turn",
    "no_model_fix",
    "order_check_off",
    "policy_for_state",
    "position_outside_limits",
    "project_with_locks",
    "ramp_toward",
    "rejection_note",
    "secondary_velocity",
    "setting_problem",
    "speed_limits",
    "stall_time_problem",
    "stop_check_answer",
    "stop_check_note",
    "task_to_joint_velocity",
    "turn_centres",
    "wrap_continuous",
    "unchanged",
    "unchecked_order_refusal",
    "untrustworthy_reason",
    "velocity_scale",
]
