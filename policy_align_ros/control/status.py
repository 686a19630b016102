"""The executor's status in words, ROS-free: what its ``/diagnostics`` message says, its
~/enable answers and its notes on rejected joint states."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence

import numpy as np

from policy_align_ros.control.armed import ArmedController
from policy_align_ros.control.causes import NO_CAUSE, ZeroCause
from policy_align_ros.control.guard_hold import guard_hold
from policy_align_ros.control.model_checks import forced_model_warning
from policy_align_ros.control.step import ControlStep

__all__ = ["ERROR", "OK", "WARN", "ClockWatch", "arming_status", "enable_answer",
           "held_error_text", "model_text", "rejection_note", "untrustworthy_reason"]

#: Levels of :func:`arming_status`, as diagnostic_msgs/DiagnosticStatus numbers them.
OK, WARN, ERROR = 0, 1, 2


class ClockWatch:
    """Whether the node clock advances, told on a steady clock: a paused simulation stops
    the node clock (``use_sim_time``), and with it every timer on it, so the status says
    so rather than falling silent.

    Parameters
    ----------
    period_ns : int
        The status period (ns, steady clock); a node clock standing still for longer is
        reported.
    """

    def __init__(self, period_ns: int) -> None:
        self.period_ns = int(period_ns)
        self._node_ns: int | None = None
        self._since_ns = 0

    def update(self, node_ns: int, steady_ns: int) -> str:
        """``"advancing"``, or for how long the node clock ``node_ns`` has stood still by
        the steady clock ``steady_ns`` (both ns) when longer than a period."""
        if node_ns != self._node_ns:
            self._node_ns, self._since_ns = int(node_ns), int(steady_ns)
        still = steady_ns - self._since_ns
        if node_ns == 0:
            return "no /clock received yet (use_sim_time): no control step runs"
        if still <= self.period_ns:
            return "advancing"
        return (f"not advancing for {still / 1e9:.1f} s (simulation paused?): no control "
                "step runs, and the controller holds the last command sent (zero when "
                "disarmed)")


def held_error_text(controller: ArmedController) -> str:
    """Largest error of the held frames from their references (mm), or "none"."""
    step = controller.step
    q = controller.last_q
    if not step.holding or q is None:
        return "none"
    return f"{1e3 * float(np.max(np.abs(step.hold_errors(q)), initial=0.0)):.3f}"


def arming_status(controller: ArmedController, now_ns: int, *, model: str, model_state: str,
                  constraints: str, rejected: Mapping[str, int], checking: bool = False
                  ) -> tuple[int, str, dict[str, str]]:
    """``(level, message, values)`` describing ``controller`` at ``now_ns`` (ns).

    Parameters
    ----------
    controller : ArmedController
    now_ns : int
        The caller's clock, ns (for the joint states' freshness).
    model, model_state, constraints : str
        The model file, its state ("joints" or "frames F1, F2") and the constraint specs
        in force, empty when none.
    rejected : mapping str -> int
        Rejected joint-state messages by reason.
    checking : bool
        A check of constraints set while armed runs (:class:`.stop_check.ArmedRecheck`).

    Returns
    -------
    level : int
        :data:`ERROR` when disarmed by a stall (the robot did not follow its command),
        :data:`WARN` when disarmed by another fault, while a forced model that is not
        allowed is loaded (it cannot be armed), while armed but held at the data's edge
        by the extrapolation guard or on a run whose stop the fold-stop check found
        uncertain (:mod:`.stop_check`); :data:`OK` otherwise.
    message : str
        Armed, held, ramping down or at zero, with the reason.
    values : dict str -> str
        Key-value pairs, in display order; ``zero_cause`` is the
        :class:`~policy_align_ros.control.causes.ZeroCause` value of ``zero_reason``, or
        :data:`~policy_align_ros.control.causes.NO_CAUSE` while armed and following the
        policy. While armed with the command held at zero by the guard
        (:func:`~policy_align_ros.control.guard_hold.guard_hold`) they are
        ``extrapolation_hold`` and the hold in words (``extrapolation_hold`` names the
        limit that binds); while disarmed at zero with a forced model that is not allowed,
        ``forced_model`` and the refusal (unless a stall's report stands).
        ``stop_spread`` and ``stop_uncertain``: the fold-stop check's, at the last arming
        or of constraints set since (``n/a``: none ran; ``checking``: it runs).
    """
    problem = controller.state_problem(now_ns)
    reason, cause = controller.zero_reason, controller.zero_cause
    faulted = not controller.armed and controller.faulted
    level = (ERROR if controller.stalled else WARN) if faulted else OK
    hold = guard_hold(controller)
    gate_cause, gate_reason = controller.step.model_check()
    if hold is not None:
        reason, cause, level = hold.text, ZeroCause.EXTRAPOLATION_HOLD, WARN
    elif (gate_cause == ZeroCause.FORCED_MODEL and not controller.armed
          and not controller.publishing and not controller.stalled):
        # What keeps it at zero now: ~/enable is refused until the model is allowed.
        reason, cause, level = gate_reason, gate_cause, WARN
    spread = controller.stop_spread
    uncertain = hold is None and controller.armed and spread is not None and spread.uncertain
    if uncertain:
        level = max(level, WARN)
    message = _message(controller, hold is not None, uncertain, reason)
    values = {
        "armed": str(controller.armed).lower(),
        "model": model or "(none)",
        "model_state": model_state or "(none)",
        "zero_reason": reason,
        "zero_cause": NO_CAUSE if cause is None else cause.value,
        "stalled": str(not controller.armed and controller.stalled).lower(),
        "stall_time_s": (f"{controller.stall.stall_time_s:g}" if controller.stall is not None
                         and controller.stall.enabled else "off"),
        "ramp_scale": f"{controller.ramp_scale:.3f}",
        **_guard_values(controller),
        "extrapolation_hold": "none" if hold is None else hold.limit,
        "held_frame_error_mm": held_error_text(controller),
        "max_abs_command_rad_s": f"{float(np.max(np.abs(controller.command))):.4f}",
        "max_acceleration_rad_s2": f"{controller.max_acceleration:g}",
        "constraints": constraints,
        "joint_states": problem or "fresh",
        "rejected_joint_states": ", ".join(
            f"{k}={v}" for k, v in sorted(rejected.items())) or "0",
        **_model_values(controller.step, model),
        **_stop_values(spread, checking),
    }
    return level, message, values


def _message(controller: ArmedController, held: bool, uncertain: bool, reason: str) -> str:
    """:func:`arming_status`'s message: armed (``held`` at the data's edge, or on a run
    whose stop is ``uncertain``), ramping down or at zero, with ``reason``."""
    if held:
        return f"armed, command held at zero: {reason}"
    if uncertain:
        return ("armed: following the policy; where it stops is uncertain (the CV folds' "
                f"stops spread over {100 * controller.stop_spread.spread:.0f} % of its "
                "travel)")
    if controller.armed:
        return "armed: following the policy"
    if controller.publishing:
        return f"disarmed, ramping down: {reason}"
    return f"disarmed, command zero: {reason}"


def _stop_values(spread, checking: bool) -> dict[str, str]:
    """The fold-stop check's ``stop_spread`` and ``stop_uncertain``."""
    if checking or spread is None:
        return dict.fromkeys(("stop_spread", "stop_uncertain"),
                             "checking" if checking else "n/a")
    return {"stop_spread": _measured(spread.spread, ".3f"),
            "stop_uncertain": str(spread.uncertain).lower()}


