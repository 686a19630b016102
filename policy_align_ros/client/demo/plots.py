"""The demo's figures, made from ``report.json`` and ``traces.npz``.

``demo_distance.png``: each run's distance to its goal over simulated time, learnt policy
against expert (log scale). ``demo_hands.png`` (robots with hand frames): the hands' paths
in the x-z plane, one panel per run.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import yaml

from policy_align_ros.kinematics import Robot, TaskSpaceMap
from policy_align_ros.learning.model_io import atomic_write_bytes

__all__ = ["plot_report"]


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=120, format="png")
    plt.close(fig)
    return atomic_write_bytes(path, lambda fh: fh.write(buffer.getvalue()))


def plot_report(out: Path, report: dict, traces: dict[str, np.ndarray]) -> list[Path]:
    """``demo_distance.png`` and ``demo_hands.png`` from ``report`` and its traces."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    robot = Robot.load(report["robot"], report.get("joints") or _joints_of(out))
    frames = list(report.get("frames", []))
    hands = TaskSpaceMap(robot, frames) if frames else None
    hand_state = report["state"] == "hands"
    units = report.get("units", "rad")
    rate = float(report.get("sim", {}).get("rate_hz", 50.0))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    paths = []
    fig, ax = plt.subplots(figsize=(7, 4))
    for k, run in enumerate(report["runs"]):
        goal = traces[f"run{k}_goal"]
        color = colors[k % len(colors)]
        for key, style, label in (("q", "-", "learnt"), ("expert", "--", "expert")):
            Q = traces[f"run{k}_{key}"]
            X = hands.states(Q) if hand_state else Q
            dist = np.linalg.norm(X - goal, axis=1)
            t = traces[f"run{k}_t"] if key == "q" else np.arange(len(Q)) / rate
            ax.plot(t, dist, style, color=color, label=f"{run['id']}: {label}")
    ax.set_yscale("log")
    ax.set_xlabel("simulated time [s]")
    ax.set_ylabel(f"distance to the goal [{units}]")
    ax.set_title("Learnt policy (executor, new starts) vs expert")
    ax.legend(fontsize=7)
    fig.tight_layout()
    paths.append(_save(fig, out / "demo_distance.png"))

    if hands is not None:
        runs = report["runs"]
        fig, axes = plt.subplots(1, len(runs), figsize=(4.5 * len(runs), 4.5), squeeze=False)
        for k, (ax, run) in enumerate(zip(axes[0], runs, strict=True)):
            for key, style in (("q", "-"), ("expert", "--")):
                X = hands.states(traces[f"run{k}_{key}"])
                for j, color in zip(range(len(frames)), ("tab:green", "tab:purple"),
                                    strict=False):
                    ax.plot(X[:, 3 * j], X[:, 3 * j + 2], style, color=color,
                            label=f"{frames[j]} ({'learnt' if key == 'q' else 'expert'})")
                    ax.plot(X[-1, 3 * j], X[-1, 3 * j + 2], "o", color=color)
            if hand_state:
                goal = traces[f"run{k}_goal"]
                ax.plot(goal[0::3], goal[2::3], "k*", label="goal")
            ax.set_title(run["id"] + (" (unseen constraint)" if run["constraint"] else ""))
            ax.set_xlabel("x [m]")
            ax.set_ylabel("z [m]")
            ax.axis("equal")
        axes[0][0].legend(fontsize=6)
        fig.tight_layout()
        paths.append(_save(fig, out / "demo_hands.png"))
    return paths


def _joints_of(out: Path) -> list[str] | None:
    try:
        params = yaml.safe_load((out / "params.yaml").read_text())
        # The learner is always told its joints (the other nodes may take a robot config's).
        return list(params["learner"]["ros__parameters"]["joints"])
    except (OSError, KeyError, TypeError, yaml.YAMLError):
        return None
