"""``policy-align learn``: fit PolicyAlign to rosbag2 demonstrations and save the model.

A thin front end of :func:`policy_align_ros.data.pipeline.learn_pipeline` (the same
pipeline the ``learner`` node runs): discovery, de-duplication, hold-out split, fit in
joint positions (rad) or stacked frame positions (m) with times in seconds, so the
learnt policy is in state units per second, the quality summary and the degenerate-fit
refusal. Exit codes: 0 model written; 1 fit refused as degenerate (the model file is left
as it was; ``--force`` writes it anyway); 2 unusable input, a failed fit, or an ``--out``
model of other joints or another state without ``--overwrite``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields

from policy_align_ros.data.fit_figure import figure_format, plot_fit
from policy_align_ros.data.pipeline import learn_pipeline, parse_sigma
from policy_align_ros.data.quality import Gates

__all__ = ["EXIT_REFUSED", "parse_joints", "parse_sigma", "run_learn"]

#: Exit status of a fit refused as degenerate.
EXIT_REFUSED = 1


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


def _gates(args: argparse.Namespace) -> Gates:
    given = {f.name: getattr(args, f.name, None) for f in fields(Gates)}
    return Gates(**{k: v for k, v in given.items() if v is not None})


def run_learn(args: argparse.Namespace) -> int:
    """Run ``policy-align learn``.

    Parameters
    ----------
    args : argparse.Namespace
        ``inputs`` (bag or dataset paths), ``out`` (model path), ``joints``
        (comma-separated or None), ``sigma`` (rule or sigma^2), ``gap`` (s), and optionally
        ``robot``, ``robot_config`` (gives ``robot`` and ``joints`` when unset),
        ``state``, ``holdout``, ``seed``, ``force``, ``overwrite``, ``plot`` (a figure
        path for :func:`~policy_align_ros.data.fit_figure.plot_fit`) and the
        :class:`Gates`
        fields (``min_sigma2_fraction``, ...; None keeps the default).

    Returns
    -------
    int
        0 on success; 1 when the fit is refused (reasons on stderr); 2 with a message on
        stderr for unusable input or a failed fit.
    """
    # Imported here: the kinematics package loads Pinocchio.
    from policy_align_ros.kinematics.robot_config import learning_robot

    try:
        try:
            sigma = parse_sigma(getattr(args, "sigma", "medium"))
        except ValueError as err:
            raise ValueError(f"--{err}") from None
        plot = getattr(args, "plot", None)
        if plot:
            figure_format(plot)  # a wrong suffix is said before the fit, not after it
        robot, joints = learning_robot(getattr(args, "robot", None),
                                       parse_joints(getattr(args, "joints", None)),
                                       getattr(args, "robot_config", None))
        result = learn_pipeline(
            args.inputs, args.out,
            joints=joints,
            sigma=sigma,
            gap_s=float(getattr(args, "gap", 0.5)),
            holdout_fraction=float(getattr(args, "holdout", 0.2)),
            seed=int(getattr(args, "seed", 0)),
            state=getattr(args, "state", "joints") or "joints",
            robot=robot,
            gates=_gates(args),
            force=bool(getattr(args, "force", False)),
            overwrite=bool(getattr(args, "overwrite", False)),
        )
    except (ValueError, OSError) as err:
        print(f"policy-align learn: error: {err}", file=sys.stderr)
        return 2
    s = result.summary
    if s.get("constant_joints"):
        print(f"policy-align learn: left out constant joint(s) "
              f"{', '.join(s['constant_joints'])}: they never move in any demonstration "
              "(name the joints with --joints to keep them)", file=sys.stderr)
    for entry in s["skipped_bags"]:
        print(f"policy-align learn: skipped bag {entry['bag']}: {entry['reason']}",
              file=sys.stderr)
    for copy, original in s["duplicate_of"].items():
        print(f"policy-align learn: skipped duplicate {copy} (same as {original})",
              file=sys.stderr)
    if plot:
        try:
            print(f"policy-align learn: drew the fit in "
                  f"{plot_fit(result.model, result.train, plot, result.held)}")
        except (ValueError, OSError) as err:  # the model is written; the figure is extra
            print(f"policy-align learn: could not draw {plot}: {err}", file=sys.stderr)
    if result.refused:
        print(f"policy-align learn: {result.line()}", file=sys.stderr)
        return EXIT_REFUSED
    shown = ", ".join(s["joints"][:6]) + (", ..." if len(s["joints"]) > 6 else "")
    space = ("" if s["state"] == "joints" else
             f" in the positions of frames {s['state'].split(':', 1)[1]} of {s['robot']}, "
             "moved by")
    print(f"Learnt a potential{space} over {len(s['joints'])} joints ({shown}) from "
          f"{s['demonstrations']['found']} demonstrations found ({s['data']}): "
          f"{result.line()}")
    return 0
