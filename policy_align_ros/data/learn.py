"""``policy-align learn``: fit PolicyAlign to rosbag2 demonstrations and save the model.

Reads bags or dataset directories with :func:`policy_align_ros.data.bags.load_dataset`
(joints matched by name, split at time gaps in seconds, malformed messages skipped and
counted), fits :class:`PolicyAlign` on joint positions (rad) with times in seconds, so
the learnt policy is in rad/s, and writes the model file atomically.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from policy_align_ros.data.bags import load_dataset
from policy_align_ros.learning.policy_align import PolicyAlign

__all__ = ["parse_joints", "parse_sigma", "run_learn"]

_SIGMA_RULES = ("narrow", "medium", "wide")


def parse_sigma(text: str | float) -> str | float:
    """``"narrow" | "medium" | "wide"`` or a positive sigma^2 (squared joint units)."""
    if isinstance(text, str) and text.strip().lower() in _SIGMA_RULES:
        return text.strip().lower()
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(
            f"--sigma: expected narrow, medium, wide or a positive number, got {text!r}"
        ) from None
    if not (value > 0 and value != float("inf")):
        raise ValueError(f"--sigma: sigma^2 must be positive and finite, got {text!r}")
    return value


def parse_joints(text: str | None) -> list[str] | None:
    """Comma-separated joint names (``None`` or empty: from the first message)."""
    if text is None or not text.strip():
        return None
    names = [name.strip() for name in text.split(",")]
    if any(not name for name in names):
        raise ValueError(f"--joints: empty joint name in {text!r}")
    if len(set(names)) != len(names):
        raise ValueError(f"--joints: a joint is listed twice in {text!r}")
    return names


def run_learn(args: argparse.Namespace) -> int:
    """Run ``policy-align learn``.

    Parameters
    ----------
    args : argparse.Namespace
        ``inputs`` (list of bag or dataset paths), ``out`` (model path), ``joints``
        (comma-separated or None), ``sigma`` (rule or sigma^2), ``gap`` (seconds).

    Returns
    -------
    int
        0 on success; 2 with a message on stderr for unusable input or a failed fit.
    """
    try:
        joints = parse_joints(getattr(args, "joints", None))
        sigma = parse_sigma(getattr(args, "sigma", "medium"))
        gap = float(getattr(args, "gap", 0.5))
        trajs, names, report = load_dataset(args.inputs, joints=joints, gap_s=gap)
        if len(trajs) < 2:
            raise ValueError(
                f"{', '.join(map(str, args.inputs))}: PolicyAlign needs at least 2 "
                f"demonstrations, found {len(trajs)} ({report.summary()})"
            )
        t0 = time.perf_counter()
        model = PolicyAlign(sigma=sigma).fit(trajs, joint_names=names)
        fit_s = time.perf_counter() - t0
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        written = model.save(out)
    except (ValueError, OSError) as err:
        print(f"policy-align learn: error: {err}", file=sys.stderr)
        return 2
    kept = len(model.inliers_)
    shown = ", ".join(names[:6]) + (", ..." if len(names) > 6 else "")
    print(
        f"Learnt a potential over {len(names)} joints ({shown}) from {len(trajs)} "
        f"demonstrations ({report.summary()}). Outlier detection kept {kept} and "
        f"discarded {len(trajs) - kept}; sigma^2 = {model.sigma2_:.4g}; fit took "
        f"{fit_s:.2f} s. Model written to {written}."
    )
    return 0
