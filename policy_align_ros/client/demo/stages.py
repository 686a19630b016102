"""The demo's stages on the running graph: wait for it, record, learn, score, run.

Each stage raises :class:`~policy_align_ros.client.demo.settings.StageError` with the
reason when it fails. Times are seconds of simulated time unless called wall time.
"""

from __future__ import annotations

import json
import re
import time

import numpy as np
import yaml

from policy_align_ros.client.demo.conductor import Conductor
from policy_align_ros.client.demo.graph import Graph
from policy_align_ros.client.demo.periods import stale_ticks
from policy_align_ros.client.demo.report import build_report, score_run, sim_block
from policy_align_ros.client.demo.settings import DemoSettings, StageError, say
from policy_align_ros.client.demo.task import Task, new_starts
from policy_align_ros.data import load_dataset
from policy_align_ros.data.pipeline import holdout_split
from policy_align_ros.learning import PolicyAlign

__all__ = ["execute_run", "learn", "learning_summary", "record_demonstrations",
           "run_schedule", "run_stages", "wait_graph"]


def run_stages(s: DemoSettings, t0: float, graph: Graph, conductor: Conductor, task: Task,
               streams: dict) -> tuple[dict, dict]:
    """Every stage on the started graph; the report (without ``total_time_s``) and the
    runs' traces (``run<k>_t``, ``run<k>_q``, ``run<k>_expert``, ``run<k>_goal``)."""
    wall_per_sim = 1.0 / s.real_time_factor
    wait_graph(s, t0, graph, conductor)
    sim0 = conductor.now()
    demonstrator_ticks = record_demonstrations(s, t0, graph, conductor)

    demos, _, _ = load_dataset([s.out / "demos"], joints=s.joints)
    names = [str(d.name) for d in demos]
    demonstration_periods = stale_ticks(demos)
    if len(demos) != s.demos:
        raise StageError(f"{len(demos)} demonstrations on disk, {s.demos} were recorded")
    model = learn(s, t0, graph, conductor, len(demos))
    learnt = learning_summary(model, s, names)
    say(t0, f"learnt: {json.dumps(learnt['demonstrations'])[:200]}; sigma^2 "
            f"{learnt['sigma2']:.4g}; fit {learnt['fit_time_s']:.2f} s")
    fresh = task.fresh_ncpe(model, streams["fresh"])
    say(t0, f"held-out nCPE on {s.fresh_demos} fresh demonstrations: {fresh:.4g}")

    recorded_starts = np.array([d.positions[0] for d in demos])
    runs, traces, executor_periods = run_schedule(s, t0, conductor, task, streams["starts"],
                                                  recorded_starts, wall_per_sim)
    sim = sim_block(s, conductor.now() - sim0, executor_periods, demonstrator_ticks,
                    demonstration_periods)
    return build_report(s, task, learnt, fresh, runs, sim), traces


def run_schedule(s: DemoSettings, t0: float, conductor: Conductor, task: Task,
                 rng: np.random.Generator, recorded_starts: np.ndarray, wall_per_sim: float
                 ) -> tuple[list[dict], dict[str, np.ndarray], tuple[int, int]]:
    """``free_runs`` unconstrained runs, then ``held_runs`` under the robot config's unseen
    constraint (else the first frame, or the first joint, held in place), from new starts
    away from ``recorded_starts`` (K, n).

    Returns the runs' report entries, their traces and the executor's ``(periods,
    missed)`` over all runs.
    """
    starts = new_starts(task, rng, s.free_runs + s.held_runs, recorded_starts)
    held = list(s.unseen_constraint) or (
        [{"type": "position", "frame": s.frames[0]}] if s.frames else
        [{"type": "joints", "joints": s.joints[:1]}])
    plan = [("unconstrained", []) for _ in range(s.free_runs)] + \
        [("unseen_constraint", held) for _ in range(s.held_runs)]
    runs, traces, ticks, missed = [], {}, 0, 0
    for k, ((name, specs), q0) in enumerate(zip(plan, starts, strict=True)):
        run_id = f"{name}_{sum(1 for other, _ in plan[:k + 1] if other == name)}"
        run, trace = execute_run(s, t0, conductor, task, run_id, specs, q0, wall_per_sim)
        separation = float(np.min(np.linalg.norm(recorded_starts - q0, axis=1)))
        run["start_separation_rad"] = round(separation, 4)
        runs.append(run)
        ticks += run.pop("_ticks")
        missed += run.pop("_missed")
        traces.update({f"run{k}_{key}": value for key, value in trace.items()})
    return runs, traces, (ticks, missed)


