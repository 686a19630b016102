"""Benchmark of the executor's control step: joint state in, velocity command out.

Setup (issue 4): the 22 upper-body joints of example-robot-data's ``human`` model
(:data:`policy_align_ros.experiments.humanoid.JOINTS`), one plane constraint per hand
(``left_hand``, ``right_hand``, normals drawn at random), and a PolicyAlign model learnt
from a paper-sized data set of that experiment (K = 100 demonstrations of N = 100 samples,
narrow sigma). One timed step does what the executor node does per control period
besides ROS transport: match the joint state's names and positions into ``q`` (22,),
evaluate ``pi_hat(q)``, build ``A(q)`` (2, 22) from Pinocchio hand Jacobians, project,
lock limit joints, scale, and convert the command to a list for the message.

Times are wall-clock (``time.perf_counter_ns``) per step, reported in microseconds as
p50 / p99 / max over ``steps`` steps after a warm-up; the target is p99 < 1 ms (1 kHz).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from policy_align_ros.experiments.humanoid import HANDS, JOINTS, make_humanoid_dataset
from policy_align_ros.kinematics import Robot, constraint_from_spec
from policy_align_ros.kinematics.control import ControlStep, model_permutation
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.model_io import atomic_write_text

__all__ = ["main", "percentiles_us", "time_steps"]


def percentiles_us(samples_ns: np.ndarray) -> dict[str, float]:
    """p50, p99 and max of durations given in ns, in microseconds."""
    us = np.asarray(samples_ns, dtype=float) / 1e3
    return {"p50_us": float(np.percentile(us, 50)), "p99_us": float(np.percentile(us, 99)),
            "max_us": float(us.max())}


def time_steps(step, states: np.ndarray, names: list[str], steps: int, warmup: int = 200
               ) -> np.ndarray:
    """Time ``steps`` control steps cycling through ``states`` (m, n); returns ns, (steps,).

    Each step starts from a joint state as a message carries it (names and a position
    list, here in reversed order so the name matching is exercised) and ends with the
    command as a list of floats.
    """
    order = list(reversed(range(len(names))))
    msg_names = [names[i] for i in order]
    msgs = [states[k % len(states)][order].tolist() for k in range(len(states))]
    index = {name: i for i, name in enumerate(names)}
    out = np.empty(steps, dtype=np.int64)
    for k in range(-warmup, steps):
        positions = msgs[k % len(msgs)]
        start = time.perf_counter_ns()
        q = np.empty(len(index))
        for name, value in zip(msg_names, positions, strict=True):
            q[index[name]] = value
        qdot, _ = step(q)
        qdot.tolist()
        if k >= 0:
            out[k] = time.perf_counter_ns() - start
    return out


def main(args: argparse.Namespace) -> int:
    """``policy-align bench executor``: print (and write to ``args.out``) the timings."""
    seed = int(getattr(args, "seed", 0) or 0)
    steps = int(getattr(args, "steps", None) or 20000)
    n_traj = int(getattr(args, "datasets", None) or 100)
    robot = Robot.load("human", joints=JOINTS, reference={"left_elbow_Z": 0.8,
                                                          "right_elbow_Z": 0.8})
    print(f"learning a model from {n_traj} demonstrations x 100 samples (22 joints) ...",
          flush=True)
    demos, _, _ = make_humanoid_dataset(seed, n_traj=n_traj, n_samples=100)
    t0 = time.perf_counter()
    model = PolicyAlign(sigma="narrow", random_state=seed).fit(
        [d.trajectory for d in demos], joint_names=JOINTS)
    fit_s = time.perf_counter() - t0
    rng = np.random.default_rng(seed + 1)
    constraints = [constraint_from_spec({"type": "plane", "frame": hand,
                                         "normal": rng.standard_normal(3).tolist()}, robot)
                   for hand in HANDS]
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 1.0), 1e-3,
                       constraints=constraints, policy=model.policy,
                       permutation=model_permutation(model.joint_names_, JOINTS))
    states = np.concatenate([d.trajectory.positions for d in demos[:10]])
    results = {"joints": len(JOINTS), "constraint_rows": 2, "steps": steps,
               "fit_s": fit_s, "full_step": percentiles_us(time_steps(
                   step, states, list(JOINTS), steps))}
    # Where the time goes: the policy alone and the constraint matrix alone.
    policy_only = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 1.0), 1e-3,
                              policy=model.policy)
    results["policy_only"] = percentiles_us(time_steps(
        policy_only, states, list(JOINTS), steps // 4))
    results["constraints_only"] = percentiles_us(time_steps(
        lambda q: (step.constraint_matrix(q), ""), states, list(JOINTS), steps // 4))
    full = results["full_step"]
    lines = [
        "Executor control step (22 joints, one plane per hand; joint state in, command out)",
        "",
        "| part | p50 [us] | p99 [us] | max [us] |",
        "|---|---|---|---|",
    ]
    for key in ("full_step", "policy_only", "constraints_only"):
        r = results[key]
        lines.append(f"| {key} | {r['p50_us']:.1f} | {r['p99_us']:.1f} | {r['max_us']:.1f} |")
    verdict = "met" if full["p99_us"] < 1000.0 else "missed"
    # Tails on a shared machine come from preemption: say how busy it was.
    results["load_average_1min"] = os.getloadavg()[0]
    lines += ["", f"target p99 < 1000 us: {verdict} (p99 {full['p99_us']:.1f} us over "
              f"{steps} steps; model fitted in {fit_s:.1f} s; load average "
              f"{results['load_average_1min']:.1f} on {os.cpu_count()} cores)"]
    text = "\n".join(lines)
    print(text)
    out = Path(getattr(args, "out", None) or "bench_out")
    out.mkdir(parents=True, exist_ok=True)
    for name, content in (("executor_bench.md", text + "\n"),
                          ("executor_bench.json", json.dumps(results, indent=2) + "\n")):
        atomic_write_text(out / name, content)
    return 0
