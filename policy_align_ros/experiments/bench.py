"""``policy-align bench``: the paper's experiments and the speed/scale measurements.

Each benchmark prints a markdown table, writes it with its figure and raw numbers to
``--out``, and returns a process exit code.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from policy_align_ros.experiments.evaluation import METRIC_NAMES
from policy_align_ros.experiments.pool import parallel_map
from policy_align_ros.learning.model_io import atomic_write_text

__all__ = ["run_bench", "run_robot_bench", "run_toy_bench", "format_mean_std"]


def format_mean_std(mean: float, std: float, percent: bool = False) -> str:
    """``mean ± std`` with 4 decimals (2 for percentages)."""
    return f"{mean:.2f} ± {std:.2f}" if percent else f"{mean:.4f} ± {std:.4f}"


def _toy_table(results: dict, n_datasets: int) -> tuple[str, list[str]]:
    from policy_align_ros.experiments.toy import PAPER_TABLE_I, RULES, SETUPS

    header = (
        "| Setup | σ² | | Alignment nMSE | Potential nMSE | nUPE | nCPE | Discarded (%) "
        "| Unaligned (%) |\n"
        "|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    verdicts = []
    for potential, n_traj, n_samples in SETUPS:
        for rule in RULES:
            key = (potential, n_traj, rule)
            values = np.array([[r[rule][m] for m in METRIC_NAMES] for r in results[key]])
            mean, std = values.mean(axis=0), values.std(axis=0)
            paper = PAPER_TABLE_I[key]
            setup = f"{potential} K={n_traj} N={n_samples}"
            ours = [format_mean_std(mean[i], std[i], i >= 4) for i in range(6)]
            theirs = [format_mean_std(*paper[i], i == 4) for i in range(5)] + ["—"]
            lines.append(f"| {setup} | {rule} | ours | " + " | ".join(ours) + " |")
            lines.append("| | | paper | " + " | ".join(theirs) + " |")
            if rule in ("narrow", "medium"):
                checks = {
                    "nUPE": mean[2] <= paper[2][0],
                    "nCPE": mean[3] <= paper[3][0],
                    "discarded": mean[4] <= paper[4][0],
                    "alignment": mean[0] <= paper[0][0] + paper[0][1],
                }
                missed = [name for name, ok in checks.items() if not ok]
                verdicts.append(
                    f"{setup}, {rule}: " + ("all targets met" if not missed
                                            else "missed " + ", ".join(missed))
                )
    table = header + "\n".join(lines) + "\n"
    table += (f"\nMean ± std over {n_datasets} data sets per row; errors on a held-out 20% "
              "of the samples of the trajectories the global model uses. Unaligned: "
              "trajectories the alignment could not level (the paper's outliers, which it "
              "discards); the global model levels and keeps them.\n")
    return table, verdicts


def run_toy_bench(args: argparse.Namespace) -> int:
    """Table I of the paper (section IV-B) and a figure like its Fig. 3."""
    from policy_align_ros.experiments.toy import SETUPS, run_toy_dataset
    from policy_align_ros.experiments.toy_figure import plot_toy_figure

    n_datasets = args.datasets or 100
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tasks = [
        (potential, n_traj, n_samples, args.seed * 100_003 + 7919 * c + i)
        for c, (potential, n_traj, n_samples) in enumerate(SETUPS)
        for i in range(n_datasets)
    ]
    start = time.perf_counter()
    flat = parallel_map(run_toy_dataset, tasks, args.jobs, "bench toy")
    elapsed = time.perf_counter() - start
    results: dict = {}
    for (potential, n_traj, _, _), res in zip(tasks, flat, strict=True):
        for rule in res:
            results.setdefault((potential, n_traj, rule), []).append(res)
    table, verdicts = _toy_table(results, n_datasets)
    text = (
        f"## Table I reproduction (`policy-align bench toy --datasets {n_datasets}`)\n\n"
        + table + "\nTargets (narrow and medium rows):\n\n"
        + "\n".join(f"- {v}" for v in verdicts)
        + f"\n\nWall time: {elapsed:.0f} s with --jobs {args.jobs}.\n"
    )
    print(text)
    atomic_write_text(out / "toy.md", text)
    raw = {f"{p}_K{k}_{r}": [res[r] for res in v] for (p, k, r), v in results.items()}
    atomic_write_text(out / "toy.json", json.dumps(raw, indent=1))
    figure = plot_toy_figure(out / "toy.png", seed=args.seed)
    print(f"wrote {out / 'toy.md'}, {out / 'toy.json'} and {figure}")
    return 0


def run_robot_bench(
    args: argparse.Namespace,
    name: str,
    run: Callable[[int, int, int, int, int], list[dict]],
    format_table: Callable[[Sequence[dict]], str],
    setup: Callable[[object, object], str],
    plot_figure: Callable[[object, Path], None],
    figure_key: str,
) -> int:
    """``policy-align bench grasp|humanoid``: print and write the table, write the figure.

    Parameters
    ----------
    args : argparse.Namespace
        Has ``datasets`` (None = the paper's 50), ``jobs``, ``out``, ``seed``; tests add
        ``n_traj`` and ``n_samples`` (not CLI options: the paper's K = N = 100).
    name : str
        Stem of the files ``<out>/<name>.md``, ``.json`` and ``.png``.
    run : callable
        ``run(datasets, jobs, seed, n_traj, n_samples)``: one metrics dict per data set.
    format_table : callable
        The markdown table of ``run``'s results.
    setup : callable
        ``setup(K, N)``: the line under the table that states the set-up.
    plot_figure : callable
        ``plot_figure(results[0][figure_key], path)`` draws the figure.
    figure_key : str
        The key of data set 0's figure data.
    """
    datasets = 50 if args.datasets is None else int(args.datasets)
    if datasets < 1:
        raise ValueError(f"--datasets: must be >= 1, got {datasets}")
    jobs = max(1, int(getattr(args, "jobs", 2) or 1))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    n_traj, n_samples = getattr(args, "n_traj", 100), getattr(args, "n_samples", 100)
    t0 = time.perf_counter()
    results = run(datasets, jobs, int(getattr(args, "seed", 0) or 0), int(n_traj),
                  int(n_samples))
    elapsed = time.perf_counter() - t0
    table = format_table(results)
    table += (f"\n{setup(n_traj, n_samples)}; {datasets} data sets in {elapsed:.0f} s "
              f"with {jobs} worker(s).\n")
    print(table)
    paths = [out / f"{name}.{ext}" for ext in ("md", "json", "png")]
    atomic_write_text(paths[0], table)
    atomic_write_text(paths[1], json.dumps(
        [{k: v for k, v in r.items() if isinstance(v, float)} for r in results], indent=1))
    plot_figure(results[0][figure_key], paths[2])
    print(f"wrote {paths[0]}, {paths[1]} and {paths[2]}", file=sys.stderr)
    return 0


def run_bench(args: argparse.Namespace) -> int:
    """Dispatch ``policy-align bench WHICH``."""
    if args.jobs < 1:
        raise ValueError(f"--jobs must be at least 1, got {args.jobs}")
    if args.datasets is not None and args.datasets < 1:
        raise ValueError(f"--datasets must be at least 1, got {args.datasets}")
    if args.which == "toy":
        return run_toy_bench(args)
    if args.which == "scale":
        from policy_align_ros.experiments.scale import run_scale_bench

        return run_scale_bench(args)
    if args.which == "grasp":
        from policy_align_ros.experiments import grasp

        return grasp.main(args)
    if args.which == "humanoid":
        from policy_align_ros.experiments import humanoid

        return humanoid.main(args)
    if args.which == "suite":
        from policy_align_ros.experiments import suite

        return suite.main(args)
    if args.which == "lasa":
        from policy_align_ros.experiments import lasa

        return lasa.main(args)
    if args.which == "executor":
        from policy_align_ros.experiments import executor_bench

        return executor_bench.main(args)
    raise ValueError(f"unknown benchmark {args.which!r}")
