"""The LASA benchmark's figure: per shape, demonstrations, rollouts and the learnt field."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["plot_figure"]

_STYLES = {"policy_align": ("C0", "PolicyAlign rollout"), "gmr": ("C3", "GMR rollout")}


def _figure_data(results: list[dict], shape: str) -> tuple[dict | None, dict]:
    """The field of a shape's first task and the rollouts of its first protocol's tasks."""
    mine = [r for r in results if r["shape"] == shape]
    if not mine:
        return None, {}
    protocol = mine[0]["protocol"]
    field = next((r["figure"]["field"] for r in mine if r["figure"]["field"] is not None),
                 None)
    rollouts: dict[str, list[np.ndarray]] = {}
    for r in mine:
        if r["protocol"] != protocol:
            continue
        for method, paths in r["figure"]["rollouts"].items():
            rollouts.setdefault(method, []).extend(paths)
    return field, rollouts


def plot_figure(results: list[dict], shapes: list[str], path: Path) -> None:
    """One panel per shape: demonstrations (grey), rollouts of PolicyAlign (blue) and GMR
    (red, when run), and streamlines of PolicyAlign's field over the bounding box plus a
    margin. Rollouts are from each shape's first protocol (``all`` when run: the model of
    all 7 demonstrations; ``loo``: each held-out demonstration's model); the field is the
    first task's model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from policy_align_ros.experiments.figures import save_figure
    from policy_align_ros.experiments.lasa import load_shape

    cols = min(len(shapes), 7)
    rows = math.ceil(len(shapes) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols, 2.6 * rows), squeeze=False)
    for ax in axes.ravel()[len(shapes):]:
        ax.axis("off")
    for ax, shape in zip(axes.ravel(), shapes, strict=False):
        field, rollouts = _figure_data(results, shape)
        if field is not None:
            ax.streamplot(field["x"], field["y"], np.nan_to_num(field["u"]),
                          np.nan_to_num(field["v"]), color="0.75", density=0.7,
                          linewidth=0.5, arrowsize=0.5)
            ax.set_xlim(field["x"][0], field["x"][-1])
            ax.set_ylim(field["y"][0], field["y"][-1])
        for demo in load_shape(shape):
            ax.plot(*demo["positions"].T, color="0.45", lw=1.0)
        for method, (color, _) in _STYLES.items():
            for p in rollouts.get(method, []):
                ax.plot(*p.T, color=color, lw=0.8, alpha=0.8)
        ax.plot(0, 0, "k*", ms=6)
        ax.set_title(shape, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_aspect("equal", adjustable="box")
    handles = [plt.Line2D([], [], color="0.45", label="demonstrations")]
    handles += [plt.Line2D([], [], color=c, label=label) for c, label in _STYLES.values()]
    handles.append(plt.Line2D([], [], color="0.75", label="PolicyAlign field"))
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), max(2, cols)),
               fontsize=9)
    fig.tight_layout(rect=(0, 0.06 if cols < 4 else 0.03, 1, 1))
    save_figure(fig, path)
    plt.close(fig)
