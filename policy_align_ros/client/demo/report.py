"""The demo's report: each run's entry, the targets, ``report.json``'s contract (section 7
of docs/design.md), the printed report and the saved traces.

Distances are in state units (rad for ``--state joints``, m for ``--state hands``) to a
run's *goal*: the point the expert settles at from the run's start under the run's
constraint.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from policy_align_ros.client.demo.settings import DemoSettings
from policy_align_ros.client.demo.task import Task
from policy_align_ros.learning.model_io import atomic_write_bytes

__all__ = ["build_report", "report_text", "save_traces", "score_run", "sim_block",
           "target_word", "targets"]


def score_run(s: DemoSettings, task: Task, run_id: str, specs: list[dict], q0: np.ndarray,
              Q: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray]:
    """A run's report entry, the expert's run and the goal.

    Parameters
    ----------
    s : DemoSettings
    task : Task
    run_id : str
    specs : list of dict
        The run's joint-space constraint specs (empty: unconstrained).
    q0 : ndarray, shape (n,)
        The run's start (rad).
    Q : ndarray, shape (T, n)
        The executed joint positions (rad).

    Returns
    -------
    run : dict
        The run's entry of ``report["runs"]``.
    expert : ndarray, shape (run_duration_s * rate_hz + 1, n)
        The expert from ``q0`` under ``specs`` for the run's duration (rad).
    goal : ndarray, shape (d,)
        Where the expert settles (state units).
    """
    expert = task.expert_run(q0, specs, s.run_duration_s)
    settle = task.expert_run(expert[-1], specs, 6.0 * s.run_duration_s)
    goal = task.states(settle[-1])[0]
    start_d = float(task.distances(q0, goal)[0])
    final_d = float(task.distances(Q[-1], goal)[0])
    expert_d = float(task.distances(expert[-1], goal)[0])
    run = {
        "name": "unconstrained" if not specs else "unseen_constraint",
        "id": run_id, "start": "new",
        "start_distance": start_d, "final_distance": final_d,
        "expert_final_distance": expert_d,
        "constraint": specs or None, "held_frame_drift_mm": None,
        "final_distance_to_attractor": float(task.distances(Q[-1], task.goal)[0]),
        "expert_settled": bool(expert_d <= 0.01 * start_d),
        "duration_s": s.run_duration_s,
    }
    if task.hand_expert is not None:
        run["start_distance_per_hand_m"] = task.frame_distances(q0, goal)
        run["final_distance_per_hand_m"] = task.frame_distances(Q[-1], goal)
        run["expert_final_distance_per_hand_m"] = task.frame_distances(expert[-1], goal)
    held_frames = [spec["frame"] for spec in specs if spec.get("type") == "position"]
    if held_frames:
        path = np.array([task.robot.frame_position(q, held_frames[0]) for q in Q])
        drift = np.linalg.norm(path - task.robot.frame_position(q0, held_frames[0]), axis=1)
        run["held_frame"] = held_frames[0]
        run["held_frame_drift_mm"] = float(1000.0 * drift.max())
        run["held_frame_final_drift_mm"] = float(1000.0 * drift[-1])
    return run, expert, goal


def sim_block(s: DemoSettings, sim_time_s: float, executor: tuple[int, int],
              demonstrator: dict, demonstrations: tuple[int, int]) -> dict:
    """The report's ``sim`` block: simulated time and missed control periods.

    ``executor`` and ``demonstrations`` are ``(periods, missed)``; ``demonstrator`` the
    node's own ``{"ticks", "late", "fraction"}`` count.
    """
    ticks, missed = executor
    demo_ticks, demo_stale = demonstrations
    return {
        "real_time_factor": s.real_time_factor, "rate_hz": s.rate_hz,
        "sim_time_s": round(sim_time_s, 2),
        "executor_periods": ticks, "executor_missed_periods": missed,
        "executor_missed_fraction": round(missed / ticks, 5) if ticks else None,
        "demonstrator_ticks": demonstrator["ticks"],
        "demonstrator_late_ticks": demonstrator["late"],
        "demonstrator_late_fraction": demonstrator["fraction"],
        "demonstration_periods": demo_ticks, "demonstration_missed_periods": demo_stale,
        "demonstration_missed_fraction": round(demo_stale / demo_ticks, 5)
        if demo_ticks else None,
    }


def build_report(s: DemoSettings, task: Task, learnt: dict, fresh: float, runs: list[dict],
                 sim: dict) -> dict:
    """``report.json``'s content without ``total_time_s``.

    ``failure`` names the last unconstrained run that did not end closer to its goal than
    it started (when ``require_progress``), else it is empty.
    """
    failure = ""
    for run in runs:
        if s.require_progress and run["name"] == "unconstrained" and \
                not run["final_distance"] < run["start_distance"]:
            failure = (f"the learnt policy did not bring run {run['id']} closer to the goal "
                       f"({run['start_distance']:.4g} -> {run['final_distance']:.4g})")
    report = {
        "robot": s.robot,
        "robot_config": s.robot_config or None,
        "joints": list(s.joints),
        "state": s.state,
        "state_spec": task.state_spec,
        "frames": list(s.frames),
        "seed": int(s.seed),
        "demonstrations": learnt["demonstrations"],
        "sigma2": learnt["sigma2"],
        "fit_time_s": round(learnt["fit_time_s"], 3),
        "heldout_ncpe_fresh": fresh,
        "heldout_ncpe_fresh_demos": s.fresh_demos,
        "heldout_ncpe_observed": learnt["heldout_ncpe_observed"],
        "runs": runs,
        "units": "rad" if s.state == "joints" else "m",
        "goal": task.goal.tolist(),
        "run_duration_s": s.run_duration_s,
        "sim": sim,
        "learning_summary_source": learnt["summary_source"],
        "failure": failure,
    }
    report["targets"] = targets(report)
    return report


def targets(report: dict) -> dict[str, bool | None]:
    """The demo's targets from the report's numbers.

    Each is met (True), missed (False) or not measured (None, printed "not measured" and
    never counted as met): a constrained run holds no frame when its constraint is no
    ``position`` constraint, so its ``held_frame_drift_mm`` is None.
    """
    joints = report["state"] == "joints"
    out = {"heldout_ncpe_fresh <= 0.2": report["heldout_ncpe_fresh"] <= 0.2}
    for run in report["runs"]:
        key = run["id"]
        if joints and run["name"] == "unconstrained":
            out[f"{key}: final <= 10% of start and <= 0.05 rad"] = bool(
                run["final_distance"] <= 0.1 * run["start_distance"]
                and run["final_distance"] <= 0.05)
        elif joints:
            out[f"{key}: final <= expert + 0.05 rad"] = bool(
                run["final_distance"] <= run["expert_final_distance"] + 0.05)
            out[f"{key}: held frame drift <= 1 mm"] = _at_most(
                run.get("held_frame_drift_mm"), 1.0)
        elif run["name"] == "unconstrained":
            out[f"{key}: each hand <= 20 mm"] = bool(
                max(run["final_distance_per_hand_m"].values()) <= 0.02)
        else:
            out[f"{key}: each hand <= expert + 20 mm"] = bool(all(
                run["final_distance_per_hand_m"][f]
                <= run["expert_final_distance_per_hand_m"][f] + 0.02
                for f in run["final_distance_per_hand_m"]))
    return out


def _at_most(value: float | None, bound: float) -> bool | None:
    """``value <= bound``, or None when ``value`` was not measured (None)."""
    return None if value is None else bool(value <= bound)


def target_word(status: bool | None) -> str:
    """How a target's status is printed: met, MISSED or not measured (None)."""
    return "not measured" if status is None else ("met" if status else "MISSED")