def execute_run(s: DemoSettings, t0: float, conductor: Conductor, task: Task, run_id: str,
                specs: list[dict], q0: np.ndarray, wall_per_sim: float
                ) -> tuple[dict, dict[str, np.ndarray]]:
    """One executor run from ``q0`` under ``specs``; the run's report entry and traces.

    The entry carries the run's executor periods as ``_ticks`` and ``_missed``.
    """
    times, Q = _drive(s, t0, conductor, run_id, specs, q0, wall_per_sim)
    ticks, missed = conductor.ticks, conductor.missed
    conductor.spin_sim(1.0, 30.0)  # the executor ramps its command down to zero
    run, expert, goal = score_run(s, task, run_id, specs, q0, Q)
    run["_ticks"], run["_missed"] = ticks, missed
    say(t0, f"run {run_id}: distance to goal {run['start_distance']:.4g} -> "
            f"{run['final_distance']:.4g} (expert {run['expert_final_distance']:.4g})"
            + (f"; held frame drift {run['held_frame_drift_mm']:.2f} mm"
               if run.get("held_frame") else ""))
    return run, {"t": times, "q": Q, "expert": expert, "goal": goal}


def _drive(s: DemoSettings, t0: float, conductor: Conductor, run_id: str,
           specs: list[dict], q0: np.ndarray, wall_per_sim: float
           ) -> tuple[np.ndarray, np.ndarray]:
    """Reset the robot to ``q0``, enable the executor for ``run_duration_s`` under
    ``specs``; the run's times (s from arming) and joint positions (T, n)."""
    conductor.set_parameter("/sim_robot", "initial_positions", q0.tolist())
    conductor.trigger("/sim_robot/reset")
    conductor.set_parameter("/executor", "constraints", yaml.safe_dump(
        specs, default_flow_style=True).strip())
    conductor.spin_sim(0.3, 10.0 + 0.3 * wall_per_sim * 20)
    conductor.listen(True)
    conductor.trace, conductor.ticks, conductor.missed = [], 0, 0
    response = conductor.enable(True)
    deadline = time.monotonic() + 10.0
    while not response.success and time.monotonic() < deadline:
        # After the reset the executor may not have taken a fresh joint state yet (a loaded
        # machine delays it); it refuses with the reason, and a retry is safe.
        conductor.spin_sim(4.0 / s.rate_hz, 10.0)
        response = conductor.enable(True)
    if not response.success:
        raise StageError(f"executor refused to enable: {response.message}")
    # The run's clock starts once ~/enable has armed: its checks before arming (the
    # controller's joint order, where the run will stop) take up to seconds on a loaded
    # machine, with the robot at rest at q0, and are not the policy's motion.
    start_sim = conductor.now()
    say(t0, f"executor run {run_id} for {s.run_duration_s:g} s of sim time"
            + (f" under {specs}" if specs else ""))
    conductor.spin_sim(s.run_duration_s, 30.0 + 20.0 * s.run_duration_s * wall_per_sim)
    conductor.enable(False)
    trace, conductor.trace = conductor.trace, None
    conductor.listen(False)
    if len(trace) < 2:
        raise StageError(f"no joint states during run {run_id}")
    times = np.array([t for t, _ in trace]) - start_sim
    Q = np.array([q for _, q in trace])
    # From the last state before the request to the last one within the run.
    first = max(int(np.searchsorted(times, 0.0, side="right")) - 1, 0)
    inside = np.arange(len(times)) >= first
    inside &= times <= s.run_duration_s + 1e-9
    return np.maximum(times[inside], 0.0), Q[inside]


def wait_graph(s: DemoSettings, t0: float, graph: Graph, conductor: Conductor) -> None:
    """Wait (at most 60 s of wall time) for the first joint state and ``/clock``."""
    deadline = time.monotonic() + 60.0
    while conductor.q is None or conductor.now() <= 0.0:
        graph.check()
        if time.monotonic() > deadline:
            raise StageError("no /joint_states or /clock from sim_robot after 60 s")
        conductor.spin(0.1)
    say(t0, "graph up: sim_robot, recorder, learner, executor, demonstrator")
    conductor.listen(False)


