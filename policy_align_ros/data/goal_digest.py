"""The learnt goal in the learn summary: a digest of the fit's goal report, and its words.

Every fit reports its learnt minima beside where the demonstrations rest
(:func:`~policy_align_ros.learning.goal.goal_summary`, stored as
``fit_summary_["goal"]``; ``docs/design/goal_report.md``). The learn pipeline
(:mod:`policy_align_ros.data.pipeline`) keeps a digest of it in the model file's
``training.pipeline`` block (:func:`goal_digest`: counts and distances, no points) and says
it in its one-line answer (:func:`goal_text`). Distances are in state units (rad for a
joint state, m for a ``frames:`` state); ``*_fraction`` values are fractions of the data's
extent.
"""

from __future__ import annotations

from typing import Any

from policy_align_ros.learning.goal import learnt_goal_index
from policy_align_ros.learning.model_io import json_floats
from policy_align_ros.learning.reach import REACH_TIME

__all__ = ["goal_digest", "goal_text"]


def goal_digest(goal: dict[str, Any] | None) -> dict[str, Any] | None:
    """The learn summary's part of ``fit_summary_["goal"]``
    (:func:`~policy_align_ros.learning.goal.goal_summary`): counts and distances (state
    units; ``*_fraction`` of the data's extent), without the points; non-finite values as
    None; ``minimum_data_fraction``: the learnt goal's distance to the nearest
    demonstration sample (the minimum :func:`~policy_align_ros.learning.goal.
    learnt_goal_index` picks; None without minima, or from a model file written before it
    was recorded). None without a goal report."""
    if not goal:
        return None
    keys = ("extent", "n_rests", "n_not_at_rest", "n_constrained_rests", "n_escaped",
            "goal_error", "goal_error_fraction", "fold_spread_max", "fold_spread_fraction",
            "n_starts_elsewhere", "n_starts_late", "n_heldout_late", "n_new_starts",
            "n_new_starts_elsewhere", "n_new_starts_late", "n_rest_places",
            "rest_spread_fraction")
    out = {key: goal.get(key) for key in keys}
    out["n_minima"] = len(goal.get("minima", ()))
    # Where no demonstrations rest together this is the one measure of the learnt goal:
    # how far from every sample the fit placed the learnt goal (an extrapolation).
    index = learnt_goal_index(goal)
    out["minimum_data_fraction"] = (None if index is None
                                    else goal["minima"][index].get("data_fraction"))
    out["n_demonstrated_goals"] = len(goal.get("demonstrated_goals", ()))
    return json_floats(out)


def _percent(fraction: float) -> str:
    """``fraction`` in % with two significant digits, without an exponent (142, not
    1.4e+02)."""
    value = 100.0 * fraction
    return f"{value:.2g}" if abs(value) < 100.0 else f"{value:.0f}"


def goal_text(digest: dict[str, Any] | None) -> str:
    """The learnt goal in words, from :func:`goal_digest` ("" without one)."""
    if not digest:
        return ""
    k = digest["n_minima"]
    text = f"learnt goal: {k} minim{'um' if k == 1 else 'a'}"
    if digest["goal_error_fraction"] is not None:
        text += (f", {_percent(digest['goal_error_fraction'])} % of the data's extent from "
                 "where the demonstrations rest")
    else:
        if digest["n_rests"] == 0:
            text += ", no demonstration ends at rest"
        elif digest["n_demonstrated_goals"] == 0:
            # The learnt speed is large at every rest: constraints held them there, or the
            # fit is wrong at all of them; the numbers cannot tell which.
            text += (f", the learnt policy still moves at all {digest['n_rests']} rests "
                     "(held by constraints, or a fit wrong there)")
        if digest.get("minimum_data_fraction") is not None:
            text += (f"; the one nearest where they end is "
                     f"{_percent(digest['minimum_data_fraction'])} % of the "
                     "data's extent from the nearest demonstration sample")
    if digest["fold_spread_fraction"] is not None:
        text += f" (spread over the CV folds {_percent(digest['fold_spread_fraction'])} %)"
    places = digest.get("n_rest_places") or 0
    if places > 1 and (digest.get("rest_spread_fraction") or 0.0) > 0.0:
        text += (f"; the demonstrations rest in {places} places up to "
                 f"{_percent(digest['rest_spread_fraction'])} % of the data's extent apart")
    if digest["n_escaped"]:
        text += f"; {digest['n_escaped']} descents found no minimum"
    if digest.get("n_starts_elsewhere"):
        text += (f"; from {digest['n_starts_elsewhere']} demonstrations' starts the policy "
                 "stops elsewhere")
    late = (digest.get("n_starts_late") or 0) - (digest.get("n_starts_elsewhere") or 0)
    if late > 0:
        text += (f"; from {late} demonstrations' starts it is still on its way after "
                 f"{REACH_TIME:g} times their duration")
    elif digest.get("n_heldout_late") and not digest.get("n_starts_elsewhere"):
        text += (f"; from {digest['n_heldout_late']} demonstrations' starts the model fitted "
                 "without them does not reach it in time: a new start may not either")
    if digest.get("n_new_starts_elsewhere"):
        text += (f"; runs from {digest['n_new_starts_elsewhere']} of {digest['n_new_starts']} "
                 "random new starts near the data stop elsewhere")
    if digest.get("n_new_starts_late"):
        text += (f"; runs from {digest['n_new_starts_late']} of {digest['n_new_starts']} "
                 f"random new starts are still on their way after {REACH_TIME:g} times the "
                 "demonstrations' median duration")
    return text