def save_traces(path: Path, traces: dict[str, np.ndarray]) -> None:
    """Write ``traces`` (name -> array) to ``path`` as ``.npz``, atomically."""
    buffer = io.BytesIO()
    np.savez(buffer, **traces)
    atomic_write_bytes(path, lambda fh: fh.write(buffer.getvalue()))


def report_text(report: dict) -> str:
    """The printed report, made from a ``report.json`` dict."""
    units = report.get("units", "rad")
    demos = report["demonstrations"]
    sim = report.get("sim", {})
    lines = [
        "",
        "policy-align demo report",
        "========================",
        f"robot {report['robot']}, state {report['state']} "
        f"({report.get('state_spec', report['state'])}), seed {report.get('seed')}",
        f"demonstrations: {demos['recorded']} recorded, {demos['training']} for training "
        f"({demos['discarded']} of them discarded, "
        f"{demos.get('unaligned', demos['discarded']) - demos['discarded']} too weakly "
        f"connected to align and levelled by the global model), {demos['held_out']} held out",
        f"sigma^2: {report['sigma2']:.4g}; fit time: {report['fit_time_s']:.2f} s",
        f"held-out nCPE on {report.get('heldout_ncpe_fresh_demos', '?')} fresh "
        f"demonstrations (true N, paper's measure): {report['heldout_ncpe_fresh']:.4g}",
    ]
    if report.get("heldout_ncpe_observed") is not None:
        lines.append(f"held-out nCPE on the held-out recordings (along observed motion): "
                     f"{report['heldout_ncpe_observed']:.4g}")
    lines.append(f"runs from new starts, {report.get('run_duration_s', '?')} s each; "
                 f"distance to the goal (where the expert settles) in {units}:")
    for run in report["runs"]:
        text = (f"  {run['id']:20s} {run['start_distance']:.4f} -> "
                f"{run['final_distance']:.4f}; expert {run['expert_final_distance']:.4f}")
        if run.get("final_distance_per_hand_m"):
            text += "; per hand " + ", ".join(
                f"{v * 1000:.1f} mm" for v in run["final_distance_per_hand_m"].values())
            text += " (expert " + ", ".join(
                f"{v * 1000:.1f} mm" for v in run["expert_final_distance_per_hand_m"].values())
            text += ")"
        if run.get("held_frame_drift_mm") is not None:
            text += f"; {run['held_frame']} held, drift {run['held_frame_drift_mm']:.2f} mm"
        lines.append(text)
    if sim:
        lines.append(
            f"sim time {sim.get('sim_time_s')} s at {sim.get('real_time_factor')}x; missed "
            f"control periods: executor {sim.get('executor_missed_periods')}/"
            f"{sim.get('executor_periods')}, demonstrations "
            f"{sim.get('demonstration_missed_periods')}/{sim.get('demonstration_periods')} "
            f"(demonstrator late ticks {sim.get('demonstrator_late_ticks')}/"
            f"{sim.get('demonstrator_ticks')})")
    status = report.get("targets", {})
    if status:
        lines.append("targets: " + "; ".join(
            f"{k}: {target_word(v)}" for k, v in status.items()))
    lines.append(f"total time: {report['total_time_s']:.1f} s")
    return "\n".join(lines)

