"""What a model file holds, in words: ``policy-align show MODEL``.

Before a model drives a robot, its user wants to know what it was learnt on and how the
learner judged it, without Python: the robot and joints, the learn summary the learner
printed when it wrote the file (made again from the header), whether it was written
despite a refusal (``--force``; the executor will not arm on it unless told to), and the
learnt goal in joint (or frame) coordinates. Everything comes from the file's header and
arrays (:meth:`~policy_align_ros.learning.PolicyAlign.load`, no pickle); nothing is
fitted or imported from ROS or Pinocchio.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.fold_stops import check_horizon
from policy_align_ros.learning.goal import learnt_goal_index
from policy_align_ros.learning.policy_file import model_robot_fields

__all__ = ["model_report", "report_lines", "run_show"]


def model_report(path: str | Path) -> dict[str, Any]:
    """What :func:`run_show` prints, as JSON-able values.

    Parameters
    ----------
    path : str or Path
        A model file written by ``PolicyAlign.save`` or the learn pipeline.

    Returns
    -------
    dict
        ``path``; ``robot`` (str or None); ``joints`` (list of str or None); ``state``
        (``"joints"``, ``"frames:..."`` or None); ``n_dims``; ``learn_summary``: the line
        the learner printed (None for a file written outside the learn pipeline);
        ``forced`` (bool) and ``refusals`` (list of str): written despite these;
        ``learnt_goal``: {name: value} in the state's coordinates (state units), None
        without a minimum; ``n_minima``; ``tracking_lag_s``; ``timing_scales``;
        ``continuous_joints``: the robot's continuous joints the learner put on one turn
        (their angles, which drivers report modulo a turn, are learnt and executed there);
        ``n_fold_models``: the CV folds' models kept (0: a file written before they were);
        ``stop_checked``: whether the executor checks a run's stop with them at arming
        (also not for an untimed model, :func:`~policy_align_ros.learning.fold_stops.
        check_horizon`).

    Raises
    ------
    ValueError, FileNotFoundError
        For a file that is no readable model file (the message names it).
    """
    path = Path(path)
    model = PolicyAlign.load(path)
    robot, joints = model_robot_fields(model)
    summary = model.fit_summary_ or {}
    block = summary.get("pipeline") or {}
    goal = summary.get("goal") or {}
    minima = goal.get("minima") or []
    index = learnt_goal_index(goal) if minima else None
    point = None if index is None else minima[index].get("point")
    n = int(np.asarray(model.support_states_).shape[1])
    names = _coordinate_names(model, n)
    refusals = [str(r) for r in block.get("refusals") or []]
    return {
        "path": str(path),
        "robot": robot,
        "joints": joints,
        "state": block.get("state"),
        "n_dims": n,
        "learn_summary": _learn_line(block, model, path) if block else None,
        "forced": bool(block.get("forced")),
        "refusals": refusals,
        "learnt_goal": (None if point is None
                        else {name: float(v) for name, v in zip(names, point, strict=True)}),
        "n_minima": len(minima),
        "tracking_lag_s": summary.get("tracking_lag"),
        "timing_scales": summary.get("timing_scales"),
        "continuous_joints": [str(j) for j in block.get("continuous_joints") or []],
        "n_fold_models": len(model.fold_regressors_),
        "stop_checked": bool(model.fold_regressors_) and check_horizon(model) is not None,
    }


def report_lines(report: dict[str, Any]) -> list[str]:
    """:func:`model_report` for a human, one fact per line."""
    lines = [f"model {report['path']}"]
    lines.append(f"robot: {report['robot'] or 'none named (learnt without --robot)'}")
    joints = report["joints"]
    lines.append(f"state: {report['state'] or 'joints'}, {report['n_dims']} coordinates"
                 + (f" over the joints {', '.join(joints)}" if joints else ""))
    if report["forced"]:
        lines.append("FORCED: written although the learner refused it: "
                     + "; ".join(report["refusals"])
                     + " (the executor arms on it only with allow_forced_model:=true)")
    if report["learn_summary"]:
        lines.append(f"learn summary: {report['learn_summary']}")
    else:
        lines.append("learn summary: none (written by PolicyAlign.save, not by "
                     "policy-align learn or the learner node)")
    goal = report["learnt_goal"]
    if goal is None:
        lines.append("learnt goal: none (the learnt potential has no minimum)")
    else:
        more = report["n_minima"] - 1
        lines.append("learnt goal: " + ", ".join(f"{k} {v:.4g}" for k, v in goal.items())
                     + (f" ({more} other minim{'um' if more == 1 else 'a'})" if more else ""))
    if report["continuous_joints"]:
        lines.append("continuous joints, learnt on one turn: "
                     + ", ".join(report["continuous_joints"]))
    lines.append(f"fold models: {report['n_fold_models']}"
                 + (" (the executor checks where a run stops with them at ~/enable)"
                    if report["stop_checked"] else " (no stop check at ~/enable: "
                    + ("the model is untimed or has no goal report)" if report["n_fold_models"]
                       else "learn again to keep them)")))
    lag = report["tracking_lag_s"]
    if lag:
        lines.append(f"tracking lag: {1000 * lag:.0f} ms (docs/design/tracking_lag.md)")
    return lines


def run_show(args: argparse.Namespace) -> int:
    """``policy-align show MODEL [--json]``: print what the model file holds; 0, or 2 for a
    file that is no model file (raised as ValueError / FileNotFoundError to the CLI)."""
    report = model_report(args.model)
    if getattr(args, "json", False):
        print(json.dumps(report, indent=2, allow_nan=False))
    else:
        print("\n".join(report_lines(report)))
    return 0


def _coordinate_names(model: PolicyAlign, n: int) -> list[str]:
    """A name per state coordinate: those the file gives (``joint_names_``: the joints of
    a joint state, ``frame.x/y/z`` for a frames state, as the learn pipeline wrote them),
    else ``x0 .. x{n-1}``."""
    names = getattr(model, "joint_names_", None)
    return list(names) if names and len(names) == n else [f"x{k}" for k in range(n)]


def _learn_line(block: dict[str, Any], model: PolicyAlign, path: Path) -> str:
    """The learn summary line the learner printed, made again from the header's block,
    without the refusals and the path (:func:`report_lines` says those first)."""
    from policy_align_ros.data.pipeline import PipelineResult

    line = PipelineResult(block, model, path, written=True).line()
    return line.removesuffix(f"; model {path}")
