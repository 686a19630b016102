"""The model file a learning run would replace: may it, and how good is it (ROS-free).

Both checks read the model at ``model_path`` (:meth:`PolicyAlign.load`); an unreadable or
missing file is no obstacle. States are in the model's state units (rad or m); nCPE is
measured along the observed motion (:func:`~policy_align_ros.data.quality.observed_ncpe`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from policy_align_ros.data.quality import observed_ncpe
from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.learning.model_io import json_float

__all__ = ["check_replacement", "current_model_check"]


def check_replacement(path: Path, joints: list[str], state: str | None) -> None:
    """Refuse to replace a model learnt for other joints or another state.

    Parameters
    ----------
    path : Path
        The model file the run would write.
    joints : list of str
        The joints the run learns from, in order.
    state : str or None
        The run's state (``"joints"`` or ``"frames:F1,F2"``); None for a caller's own
        state map, compared by joints only.

    Raises
    ------
    ValueError
        Naming both joint lists and states and the fix (``--overwrite``, ``overwrite``,
        another file). A missing, unreadable or unnamed model raises nothing.
    """
    if not path.is_file():
        return
    try:
        current = PolicyAlign.load(path)
    except (ValueError, OSError):
        return  # current_model_check notes it as unreadable
    block = (current.fit_summary_ or {}).get("pipeline") or {}
    old_joints = block.get("joints") or current.joint_names_
    old_state = block.get("state") or (
        "joints" if getattr(current, "state_definition_", None) is None else None)
    if old_joints is None:
        return  # a model without names: nothing says it is for other joints
    if list(old_joints) == list(joints) and (state is None or old_state in (None, state)):
        return
    raise ValueError(
        f"model_path: {path} holds a model for {len(old_joints)} joints "
        f"({', '.join(old_joints[:6])}{', ...' if len(old_joints) > 6 else ''}; state "
        f"{old_state or 'unknown'}), this run learns {len(joints)} "
        f"({', '.join(joints[:6])}{', ...' if len(joints) > 6 else ''}; state "
        f"{state or 'custom'}): replace it with --overwrite (learner node: "
        "overwrite:=true) or write to another --out (model_path)")


def current_model_check(path: Path, model: PolicyAlign, held: list[Trajectory],
                        held_names: list[str], held_prints: list[str],
                        ncpe: float | None) -> dict[str, Any]:
    """Score the model now at ``path`` on the held-out demonstrations it was not fit on."""
    out: dict[str, Any] = {"path": str(path), "heldout_ncpe_observed": None,
                           "compared_on": [], "note": ""}
    if not path.is_file():
        out["note"] = "no current model"
        return out
    try:
        current = PolicyAlign.load(path)
    except (ValueError, OSError) as err:
        out["note"] = f"current model unreadable, not compared: {err}"
        return out

    def plain(defn: dict | None) -> dict | None:
        return None if defn is None else {k: v for k, v in defn.items() if k != "rest"}

    if (current.n_features_in_ != model.n_features_in_
            or current.joint_names_ != model.joint_names_
            or plain(getattr(current, "state_definition_", None))
            != plain(model.state_definition_)):
        out["note"] = "current model has another state, not compared"
        return out
    block = (current.fit_summary_ or {}).get("pipeline") or {}
    # Demonstrations the current model was fit on would flatter it; its own held-out and
    # new ones are fair. Recognised by content: names repeat across datasets.
    trained_on = set(block.get("training_fingerprints", []))
    if not block:
        out["note"] = "current model's training demonstrations unknown; compared on all"
    keep = [k for k, fp in enumerate(held_prints) if fp not in trained_on]
    if not keep or ncpe is None:
        out["note"] = out["note"] or "every held-out demonstration trained the current model"
        return out
    subset = [held[k] for k in keep]
    out["compared_on"] = [held_names[k] for k in keep]
    out["heldout_ncpe_observed"] = json_float(observed_ncpe(current.policy, subset), "null")
    out["new_ncpe_observed"] = json_float(observed_ncpe(model.policy, subset), "null")
    return out