def record_demonstrations(s: DemoSettings, t0: float, graph: Graph, conductor: Conductor
                          ) -> dict:
    """Wait for the demonstrator to finish; its ``{"ticks", "late", "fraction"}`` count."""
    sim_start = conductor.now()
    per_demo = s.demo_duration_s + 6.0
    budget = 30.0 + s.demos * per_demo  # wall seconds
    deadline = time.monotonic() + budget
    shown = ""
    while graph.procs["demonstrator"].poll() is None:
        graph.check(allow_exit=("demonstrator",))
        if conductor.progress != shown:
            shown = conductor.progress
            say(t0, f"demonstrations recorded: {shown}")
        if time.monotonic() > deadline:
            raise StageError(f"demonstrations not finished after {budget:.0f} s "
                             f"(progress {shown or '0'}):\n{graph.tail('demonstrator')}")
        conductor.spin(0.1)
    graph.check(allow_exit=("demonstrator",))
    conductor.spin(0.2)
    match = re.search(r"late_ticks=(\d+)/(\d+)", conductor.progress)
    late, ticks = (int(match.group(1)), int(match.group(2))) if match else (0, 0)
    say(t0, f"demonstrator finished: {s.demos} demonstrations recorded in "
            f"{conductor.now() - sim_start:.1f} s of sim time")
    return {"ticks": ticks, "late": late,
            "fraction": round(late / ticks, 5) if ticks else None}


def learning_summary(model: PolicyAlign, s: DemoSettings, recorded: list[str]) -> dict:
    """The demonstrations block and fit numbers, from the model file's header.

    ``training`` counts the demonstrations of the training split (``discarded`` of them
    were left out of the global model, ``unaligned`` of them were too weakly connected to
    align and levelled by the global model instead), ``held_out`` those kept for
    scoring.
    """
    training = model.fit_summary_ or {}
    pipeline = training.get("pipeline")
    if pipeline is not None:
        demos = pipeline["demonstrations"]
        train = list(demos.get("training", []))
        discarded = list(demos.get("discarded", []))
        unaligned = list(demos.get("unaligned", discarded))
        return {
            "demonstrations": {
                "recorded": len(recorded), "found": int(demos.get("found", len(recorded))),
                "training": len(train), "held_out": len(demos["held_out"]),
                "discarded": len(discarded), "unaligned": len(unaligned),
                "duplicates": len(demos.get("duplicates", [])),
                "held_out_names": list(demos["held_out"]), "discarded_names": discarded},
            "sigma2": float(pipeline.get("sigma2", model.sigma2_)),
            "fit_time_s": float(pipeline["fit_time_s"]),
            "heldout_ncpe_observed": pipeline.get("heldout_ncpe_observed"),
            "skipped_bags": pipeline.get("skipped_bags", []),
            "summary_source": "model header: training.pipeline",
        }
    # A model written before the shared pipeline: its header has the fit only, and the
    # learner's hold-out split is reproduced from its seed.
    n_fit = int(training.get("n_trajectories", 0))
    n_kept = int(training.get("n_inliers", n_fit))
    _, held = holdout_split(len(recorded), s.holdout_fraction, s.seed)
    return {
        "demonstrations": {"recorded": len(recorded), "training": n_fit,
                           "held_out": len(recorded) - n_fit, "discarded": n_fit - n_kept,
                           "held_out_names": [recorded[k] for k in held]},
        "sigma2": float(model.sigma2_),
        "fit_time_s": float(training.get("timings_s", {}).get("total", float("nan"))),
        "heldout_ncpe_observed": None,
        "summary_source": "model header: training (fit only)",
    }


def learn(s: DemoSettings, t0: float, graph: Graph, conductor: Conductor,
          n_recorded: int) -> PolicyAlign:
    """Call ``/learner/learn``, wait for the executor to load the model, and load it."""
    say(t0, "calling /learner/learn ...")
    conductor.trigger("/learner/learn", timeout=150.0)
    model_path = s.out / "model.npz"
    deadline = time.monotonic() + 20.0
    while conductor.get_parameter("/executor", "model_path") != str(model_path):
        graph.check(allow_exit=("demonstrator",))
        if time.monotonic() > deadline:
            raise StageError(f"executor did not load the model:\n{graph.tail('executor')}")
        conductor.spin(0.2)
    try:
        return PolicyAlign.load(model_path)
    except (OSError, ValueError) as err:
        raise StageError(f"model file unreadable: {err}") from None

