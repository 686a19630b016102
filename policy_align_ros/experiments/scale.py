"""Speed and memory at scale (``policy-align bench scale``).

Data: ``K`` trajectories of ``N`` samples in ``n = 22`` dimensions following
``pi = -grad phi`` with ``phi = x^T W x``, ``W = 0.05 I``, under two random constraint rows
``A ~ N(0, I)`` (2 x n) re-drawn twice per trajectory; start states uniform in
``[-2, 2]^n``; the time step is ``dt = 100 / N`` seconds, so every trajectory covers the same
motion as the paper's 100-step trajectories, sampled more densely as ``N`` grows.

Each size is fitted in a fresh child process, which reports the fit time of every stage and
its peak resident memory (``ru_maxrss``), so one size's memory cannot hide another's.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from policy_align_ros.learning import PolicyAlign, Trajectory, metrics
from policy_align_ros.learning.model_io import atomic_write_text
from policy_align_ros.learning.outliers import largest_group

__all__ = ["make_scale_dataset", "run_scale_bench", "SIZES"]

SIZES = ((100, 100), (300, 300), (1000, 1000))
DIM = 22
TARGETS_S = {(100, 100): 2.0, (1000, 1000): 60.0}
TARGET_MB = 4096.0


def make_scale_dataset(
    n_traj: int, n_samples: int, rng: np.random.Generator, dim: int = DIM
) -> list[Trajectory]:
    """Simulate ``n_traj`` timed trajectories of ``n_samples`` states in ``dim`` dimensions."""
    dt = 100.0 / n_samples
    x = rng.uniform(-2.0, 2.0, size=(n_traj, dim))
    # Orthonormal bases of the constraint row spaces: N v = v - U U^T v.
    rows = rng.standard_normal((n_traj, 3, dim, 2))
    bases = np.linalg.qr(rows)[0]  # (K, 3, dim, 2)
    segment = np.minimum((3 * np.arange(n_samples)) // n_samples, 2)
    X = np.empty((n_traj, n_samples, dim))
    for i in range(n_samples):
        X[:, i] = x
        U = bases[:, segment[i]]
        pi = -0.1 * x
        x = x + dt * (pi - np.einsum("kdr,kr->kd", U, np.einsum("kdr,kd->kr", U, pi)))
    times = dt * np.arange(n_samples)
    return [Trajectory(X[k], times=times, name=str(k)) for k in range(n_traj)]


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _child(n_traj: int, n_samples: int, seed: int) -> dict:
    data = make_scale_dataset(n_traj, n_samples, np.random.default_rng(seed))
    after_data = _peak_mb()
    start = time.perf_counter()
    model = PolicyAlign(sigma="narrow", random_state=seed).fit(data)
    fit_s = time.perf_counter() - start
    # Ground truth: phi = 0.05 ||x||^2, pi = -0.1 x (per second), on 5000 random samples.
    rng = np.random.default_rng(seed + 1)
    # The aligned set (the others' levels come from the global model).
    aligned_set = largest_group(model.groups_)
    X = np.concatenate([data[k].positions for k in aligned_set])
    aligned = np.concatenate([model.aligned_potentials_[k] for k in aligned_set])
    pick = rng.choice(len(X), size=min(5000, len(X)), replace=False)
    accuracy = {
        "alignment_nmse": metrics.potential_nmse(aligned[pick], 0.05 * np.sum(X[pick] ** 2, 1)),
        "nupe": metrics.nupe(-0.1 * X[pick], model.policy(X[pick])),
    }
    return {
        "K": n_traj,
        "N": n_samples,
        "fit_s": fit_s,
        "stages_s": model.fit_summary_["timings_s"],
        "peak_mb": _peak_mb(),
        "data_mb": after_data,
        "kept": int(len(model.inliers_)),
        "responsibilities": model.fit_summary_["n_responsibilities"],
        **accuracy,
    }


def _run_child(n_traj: int, n_samples: int, seed: int) -> dict:
    cmd = [sys.executable, "-m", "policy_align_ros.experiments.scale",
           "--child", str(n_traj), str(n_samples), str(seed)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"scale child {n_traj}x{n_samples} failed:\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def run_scale_bench(args: argparse.Namespace) -> int:
    """Fit time and peak memory for K x N = 100x100, 300x300, 1000x1000 in 22-D."""
    repeats = args.datasets or 3
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    raw = []
    for n_traj, n_samples in SIZES:
        runs = []
        for r in range(repeats):
            print(f"bench scale: {n_traj}x{n_samples} run {r + 1}/{repeats} ...",
                  file=sys.stderr, flush=True)
            runs.append(_run_child(n_traj, n_samples, args.seed + r))
        raw.extend(runs)
        fit = statistics.median(run["fit_s"] for run in runs)
        peak = statistics.median(run["peak_mb"] for run in runs)
        stages = {
            name: statistics.median(run["stages_s"][name] for run in runs)
            for name in ("sigma", "alignment", "regression")
        }
        dense_gb = 2 * n_traj * n_traj * n_samples * 8 / 1e9
        target = TARGETS_S.get((n_traj, n_samples))
        verdict = "" if target is None else (
            f"{'met' if fit < target and peak < TARGET_MB else 'MISSED'} "
            f"(< {target:g} s, < 4 GB)"
        )
        accuracy = {name: statistics.median(run[name] for run in runs)
                    for name in ("alignment_nmse", "nupe")}
        rows.append(
            f"| {n_traj} x {n_samples} | {n_traj * n_samples:,} | {fit:.2f} | "
            f"{stages['sigma']:.2f} / {stages['alignment']:.2f} / {stages['regression']:.2f} | "
            f"{peak:.0f} | {dense_gb:.2f} | {statistics.median(r['kept'] for r in runs):.0f} "
            f"| {accuracy['alignment_nmse']:.4f} | {accuracy['nupe']:.3f} | {verdict} |"
        )
    base = statistics.median(run["fit_s"] for run in raw[:repeats])
    last = statistics.median(run["fit_s"] for run in raw[-repeats:])
    text = (
        f"## Scale (`policy-align bench scale --datasets {repeats}`)\n\n"
        f"n = {DIM}, narrow sigma, medians over {repeats} runs, each in a fresh process.\n\n"
        "| K x N | samples | fit [s] | sigma / align / regression [s] | peak RSS [MB] | "
        "dense Q, F would need [GB] | kept | alignment nMSE | nUPE | target |\n"
        "|---|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n\n"
        "Accuracy against the true potential and policy on 5000 random training samples of "
        "the kept trajectories.\n"
        f"1000x1000 is 100x the samples of 100x100 and took {last / base:.1f}x the time.\n"
    )
    print(text)
    atomic_write_text(out / "scale.md", text)
    atomic_write_text(out / "scale.json", json.dumps(raw, indent=1))
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--child":
        print(json.dumps(_child(int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]))))
    else:
        sys.exit("usage: python -m policy_align_ros.experiments.scale --child K N SEED")
