"""The one learning pipeline: rosbag2 demonstrations -> checked model file (ROS-free).

Both ``policy-align learn`` (:mod:`policy_align_ros.data.learn`) and the ``learner`` node
call :func:`learn_pipeline`, which does, in order:

1. **discovery**: bags and dataset directories are read with
   :func:`~policy_align_ros.data.bags.dataset.load_dataset` (joints matched by name, split
   at time gaps, malformed messages skipped and counted); bags that give nothing are named
   with the reason (a bag without JointState messages with its topics), a missing joint is
   named beside the joints that exist; unless ``joints`` is given, joints that never move
   (:func:`~policy_align_ros.data.selection.constant_joints`) are left out of a joint state
   and named; with a ``robot``, its continuous joints are put on one turn
   (:func:`~policy_align_ros.data.turns.unwrap_turns`: drivers report them modulo a
   turn); a model file at ``model_path`` learnt for other joints or another state is
   replaced only with ``overwrite``;
2. **de-duplication**: a bag named twice is read once, and demonstrations that are
   near-identical copies of an earlier one
   (:func:`~policy_align_ros.data.selection.find_duplicates`) are skipped and
   reported by name: identical demonstrations have a closest approach of 0, which
   collapses the kernel width of the alignment (paper eqs. 17-19);
3. **hold-out split** (:func:`~policy_align_ros.data.selection.holdout_split`), seeded;
4. **state map**: joint positions (rad) as they are, or for ``state="frames:F1,F2"`` the
   stacked positions (m) of those frames of ``robot`` computed with Pinocchio;
5. **fit** of :class:`~policy_align_ros.learning.PolicyAlign` on the training part;
6. **quality summary** and **degenerate-fit refusal**
   (:class:`~policy_align_ros.data.quality.Gates`): a sigma^2 that
   collapsed, most demonstrations discarded as outliers, or a held-out error worse than
   the current model's at ``model_path``; a refused fit never replaces that file unless
   ``force`` is set;
7. the model is written atomically with the summary in its header's ``training`` block,
   under ``"pipeline"`` (see :class:`PipelineResult` for the keys).

Notation: ``K`` demonstrations, each ``X_k`` (``N_k`` x ``n``) with times in seconds; ``n``
is the number of joints (state in rad) or ``3F`` for ``F`` frames (state in m). nCPE is
measured along the observed motion (:func:`~policy_align_ros.data.quality.observed_ncpe`),
so it needs no constraint. Each numbered step is one function (``_discover`` ...
``_write``).

Imports: numpy, scipy and :mod:`policy_align_ros.learning`, and rosbags through ``bags``. The
``frames:`` state and a joint state with a ``robot`` need Pinocchio:
:mod:`policy_align_ros.kinematics` is imported inside :func:`learn_pipeline` only for those
(or the caller passes its own ``state_map``), so this module imports without Pinocchio.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from policy_align_ros.data.arguments import (
    HOLDOUT_RANGE,
    check_state_frames,
    check_writable,
    parse_sigma,
    state_name,
)
from policy_align_ros.data.bags.dataset import DatasetReport, load_dataset
from policy_align_ros.data.current_model import check_replacement, current_model_check
from policy_align_ros.data.goal_digest import goal_digest, goal_text
from policy_align_ros.data.quality import (
    Gates,
    observed_ncpe,
    poorly_explained,
    refusals,
    zero_policy_comparison,
)
from policy_align_ros.data.selection import (
    constant_joints,
    find_duplicates,
    fingerprint,
    holdout_split,
)
from policy_align_ros.data.turns import check_jumps, unwrap_turns
from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.learning.model_io import json_float, json_floats

#: Share of the mean squared step explained by position noise from which the summary
#: line mentions it (the fit corrects for any amount; see PolicyAlign.position_noise_).
NOISY_STEPS = 0.1

__all__ = ["PipelineResult", "learn_pipeline"]


@dataclass
class PipelineResult:
    """Outcome of :func:`learn_pipeline`.

    Attributes
    ----------
    summary : dict
        The ``"pipeline"`` entry of the model header's ``training`` block (also
        ``PolicyAlign.load(model_path).fit_summary_["pipeline"]``): ``demonstrations``
        {``found`` (int, every demonstration read including copies), ``training``,
        ``held_out``, ``discarded`` (training demonstrations outlier detection dropped),
        ``duplicates`` (skipped copies; a bag named twice gives ``"NAME (repeat)"``)} as
        lists of demonstration names; ``duplicate_of`` {copy: original};
        ``training_fingerprints``
        (:func:`~policy_align_ros.data.selection.fingerprint` of each training one);
        ``cut_short_bags`` [{``bag``, ``reason``}] (damaged bags whose first part is used);
        ``skipped_bags`` [{``bag``, ``reason``}]; ``sigma2``; ``fit_time_s``;
        ``heldout_ncpe_observed`` (float or None); ``goal``
        (:func:`~policy_align_ros.data.goal_digest.goal_digest`); ``state``; ``joints``;
        ``constant_joints`` (left out because they never move); ``continuous_joints``
        (``robot``'s continuous joints, put on one turn: :mod:`~policy_align_ros.data.
        turns`); ``robot``;
        ``data`` (what was read, one line); ``current_model`` (its held-out nCPE on the
        demonstrations it was not trained on); ``gates``; ``refusals``; ``forced``.
    model : PolicyAlign
        The fitted model (also when refused; then it was not written).
    model_path : Path
        Where the model is (or would have been) written.
    written : bool
        Whether ``model_path`` now holds this model.
    refusals : list of str
        Why the fit is degenerate (empty when it passed every gate).
    train, held : lists of Trajectory
        The training and held-out demonstrations in the learnt state (the order of
        ``summary["demonstrations"]``), for :func:`~policy_align_ros.data.fit_figure.
        plot_fit`.
    """

    summary: dict[str, Any]
    model: PolicyAlign
    model_path: Path
    written: bool
    refusals: list[str] = field(default_factory=list)
    train: list[Trajectory] = field(default_factory=list)
    held: list[Trajectory] = field(default_factory=list)

    @property
    def refused(self) -> bool:
        """True when the fit was refused and the model file left as it was."""
        return bool(self.refusals) and not self.written

    def line(self) -> str:
        """One line for humans and for the ``~/learn`` answer, made from the summary."""
        s = self.summary
        demos = s["demonstrations"]
        n_train, n_out = len(demos["training"]), len(demos["held_out"])
        n_disc = len(demos["discarded"])
        n_free = len(demos.get("unaligned", ())) - n_disc
        ncpe = s["heldout_ncpe_observed"]
        text = (f"learnt from {n_train - n_disc} of {n_train} training demonstrations "
                f"({n_disc} discarded, {n_free} levelled by the global model, {n_out} held "
                f"out")
        if demos["duplicates"]:
            text += f", {len(demos['duplicates'])} duplicates skipped"
        if s["skipped_bags"]:
            text += f", {len(s['skipped_bags'])} bags skipped"
        if s.get("constant_joints"):
            text += (f", constant joint(s) {', '.join(s['constant_joints'])} left out")
        text += f"); state {s['state']}; sigma^2={s['sigma2']:.4g}; "
        noisy = s.get("noise_to_step")
        if noisy is not None and noisy >= NOISY_STEPS:
            text += f"position noise {100 * noisy:.0f} % of the mean squared step (corrected); "
        text += (f"fit {s['fit_time_s']:.2f} s; held-out nCPE "
                 + ("n/a" if ncpe is None else f"{ncpe:.4f}") + " (along observed motion")
        current = s.get("current_model") or {}
        if current.get("heldout_ncpe_observed") is not None:
            # Beside this model's own number, which it is compared with.
            text += (f"; the current model's {current['heldout_ncpe_observed']:.4f} on "
                     f"{len(current['compared_on'])} of them")
        text += ")"
        if s.get("poor_fit"):
            text += "; poor fit: it explains at most half of the held-out motion"
        poorly = s.get("poorly_explained") or {}
        if poorly:
            # One demonstration unlike the others (a reset or a jump in it) shows here.
            text += ("; held out and explained at most half (error over a zero policy's): "
                     + ", ".join(f"{k} ({v:.2f})" for k, v in poorly.items()))
        if s.get("unfixed_goal"):
            text += "; the CV folds do not fix the goal (docs/design/goal_report.md)"
        scales = s.get("timing_scales") or []
        if any(f != 1.0 for f in scales):
            text += (f"; demonstrations on their own clocks (factors {min(scales):.2f}-"
                     f"{max(scales):.2f}, docs/design/timing.md)"
                     + _odd_clocks(scales, demos["training"]))
        goal = goal_text(s.get("goal"))
        if goal:
            text += f"; {goal}"
        if self.refused:
            kept = "kept unchanged" if Path(self.model_path).exists() else "not written"
            return (f"refused: {'; '.join(self.refusals)}; {self.model_path} {kept} "
                    f"(write it anyway with --force; learner node: force:=true) [{text}]")
        prefix = f"forced despite: {'; '.join(self.refusals)}; " if self.refusals else ""
        return f"{prefix}{text}; model {self.model_path}"


#: A demonstration whose clock factor is off 1 by more than this factor is named in the
#: summary: its teacher moved at a speed the others' potential does not give it.
ODD_CLOCK = 2.0


def _odd_clocks(scales: list[float], names: list[str]) -> str:
    """The fastest and the slowest training demonstration, when their clock factors
    (``timing_scales``, one per training demonstration) are off 1 by more than
    :data:`ODD_CLOCK`; "" otherwise. A factor ``s`` scales a demonstration's potential
    drops, which its speed sets: it moved ``1 / s`` times as fast as the model."""
    if len(scales) != len(names):
        return ""
    out = []
    fast, slow = int(np.argmin(scales)), int(np.argmax(scales))
    if scales[fast] < 1.0 / ODD_CLOCK:
        out.append(f"{names[fast]} moved {1.0 / scales[fast]:.2g} times as fast as the "
                   "others' potential gives")
    if scales[slow] > ODD_CLOCK:
        out.append(f"{names[slow]} {1.0 / scales[slow]:.2g} times as fast")
    return "".join(f"; {text}" for text in out)


def _load_frames_map(robot: str, frames: list[str], joints: list[str]):
    """The Pinocchio state map for the demonstrations' joints."""
    from policy_align_ros.kinematics import LearningStateMap, Robot

    return LearningStateMap(Robot.load(robot, joints), frames)


def learn_pipeline(
    inputs: str | Path | Sequence[str | Path],
    model_path: str | Path,
    *,
    joints: Sequence[str] | None = None,
    sigma: str | float = "medium",
    gap_s: float = 0.5,
    holdout_fraction: float = 0.2,
    seed: int = 0,
    state: str = "joints",
    robot: str | None = None,
    gates: Gates | None = None,
    force: bool = False,
    overwrite: bool = False,
    state_map: Callable[[Trajectory], Trajectory] | None = None,
    log: Callable[[str], None] | None = None,
) -> PipelineResult:
    """Learn a model from rosbag2 demonstrations and write it unless the fit is degenerate.

    Parameters
    ----------
    inputs : path or sequence of paths
        Bags (directories, ``.mcap``/``.db3``) and dataset directories of bags.
    model_path : path
        Model file; written atomically (parents created) only when the fit passes the
        gates or ``force`` is set. When it exists, it is "the current model" the new fit
        must not be worse than on held-out data.
    joints : sequence of str, optional
        Joints of the state, in order (default: the joints the bags share, without those
        that never move in any demonstration, for a joint state). For a ``frames:``
        state, the robot's moving joints (the others stay at the robot's reference
        posture).
    sigma : str or float
        PolicyAlign's ``sigma`` (rule or sigma^2 in squared state units).
    gap_s : float
        Split recordings at time gaps longer than this (s).
    holdout_fraction : float in HOLDOUT_RANGE ([0, 0.5])
        Fraction of the (unique) demonstrations held out
        (:func:`~policy_align_ros.data.selection.holdout_split`).
    seed : int
        Seeds the hold-out split and the fit.
    state : str
        ``"joints"`` or ``"frames:F1,F2,..."``: learn in the stacked positions (m) of those
        frames of ``robot`` (Pinocchio, imported only then).
    robot : str, optional
        example-robot-data name or URDF path the demonstrations were recorded on;
        needed for a ``frames:`` state, and stored in the model file (``robot_``) so the
        executor knows it.
    gates : Gates, optional
        Refusal thresholds (default ``Gates()``).
    force : bool
        Write the model even when a gate refuses it (the refusals stay in the summary).
    overwrite : bool
        Replace a model at ``model_path`` learnt for other joints or another state
        (without it that is a ``ValueError`` before the fit). A model of the same joints
        and state is always replaced by a fit that passes the gates.
    state_map : callable, optional
        Maps a joint Trajectory to a state Trajectory and has ``definition() -> dict``
        (like :class:`~policy_align_ros.kinematics.task_space.LearningStateMap`); given,
        it replaces the ``frames:`` map built from ``robot``.
    log : callable, optional
        Receives progress lines.

    Returns
    -------
    PipelineResult
        Its ``summary`` (keys in :class:`PipelineResult`) is also stored in the model file.

    Raises
    ------
    ValueError
        Unusable input (the message names the path, joint, frame or parameter), fewer
        than 2 unique demonstrations, a model of other joints at ``model_path`` without
        ``overwrite``, or a failed fit.
    OSError
        When the model file cannot be written.
    """
    say = log or (lambda _msg: None)
    run = _check_arguments(inputs, model_path, sigma, state, robot, gates or Gates(), force,
                           seed, holdout_fraction, gap_s)
    if state_map is None:
        check_state_frames(run.state, robot)
    demos = _discover(run, joints, gap_s, say)
    if joints is None and run.state == "joints" and state_map is None:
        _drop_constant_joints(demos, say)
    if run.state == "joints" and state_map is None:
        _unwrap_continuous(demos, run.robot, say)
    if not overwrite:
        check_replacement(run.path, demos.joints, run.state if state_map is None else None)
    _deduplicate(demos, run, say)
    train_k, test_k = _split(demos.unique, holdout_fraction, seed)
    states = _map_states(demos, run.state, state_map, robot)
    train = [states.mapped[k] for k in train_k]
    held = [states.mapped[k] for k in test_k]
    fit = _fit(train, held, run, states, say)
    result = _summarise(demos, train_k, test_k, states, fit, train, held, run)
    return _write(result, run, say)


@dataclass(frozen=True)
class _Run:
    """The checked arguments of one :func:`learn_pipeline` run."""

    inputs: list[Path]
    path: Path
    sigma: str | float
    state: str
    robot: str | None
    gates: Gates
    force: bool
    seed: int
    holdout_fraction: float
    gap_s: float


@dataclass
class _Demos:
    """The demonstrations read (in joint space) and which of them are distinct."""

    trajs: list[Trajectory]
    joints: list[str]
    report: DatasetReport
    names: list[str]
    duplicate_of: dict[str, str] = field(default_factory=dict)
    unique: list[int] = field(default_factory=list)
    constant: list[str] = field(default_factory=list)
    continuous: list[str] = field(default_factory=list)


@dataclass
class _States:
    """The distinct demonstrations in the learnt state, by index into ``_Demos.trajs``."""

    mapped: dict[int, Trajectory]
    definition: dict | None
    coords: list[str] | None
    state: str


@dataclass
class _Fit:
    """The fitted model, its fit time (s) and its held-out nCPE (None without hold-out)."""

    model: PolicyAlign
    seconds: float
    ncpe: float | None


def _check_arguments(inputs: str | Path | Sequence[str | Path], model_path: str | Path,
                     sigma: str | float, state: str, robot: str | None, gates: Gates,
                     force: bool, seed: int, holdout_fraction: float, gap_s: float) -> _Run:
    """Check every argument before reading any data; the message names the parameter."""
    sigma = parse_sigma(sigma)
    state = state_name(state)
    low, high = HOLDOUT_RANGE
    if not (isinstance(holdout_fraction, (int, float)) and low <= holdout_fraction <= high):
        raise ValueError(f"holdout_fraction: must be in [{low:g}, {high:g}], "
                         f"got {holdout_fraction!r}")
    # Checked here: NumPy's own complaint about a negative seed names no parameter.
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: must be an integer >= 0, got {seed!r}")
    if isinstance(inputs, (str, Path)):
        inputs = [inputs]
    paths = [Path(p).expanduser() for p in inputs]
    for p in paths:
        if not p.exists():
            raise ValueError(f"{p}: no such file or directory")
    path = Path(model_path).expanduser().resolve()
    check_writable(path)
    return _Run(paths, path, sigma, state, robot, gates, force, seed, holdout_fraction,
                gap_s)


def _discover(run: _Run, joints: Sequence[str] | None, gap_s: float,
              say: Callable[[str], None]) -> _Demos:
    """Stage 1: read the bags (:func:`~policy_align_ros.data.bags.dataset.load_dataset`)."""
    trajs, names, report = load_dataset(run.inputs, joints=joints, gap_s=gap_s)
    say(f"read {report.summary()}")
    return _Demos(trajs, names, report, [d.name for d in report.demos])


def _deduplicate(demos: _Demos, run: _Run, say: Callable[[str], None]) -> None:
    """Stage 2: name the copies and keep the distinct demonstrations (in joint space:
    copies there are copies in any state).

    Raises
    ------
    ValueError
        When fewer than 2 distinct demonstrations are left.
    """
    duplicate_of = demos.duplicate_of
    for bag in demos.report.repeated_bags:
        resolved = Path(bag).resolve()
        for d in demos.report.demos:
            if Path(d.bag).resolve() == resolved:
                duplicate_of[f"{d.name} (repeat)"] = d.name
    copies = find_duplicates([t.positions for t in demos.trajs], run.gates.duplicate_tol)
    for j, i in sorted(copies.items()):
        duplicate_of[demos.names[j]] = demos.names[i]
    demos.unique = [k for k in range(len(demos.trajs)) if k not in copies]
    if duplicate_of:
        say(f"skipped {len(duplicate_of)} duplicate demonstration(s): "
            + ", ".join(f"{a} = {b}" for a, b in duplicate_of.items()))
    if len(demos.unique) < 2:
        # One demonstration read: typically one continuous ``ros2 bag record``.
        hint = ("; a recording of several demonstrations is split only at pauses in its "
                "messages longer than --gap seconds (learner: gap_s, now "
                f"{run.gap_s:g}): lower --gap below those pauses, or record one bag per "
                "demonstration (recorder ~/start_demo, ~/stop_demo)"
                if len(demos.trajs) == 1 else "")
        raise ValueError(
            f"{', '.join(map(str, run.inputs))}: PolicyAlign needs at least 2 distinct "
            f"demonstrations, found {len(demos.unique)}"
            + (f" ({len(duplicate_of)} duplicates skipped)" if duplicate_of else "")
            + f" ({demos.report.summary()}){hint}")


def _drop_constant_joints(demos: _Demos, say: Callable[[str], None]) -> None:
    """Leave joints that never move out of the state (a constant column adds a direction
    no demonstration explores, and the executor would need it on the robot)."""
    drop = constant_joints([t.positions for t in demos.trajs])
    if not drop:
        return
    keep = [k for k in range(len(demos.joints)) if k not in drop]
    demos.constant = [demos.joints[k] for k in drop]
    demos.joints = [demos.joints[k] for k in keep]
    demos.trajs = [Trajectory(t.positions[:, keep], t.times,
                              None if t.velocities is None else t.velocities[:, keep],
                              name=t.name) for t in demos.trajs]
    say(f"left out {len(drop)} constant joint(s) that never move in any demonstration: "
        f"{', '.join(demos.constant)} (name the joints to keep them: --joints; learner "
        "node: joints)")


def _unwrap_continuous(demos: _Demos, robot: str | None, say: Callable[[str], None]
                       ) -> None:
    """Put the continuous joints of ``robot`` (its URDF) on one turn in every demonstration
    (:mod:`~policy_align_ros.data.turns`): drivers report them modulo a turn. A joint
    that still jumps by more than half a turn, or faster than ten times its velocity
    limit, is refused (``check_jumps``).

    A ``robot`` that does not load with the demonstrations' joints is refused
    (``ValueError``): the model file would name a robot the executor cannot load."""
    mask, limits = np.zeros(len(demos.joints), dtype=bool), None
    if robot:
        from policy_align_ros.kinematics import Robot  # Pinocchio, only with a robot

        try:
            loaded = Robot.load(robot, demos.joints)
            mask, limits = loaded.continuous, loaded.velocity_limit
        except (ValueError, OSError) as err:
            raise ValueError(
                f"robot {robot!r} does not load with the demonstrations' joints "
                f"({', '.join(demos.joints)}): {err}; give the robot they were recorded on "
                "(--robot or --robot-config; learner node: robot or robot_config), or none "
                "(the model file then names no robot)") from None
    if mask.any():
        demos.trajs = unwrap_turns(demos.trajs, mask)
        demos.continuous = [j for j, c in zip(demos.joints, mask, strict=True) if c]
        say(f"continuous joint(s) {', '.join(demos.continuous)} put on one turn")
    check_jumps(demos.trajs, demos.names, demos.joints, robot, limits)


def _split(unique: list[int], fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """Stage 3: the training and held-out demonstrations (indices into the ones read)."""
    train_idx, test_idx = holdout_split(len(unique), fraction, seed)
    return [unique[i] for i in train_idx], [unique[i] for i in test_idx]


def _map_states(demos: _Demos, state: str,
                state_map: Callable[[Trajectory], Trajectory] | None,
                robot: str | None) -> _States:
    """Stage 4: joint positions as they are, or mapped to the ``frames:`` state (or by a
    caller's ``state_map``, the state then named after its frames)."""
    if state == "joints" and state_map is None:
        return _States({k: demos.trajs[k] for k in demos.unique}, None, list(demos.joints),
                       state)
    if state_map is None:
        state_map = _load_frames_map(robot, state.split(":", 1)[1].split(","), demos.joints)
    mapped = {k: state_map(demos.trajs[k]) for k in demos.unique}
    definition = state_map.definition()
    frames = definition.get("frames") if isinstance(definition, dict) else None
    if state == "joints":  # a caller's map: name the state after its frames
        state = "frames:" + ",".join(frames) if frames else "custom"
    dim = mapped[demos.unique[0]].n_dims
    coords = ([f"{f}.{a}" for f in frames for a in "xyz"]
              if frames and 3 * len(frames) == dim else None)
    return _States(mapped, definition, coords, state)


def _fit(train: list[Trajectory], held: list[Trajectory], run: _Run, states: _States,
         say: Callable[[str], None]) -> _Fit:
    """Stage 5: fit PolicyAlign on the training part and score it on the held-out part."""
    say(f"fitting on {len(train)} demonstrations ({len(held)} held out)")
    start = time.perf_counter()
    try:
        model = PolicyAlign(sigma=run.sigma, random_state=run.seed).fit(
            train, joint_names=states.coords)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as err:
        raise ValueError(f"fit failed on {len(train)} demonstrations: {err}") from None
    fit_s = time.perf_counter() - start
    model.state_definition_ = states.definition
    ncpe = json_float(observed_ncpe(model.policy, held), "null") if held else None
    return _Fit(model, fit_s, ncpe)


def _summarise(demos: _Demos, train_k: list[int], test_k: list[int], states: _States,
               fit: _Fit, train: list[Trajectory], held: list[Trajectory], run: _Run
               ) -> PipelineResult:
    """Stage 6: the quality summary, with the comparison to the current model and the
    degenerate-fit refusals (:func:`~policy_align_ros.data.quality.refusals`)."""
    model, report = fit.model, demos.report
    train_names = [demos.names[k] for k in train_k]
    held_names = [demos.names[k] for k in test_k]
    kept = set(int(i) for i in model.inliers_)
    discarded = [train_names[i] for i in range(len(train)) if i not in kept]
    unaligned = [train_names[i] for i in np.flatnonzero(model.groups_ != 0)]
    current = current_model_check(run.path, model, held, held_names,
                                   [fingerprint(demos.trajs[k]) for k in test_k], fit.ncpe)
    zero = zero_policy_comparison(model.policy, held) if held else None
    refused = refusals(model, run.sigma, train, unaligned, current, run.gates, zero)
    duplicate_of = demos.duplicate_of
    summary: dict[str, Any] = {
        "demonstrations": {
            "found": len(demos.trajs) + sum(n.endswith(" (repeat)") for n in duplicate_of),
            "training": train_names,
            "held_out": held_names,
            "discarded": discarded,
            "unaligned": unaligned,
            "duplicates": list(duplicate_of),
        },
        "duplicate_of": duplicate_of,
        "training_fingerprints": [fingerprint(demos.trajs[k]) for k in train_k],
        "skipped_bags": [{"bag": bag, "reason": why} for bag, why in report.skipped_bags],
        "cut_short_bags": [{"bag": bag, "reason": why} for bag, why in report.cut_short_bags],
        "sigma2": float(model.sigma2_),
        "noise_to_step": json_float(model.fit_summary_["noise_to_step"], "null"),
        "fit_time_s": float(fit.seconds),
        "heldout_ncpe_observed": fit.ncpe,
        "poorly_explained": poorly_explained(model.policy, held, held_names),
        "heldout_vs_zero": {"cv_folds": json_floats(model.fit_summary_.get("heldout_vs_zero")),
                            "held_out": json_floats(zero)},
        "worse_than_zero": bool(model.fit_summary_.get("worse_than_zero"))
        or bool(zero and zero["ratio"] >= 1.0),
        "poor_fit": bool(model.fit_summary_.get("poor_fit")),
        # Files of models fitted before per-demonstration clocks hold none: one clock.
        "timing_scales": json_floats(model.fit_summary_.get("timing_scales")),
        "no_minimum": bool(model.fit_summary_.get("no_minimum")),
        "unfixed_goal": bool(model.fit_summary_.get("unfixed_goal")),
        "goal": goal_digest(model.fit_summary_.get("goal")),
        "state": states.state,
        "joints": list(demos.joints),
        "constant_joints": list(demos.constant),
        "continuous_joints": list(demos.continuous),
        "robot": run.robot,
        "inputs": [str(p) for p in run.inputs],
        "data": report.summary(),
        "current_model": current,
        "gates": asdict(run.gates),
        "refusals": refused,
        "forced": bool(run.force and refused),
        "seed": int(run.seed),
        "holdout_fraction": float(run.holdout_fraction),
    }
    return PipelineResult(summary=summary, model=model, model_path=run.path, written=False,
                          refusals=refused, train=list(train), held=list(held))


def _write(result: PipelineResult, run: _Run, say: Callable[[str], None]) -> PipelineResult:
    """Stage 7: write the model (atomically, the summary in its header) unless refused."""
    if result.refusals and not run.force:
        say(result.line())
        return result
    model = result.model
    model.fit_summary_ = {**(model.fit_summary_ or {}), "pipeline": result.summary}
    model.robot_ = run.robot  # the executor takes its robot from here when not told
    run.path.parent.mkdir(parents=True, exist_ok=True)
    model.save(run.path)
    result.written = True
    return result