def _guard_values(controller: ArmedController) -> dict[str, str]:
    """The extrapolation guard's scale and distances at the last step (``off`` without a
    guard)."""
    guard = controller.step.guard
    if guard is None:
        return dict.fromkeys(("extrapolation_scale", "extrapolation_distance",
                              "extrapolation_distance_rad"), "off")
    return {"extrapolation_scale": f"{controller.extrapolation_scale:.3f}",
            "extrapolation_distance": _measured(controller.step.extrapolation_distance, ".2f"),
            "extrapolation_distance_rad": _measured(guard.last_distance_rad, ".3f")}


def _measured(value: float, spec: str) -> str:
    """``value`` formatted, or ``n/a`` before the first step has measured it (NaN)."""
    return format(value, spec) if math.isfinite(value) else "n/a"


def _model_values(step: ControlStep, model: str) -> dict[str, str]:
    """The ``/diagnostics`` values of what was found about the model in force when it was
    loaded: forced (``model_forced``, ``allow_forced_model``), its learnt goal's distance
    to the data and the guard's reach that way (``goal_distance_rad``,
    ``goal_reach_rad``, ``goal_beyond_guard``; ``n/a`` when not measured) and both in
    words (``model_warnings``)."""
    warnings = []
    if step.model_refusals:
        warnings.append(forced_model_warning(model, step.model_refusals,
                                             step.allow_forced_model))
    goal, guard = step.goal_reach, step.guard
    distance = reach = beyond = "n/a"
    if goal is not None and guard is not None:
        limits = (guard, step.max_velocity, step.max_acceleration)
        reach_rad = goal.reach_rad(*limits)[0]
        distance = f"{goal.distance_rad:.3f}"
        reach = f"{reach_rad:.3f}" if math.isfinite(reach_rad) else "inf"
        beyond = str(goal.beyond(*limits)).lower()
        warnings.append(goal.problem(*limits))
    return {
        "model_forced": str(bool(step.model_refusals)).lower(),
        "allow_forced_model": str(step.allow_forced_model).lower(),
        "goal_distance_rad": distance,
        "goal_reach_rad": reach,
        "goal_beyond_guard": beyond,
        "model_warnings": "; ".join(w for w in warnings if w) or "none",
    }


