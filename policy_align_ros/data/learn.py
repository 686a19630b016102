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
import warnings
from collections.abc import Sequence
from dataclasses import fields

from policy_align_ros.data.arguments import check_writable, parse_sigma
from policy_align_ros.data.fit_figure import figure_format, plot_fit
from policy_align_ros.data.pipeline import learn_pipeline
from policy_align_ros.data.quality import Gates

__all__ = ["EXIT_REFUSED", "parse_joints", "parse_sigma", "run_learn", "warning_lines"]

#: Distinct numerical warning texts named in their one line.
_SHOWN_NUMERICAL = 3

#: Exit status of a fit refused as degenerate.
EXIT_REFUSED = 1
#: The summary line names every joint up to this many (then the first of them).
SHOWN_JOINTS = 12


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


def _say(message: str) -> None:
    """A progress line or note of the pipeline, on stderr."""
    print(f"policy-align learn: {message}", file=sys.stderr)


def warning_lines(caught: Sequence[warnings.WarningMessage]) -> list[str]:
    """The warnings of one learning run as log lines, without source files or lines.

    Parameters
    ----------
    caught : sequence of warnings.WarningMessage
        As recorded by ``warnings.catch_warnings(record=True)``.

    Returns
    -------
    list of str
        Each text of a warning other than a ``RuntimeWarning`` once, in order; then, when
        there are ``RuntimeWarning`` (numpy's overflow or invalid value inside a fit,
        possibly thousands of them, which say nothing about the model the fit's own
        checks do not), one line counting them and naming their first distinct texts.
    """
    numerical = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    lines = list(dict.fromkeys(str(w.message) for w in caught
                               if not issubclass(w.category, RuntimeWarning)))
    if numerical:
        kinds = list(dict.fromkeys(numerical))
        shown = "; ".join(kinds[:_SHOWN_NUMERICAL])
        if len(kinds) > _SHOWN_NUMERICAL:
            shown += f"; {len(kinds) - _SHOWN_NUMERICAL} other kind(s)"
        lines.append(f"{len(numerical)} numerical warning(s) during learning ({shown})")
    return lines


def _warn(caught: list[warnings.WarningMessage]) -> None:
    """The fit's warnings as lines of this command (:func:`warning_lines`)."""
    for line in warning_lines(caught):
        print(f"policy-align learn: warning: {line}", file=sys.stderr)


def _joint_list(joints: list[str]) -> str:
    """The joints learnt, every one unless there are more than :data:`SHOWN_JOINTS`."""
    if len(joints) <= SHOWN_JOINTS:
        return ", ".join(joints)
    return f"{', '.join(joints[:SHOWN_JOINTS - 2])}, ... ({len(joints) - SHOWN_JOINTS + 2} more)"


def _grouped(skipped: list[dict]) -> dict[str, list[str]]:
    """The skipped bags by reason, in order: bags of another robot share one line."""
    out: dict[str, list[str]] = {}
    for entry in skipped:
        out.setdefault(entry["reason"], []).append(entry["bag"])
    return out


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

    caught: list[warnings.WarningMessage] = []
    try:
        try:
            sigma = parse_sigma(getattr(args, "sigma", "medium"))
        except ValueError as err:
            raise ValueError(f"--{err}") from None
        plot = getattr(args, "plot", None)
        if plot:
            figure_format(plot)  # a wrong suffix is said before the fit, not after it
            check_writable(plot, "--plot")
        robot, joints = learning_robot(getattr(args, "robot", None),
                                       parse_joints(getattr(args, "joints", None)),
                                       getattr(args, "robot_config", None))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
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
                log=_say,
            )
    except (ValueError, OSError) as err:
        _warn(caught)
        print(f"policy-align learn: error: {err}", file=sys.stderr)
        return 2
    _warn(caught)
    s = result.summary
    for reason, bags in _grouped(s["skipped_bags"]).items():
        _say(f"skipped bag {bags[0]}: {reason}" if len(bags) == 1 else
             f"skipped {len(bags)} bags ({', '.join(bags)}): {reason}")
    if plot:
        try:
            _say(f"drew the fit in {plot_fit(result.model, result.train, plot, result.held)}")
        except (ValueError, OSError) as err:  # the model is written; the figure is extra
            _say(f"could not draw {plot}: {err}")
    if result.refused:
        return EXIT_REFUSED  # the pipeline said why
    space = (" over" if s["state"] == "joints" else
             f" in the positions of frames {s['state'].split(':', 1)[1]} of {s['robot']}, "
             "moved by")
    print(f"Learnt a potential{space} {len(s['joints'])} joints "
          f"({_joint_list(s['joints'])}) from {s['demonstrations']['found']} demonstrations "
          f"found ({s['data']}): {result.line()}")
    return 0
