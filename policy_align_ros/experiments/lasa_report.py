"""The LASA benchmark's markdown report: headline table, targets, per-shape tables.

Aggregation: a shape's nV and DTW are the means over its evaluated demonstrations (7 per
protocol); the table gives their median over shapes. Convergence is the share of all
rollouts; fit time the median over all fits. New starts: the share of the runs from every
fit's grid of starts over the field's box that converged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from policy_align_ros.experiments.lasa_methods import METHOD_LABELS

__all__ = ["summarise", "format_report", "TARGETS"]

#: Targets (leave one out, reporting shapes): median nV, median DTW (mm), % converged.
TARGETS = {"nV": 0.5, "dtw_mm": 10.0, "converged_pct": 95.0}
_SETS = ("tuning", "reporting", "multi")


def _per_shape(rows: list[dict], key: str) -> dict[str, float]:
    shapes: dict[str, list[float]] = {}
    for r in rows:
        shapes.setdefault(r["shape"], []).append(float(r[key]))
    return {s: float(np.mean(v)) for s, v in shapes.items()}


def summarise(records: Sequence[dict], method: str, protocol: str,
              shape_set: str | None = None) -> dict[str, float] | None:
    """Median over shapes of nV and DTW, % of rollouts converged, median fit time (s).

    Parameters
    ----------
    records : sequence of dict
        Records of ``lasa.run_task``.
    method, protocol : str
        Which rows.
    shape_set : {"tuning", "reporting", "multi"} or None
        Restrict to one half of the split; None: all shapes.

    Returns
    -------
    dict or None
        ``nV``, ``nV_across``, ``dtw_mm``, ``converged_pct``, ``final_mm`` (median over
        rollouts of the final distance to the goal), ``fit_s``, ``new_starts_pct`` (the
        share of the runs from every fit's grid of new starts that converged),
        ``n_shapes``, ``n_rollouts``,
        ``n_missed`` (rollouts that did not converge) and ``n_missed_silently`` (those of
        them whose fit raised no warning); None when no record matches.
    """
    rows = [r for r in records if r["method"] == method and r["protocol"] == protocol
            and (shape_set is None or r["set"] == shape_set)]
    if not rows:
        return None
    # One fit per (shape, held-out demonstration): its time and its new starts' share are
    # repeated on its records.
    def fit(r: dict) -> tuple:
        return r["shape"], r["demo"] if protocol == "loo" else -1

    fits = {fit(r): r["fit_s"] for r in rows}
    grid = {fit(r): r["new_starts_converged"] for r in rows if "new_starts_converged" in r}
    return {
        "nV": float(np.median(list(_per_shape(rows, "nV").values()))),
        "nV_across": float(np.median(list(_per_shape(rows, "nV_across").values()))),
        "dtw_mm": float(np.median(list(_per_shape(rows, "dtw_mm").values()))),
        "converged_pct": 100.0 * float(np.mean([r["converged"] for r in rows])),
        "final_mm": float(np.median([r["final_mm"] for r in rows])),
        "fit_s": float(np.median(list(fits.values()))),
        # Records written before the new-start grid have none: NaN, not an error.
        "new_starts_pct": 100.0 * float(np.mean(list(grid.values()))) if grid else math.nan,
        "n_shapes": len({r["shape"] for r in rows}),
        "n_rollouts": len(rows),
        "n_missed": sum(1 for r in rows if not r["converged"]),
        "n_missed_silently": sum(1 for r in rows
                                 if not r["converged"] and not r.get("fit_warnings")),
    }


def _headline(records, methods, protocols) -> list[str]:
    lines = ["| shapes | protocol | method | nV (median over shapes) | nV across (median) "
             "| DTW mm (median) "
             "| converged % (rollouts) | new starts converged % | final distance mm (median) "
             "| fit s (median) | shapes / rollouts |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for shape_set in (*_SETS, None):
        for protocol in protocols:
            for method in methods:
                s = summarise(records, method, protocol, shape_set)
                if s is None:
                    continue
                lines.append(
                    f"| {shape_set or 'all'} | {protocol} | {METHOD_LABELS[method]} "
                    f"| {s['nV']:.3f} | {s['nV_across']:.3f} | {s['dtw_mm']:.2f} "
                    f"| {s['converged_pct']:.0f} | {s['new_starts_pct']:.0f} "
                    f"| {s['final_mm']:.2f} "
                    f"| {s['fit_s']:.3f} | {s['n_shapes']} / {s['n_rollouts']} |")
    return lines


def _targets(records, methods) -> list[str]:
    lines = []
    for method in methods:
        s = summarise(records, method, "loo", "reporting")
        if s is None:
            continue
        verdicts = [
            f"nV {s['nV']:.3f} {'<=' if s['nV'] <= TARGETS['nV'] else '>'} "
            f"{TARGETS['nV']}",
            f"DTW {s['dtw_mm']:.2f} mm {'<=' if s['dtw_mm'] <= TARGETS['dtw_mm'] else '>'} "
            f"{TARGETS['dtw_mm']:.0f} mm",
            f"converged {s['converged_pct']:.1f} % "
            f"{'>=' if s['converged_pct'] >= TARGETS['converged_pct'] else '<'} "
            f"{TARGETS['converged_pct']:.0f} %"]
        met = (s["nV"] <= TARGETS["nV"] and s["dtw_mm"] <= TARGETS["dtw_mm"]
               and s["converged_pct"] >= TARGETS["converged_pct"])
        lines.append(f"- {METHOD_LABELS[method]}: {'all met' if met else 'missed'} "
                     f"({'; '.join(verdicts)})")
    return lines


def _silent(records, protocols) -> list[str]:
    """PolicyAlign's rollouts that missed the goal although its fit did not warn."""
    lines = []
    for protocol in protocols:
        s = summarise(records, "policy_align", protocol)
        if s is not None:
            lines.append(f"- `{protocol}`: {s['n_missed_silently']} of {s['n_rollouts']} "
                         f"rollouts ({s['n_missed']} missed the goal)")
    return lines


def _shape_table(records, methods, protocol) -> list[str]:
    rows = [r for r in records if r["protocol"] == protocol]
    shapes = {r["shape"]: r["set"] for r in rows}
    lines = ["| shape | set | " + " | ".join(METHOD_LABELS[m] for m in methods) + " |",
             "|---|---|" + "---|" * len(methods)]
    for shape, shape_set in shapes.items():
        cells = []
        for method in methods:
            mine = [r for r in rows if r["shape"] == shape and r["method"] == method]
            if not mine:
                cells.append("—")
                continue
            cells.append(f"{np.mean([r['nV'] for r in mine]):.2f} / "
                         f"{np.mean([r['dtw_mm'] for r in mine]):.1f} / "
                         f"{100 * np.mean([r['converged'] for r in mine]):.0f} %")
        lines.append(f"| {shape} | {shape_set} | "
                     + " | ".join(cells) + " |")
    return lines


def format_report(records: Sequence[dict], methods: Sequence[str],
                  protocols: Sequence[str], elapsed: float, command: str) -> str:
    """The markdown of ``lasa.md``."""
    parts = [f"## LASA handwriting (`{command}`)", "",
             *_headline(records, methods, protocols), "",
             "nV: RMS |f(x_i) - v_i| / RMS |v_i| on the evaluated demonstration's samples; "
             "nV across: the same with the part of f(x_i) across v_i alone; "
             "DTW: mean Euclidean cost along the optimal DTW path between the demonstration "
             "and the rollout's first 1.5 T (every 5th sample); converged: |x(3T) - g| < "
             "0.01 W, g the origin (with --scattered-ends the mean of the training "
             "demonstrations' ends). "
             "New starts: runs from a 9 x 9 grid over the demonstrations' box widened by "
             "15 % of W, converged by the same rule, T the demonstrations' median duration. "
             "A shape's value is the mean over its evaluated demonstrations. `all`: trained "
             "on the 7 demonstrations; `loo`: trained on 6, evaluated on the held-out one.",
             ""]
    if "loo" in protocols:
        parts += ["Targets (leave one out, reporting shapes: median nV <= 0.5, median DTW "
                  "<= 10 mm, >= 95 % converged):", "", *_targets(records, methods), ""]
    if "policy_align" in methods:
        parts += ["`PolicyAlign()`'s rollouts that missed the goal although the fit raised "
                  "no warning (all shapes):", "", *_silent(records, protocols), ""]
    for protocol in protocols:
        parts += [f"### Per shape, protocol `{protocol}` (nV / DTW mm / converged)", "",
                  *_shape_table(records, methods, protocol), ""]
    parts.append(f"Wall time: {elapsed:.0f} s.")
    return "\n".join(parts) + "\n"