def model_text(model_path: str) -> str:
    """The model in force, for the ~/enable answers: its file, or that there is none."""
    return f"model {model_path}" if model_path else "no model loaded"


def enable_answer(accepted: bool, reason: str, note: str, model_path: str) -> str:
    """The ~/enable answer to an enable request: ``accepted`` with the model in force and
    ``note`` (the joint order check off), else the refusal ``reason`` (with the model,
    when one is loaded)."""
    model = model_text(model_path)
    if accepted:
        return f"enabled ({model}){note}"
    return f"refused: {reason}" + (f" ({model})" if model_path else "")


def rejection_note(reason: str, total: int, hint: str = "") -> tuple[bool, str]:
    """``(routine, text)``: the note on a joint state rejected for ``reason``, the
    ``total`` rejected so far and ``hint`` (how to fix it, may be empty); ``routine``
    when it is worth no warning."""
    text = f"joint state rejected: {reason} ({total} rejected so far)"
    text += f"; {hint}" if hint else ""
    # Another publisher's joints on the same topic are normal; everything else is not.
    return reason == "unknown_joints", text


def untrustworthy_reason(key: str, joints: Sequence[str], names: Sequence[str],
                         positions: Sequence[float], velocities: Sequence[float] = (),
                         efforts: Sequence[float] = ()) -> str:
    """Why a joint-state message was rejected as broken (``key``, one of
    :data:`~policy_align_ros.data.messages.UNTRUSTWORTHY`), naming what is broken.

    Parameters
    ----------
    key : str
        ``non_finite`` (then the controlled ``joints`` whose position or velocity is NaN
        or infinite are named, with the value), ``duplicate_joints`` (the names given more
        than once) or ``length_mismatch`` (the lengths).
    joints : sequence of str
        The controlled joints (only theirs are checked for finite values).
    names, positions, velocities, efforts : sequences
        The message's fields.
    """
    detail = ""
    if key == "non_finite":
        index = {name: i for i, name in reversed(list(enumerate(names)))}
        bad = []
        for joint in joints:
            i = index.get(joint)
            for field, values in (("position", positions), ("velocity", velocities)):
                if i is not None and i < len(values) and not math.isfinite(values[i]):
                    bad.append(f"{joint} {field} {values[i]}")
        detail = ", ".join(bad)
    elif key == "duplicate_joints":
        detail = ", ".join(f"{name!r} {count} times"
                           for name, count in Counter(names).items() if count > 1)
    elif key == "length_mismatch":
        detail = (f"{len(names)} names, {len(positions)} positions, {len(velocities)} "
                  f"velocities, {len(efforts)} efforts")
    return f"untrustworthy joint state: {key}" + (f": {detail}" if detail else "")
