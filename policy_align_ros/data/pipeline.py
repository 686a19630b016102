"""The one learning pipeline: rosbag2 demonstrations -> checked model file (ROS-free).

Both ``policy-align learn`` (:mod:`policy_align_ros.data.learn`) and the ``learner`` node
call :func:`learn_pipeline`, which does, in order:

1. **discovery**: bags and dataset directories are read with
   :func:`~policy_align_ros.data.bags.load_dataset` (joints matched by name, split at time
   gaps, malformed messages skipped and counted); bags that give nothing are named with
   the reason, a missing joint is named beside the joints that exist;
2. **de-duplication**: a bag named twice is read once, and demonstrations that are
   near-identical copies of an earlier one (:func:`find_duplicates`) are skipped and
   reported by name: identical demonstrations have a closest approach of 0, which
   collapses the kernel width of the alignment (paper eqs. 17-19);
3. **hold-out split** (:func:`holdout_split`), seeded;
4. **state map**: joint positions (rad) as they are, or for ``state="frames:F1,F2"`` the
   stacked positions (m) of those frames of ``robot`` computed with Pinocchio;
5. **fit** of :class:`~policy_align_ros.learning.PolicyAlign` on the training part;
6. **quality summary** and **degenerate-fit refusal** (:class:`Gates`): a sigma^2 that
   collapsed, most demonstrations discarded as outliers, or a held-out error worse than
   the current model's at ``model_path``; a refused fit never replaces that file unless
   ``force`` is set;
7. the model is written atomically with the summary in its header's ``training`` block,
   under ``"pipeline"`` (see :func:`learn_pipeline` for the keys).

Notation: ``K`` demonstrations, each ``X_k`` (``N_k`` x ``n``) with times in seconds; ``n``
is the number of joints (state in rad) or ``3F`` for ``F`` frames (state in m). nCPE is
measured along the observed motion (:func:`observed_ncpe`), so it needs no constraint.

Imports: numpy and :mod:`policy_align_ros.learning`, and rosbags through ``bags``. The
``frames:`` state needs Pinocchio: :mod:`policy_align_ros.kinematics` is imported inside
:func:`learn_pipeline` only for that case (or the caller passes its own ``state_map``), so
this module imports without Pinocchio for joint states.
"""

from __future__ import annotations

import hashlib
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from policy_align_ros.data.bags import load_dataset
from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.learning.model_io import json_float
from policy_align_ros.learning.state_spec import parse_state_spec

#: Share of the mean squared step explained by position noise from which the summary
#: line mentions it (the fit corrects for any amount; see PolicyAlign.position_noise_).
NOISY_STEPS = 0.1

__all__ = [
    "Gates",
    "PipelineResult",
    "SIGMA_RULES",
    "find_duplicates",
    "fingerprint",
    "holdout_split",
    "learn_pipeline",
    "observed_ncpe",
    "parse_sigma",
    "state_name",
]

SIGMA_RULES = ("narrow", "medium", "wide")


def parse_sigma(text: str | float) -> str | float:
    """``"narrow" | "medium" | "wide"`` or a positive sigma^2 (squared state units).

    Raises
    ------
    ValueError
        For anything else, naming the value.
    """
    if isinstance(text, str) and text.strip().lower() in SIGMA_RULES:
        return text.strip().lower()
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(
            f"sigma: expected narrow, medium, wide or a positive number, got {text!r}"
        ) from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"sigma: sigma^2 must be positive and finite, got {text!r}")
    return value


def state_name(state: str) -> str:
    """Normalised state spec: ``"joints"`` or ``"frames:F1,F2"`` (frames checked).

    Raises
    ------
    ValueError
        For any other text, an empty or a repeated frame.
    """
    frames = parse_state_spec(state)
    return "joints" if frames is None else "frames:" + ",".join(frames)


@dataclass(frozen=True)
class Gates:
    """Thresholds of the degenerate-fit refusal (all dimensionless).

    Attributes
    ----------
    min_sigma2_fraction : float
        Refuse when a sigma rule (narrow/medium/wide) gave ``sigma^2`` below this
        fraction of the training states' total variance ``sum_d var(X[:, d])``: the kernel
        then sees single samples, as happens when demonstrations coincide. Default 1e-4
        (a kernel width of 1 % of the data's spread). Not applied to an explicit sigma^2.
    max_discarded_fraction : float
        Refuse when outlier detection finds more than this fraction of the training
        demonstrations too weakly connected to align (the paper's outliers). The default
        global model levels and keeps them, but most of the data would then tie together
        through the model alone: a sign of a kernel far too narrow or of demonstrations
        that never meet. Default 0.5 ("most").
    heldout_tolerance : float
        Refuse when the new model's held-out nCPE exceeds the current model's on the same
        held-out demonstrations (those the current model was not trained on) by more than
        this. nCPE is normalised (1 = no better than a zero policy). Default 0.02.
    duplicate_tol : float
        Two demonstrations are duplicates when each sample of either lies, on average,
        within this fraction of the data's RMS spread ``sqrt(sum_d var(X[:, d]))`` of the
        other (:func:`find_duplicates`). Default 1e-3.
    """

    min_sigma2_fraction: float = 1e-4
    max_discarded_fraction: float = 0.5
    heldout_tolerance: float = 0.02
    duplicate_tol: float = 1e-3

    def __post_init__(self) -> None:
        for name, low, high in (("min_sigma2_fraction", 0.0, 1.0),
                                ("max_discarded_fraction", 0.0, 1.0),
                                ("heldout_tolerance", 0.0, math.inf),
                                ("duplicate_tol", 0.0, 1.0)):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)
                    and low <= value <= high):
                raise ValueError(f"{name}: must be a number in [{low}, {high}], "
                                 f"got {value!r}")


def observed_ncpe(policy: Callable[[np.ndarray], np.ndarray],
                  trajectories: Sequence[Trajectory]) -> float:
    """nCPE with each ``N_i`` replaced by the projector onto the observed velocity.

    The constraints of recorded demonstrations are unknown. Because ``N_i`` is an
    orthogonal projection, ``u_i^T pi_i = ||u_i||^2`` for the observed ``u_i = N_i pi_i``,
    so the projection of the true policy onto ``u_i`` is ``u_i`` itself and the measure
    needs the data only; it scores the policy along the observed motion.

    Parameters
    ----------
    policy : callable
        ``policy(X)`` (m, n) -> (m, n) in state units per second.
    trajectories : sequence of Trajectory
        Held-out demonstrations with times (s).

    Returns
    -------
    float
        ``mean_i ||u_i - P_i pi_hat_i||^2 / sum_d var(u[:, d])`` over samples with
        non-zero velocity, where ``u_i`` is the forward-difference velocity and
        ``P_i = u_i u_i^T / ||u_i||^2``; NaN when no sample moves.
    """
    us, xs = [], []
    for traj in trajectories:
        dt = traj.dt[:, None]
        us.append(np.diff(traj.positions, axis=0) / dt)
        xs.append(traj.positions[:-1])
    if not us:
        return float("nan")
    u = np.concatenate(us)
    x = np.concatenate(xs)
    norm2 = np.einsum("ij,ij->i", u, u)
    moving = norm2 > 1e-12 * max(float(norm2.max(initial=0.0)), 1e-300)
    if not np.any(moving):
        return float("nan")
    u, x, norm2 = u[moving], x[moving], norm2[moving]
    pi_hat = policy(x)
    along = np.einsum("ij,ij->i", u, pi_hat) / norm2
    err = u - along[:, None] * u
    scale = float(np.sum(np.var(u, axis=0)))
    return float(np.mean(np.einsum("ij,ij->i", err, err)) / scale) if scale > 0 else float("nan")


def holdout_split(n_demos: int, fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """Indices of the training and held-out demonstrations (both sorted).

    At least one demonstration is held out when there are 3 or more and ``fraction > 0``,
    and at least two are always kept for training.
    """
    n_out = int(round(fraction * n_demos)) if n_demos >= 3 else 0
    if fraction > 0 and n_demos >= 3:
        n_out = min(max(n_out, 1), n_demos - 2)
    order = np.random.default_rng(seed).permutation(n_demos)
    return sorted(order[n_out:].tolist()), sorted(order[:n_out].tolist())


def find_duplicates(positions: Sequence[np.ndarray], tol: float = 1e-3) -> dict[int, int]:
    """Demonstrations that are near-identical copies of an earlier one.

    Parameters
    ----------
    positions : sequence of ndarray (N_k, n)
        The demonstrations' states.
    tol : float
        Relative tolerance: ``j`` duplicates ``i < j`` when the mean distance from each
        sample of either to the nearest sample of the other is at most
        ``tol * sqrt(sum_d var(X[:, d]))`` over all samples ``X``, and their first and last
        samples are that close too (a cheap pre-filter).

    Returns
    -------
    dict int -> int
        Index of each duplicate -> index of the first demonstration it copies.
    """
    arrays = [np.asarray(p, dtype=float) for p in positions]
    if len(arrays) < 2:
        return {}
    spread = math.sqrt(float(np.sum(np.var(np.concatenate(arrays), axis=0))))
    threshold = tol * (spread if spread > 0 else 1.0)
    starts = np.array([a[0] for a in arrays])
    ends = np.array([a[-1] for a in arrays])
    trees: dict[int, cKDTree] = {}

    def tree(k: int) -> cKDTree:
        if k not in trees:
            trees[k] = cKDTree(arrays[k])
        return trees[k]

    dup: dict[int, int] = {}
    for i in range(len(arrays)):
        if i in dup:
            continue
        near = np.flatnonzero(
            (np.linalg.norm(starts - starts[i], axis=1) <= threshold)
            & (np.linalg.norm(ends - ends[i], axis=1) <= threshold))
        for j in near[near > i]:
            j = int(j)
            if j in dup:
                continue
            d_ij = float(np.mean(tree(j).query(arrays[i])[0]))
            d_ji = float(np.mean(tree(i).query(arrays[j])[0]))
            if max(d_ij, d_ji) <= threshold:
                dup[j] = i
    return dup


@dataclass
class PipelineResult:
    """Outcome of :func:`learn_pipeline`.

    Attributes
    ----------
    summary : dict
        The ``"pipeline"`` entry of the model header's ``training`` block.
    model : PolicyAlign
        The fitted model (also when refused; then it was not written).
    model_path : Path
        Where the model is (or would have been) written.
    written : bool
        Whether ``model_path`` now holds this model.
    refusals : list of str
        Why the fit is degenerate (empty when it passed every gate).
    """

    summary: dict[str, Any]
    model: PolicyAlign
    model_path: Path
    written: bool
    refusals: list[str] = field(default_factory=list)

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
        text += f"); state {s['state']}; sigma^2={s['sigma2']:.4g}; "
        noisy = s.get("noise_to_step")
        if noisy is not None and noisy >= NOISY_STEPS:
            text += f"position noise {100 * noisy:.0f} % of the mean squared step (corrected); "
        text += (f"fit {s['fit_time_s']:.2f} s; held-out nCPE "
                 + ("n/a" if ncpe is None else f"{ncpe:.4f}") + " (along observed motion)")
        current = s.get("current_model") or {}
        if current.get("heldout_ncpe_observed") is not None:
            text += (f", current model {current['heldout_ncpe_observed']:.4f} on "
                     f"{len(current['compared_on'])} of them")
        if self.refused:
            return (f"refused: {'; '.join(self.refusals)}; {self.model_path} kept unchanged "
                    f"(set force to write it anyway) [{text}]")
        prefix = f"forced despite: {'; '.join(self.refusals)}; " if self.refusals else ""
        return f"{prefix}{text}; model {self.model_path}"


def fingerprint(traj: Trajectory) -> str:
    """Content hash of a demonstration (positions and times), 16 hex digits.

    Names repeat across datasets (every recorder writes ``demo_0000``), so a model's
    training demonstrations are recognised by content.
    """
    digest = hashlib.sha256(np.ascontiguousarray(traj.positions, dtype=np.float64).tobytes())
    if traj.times is not None:
        digest.update(np.ascontiguousarray(traj.times, dtype=np.float64).tobytes())
    return digest.hexdigest()[:16]


def _check_writable(path: Path) -> None:
    """Fail before a long fit when the model file could not be written."""
    if path.is_dir():
        raise ValueError(f"model_path: {path} is a directory, expected a file name")
    ancestor = path.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ValueError(f"model_path: {ancestor} is not a directory, cannot write {path}")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise ValueError(f"model_path: no permission to write in {ancestor}")


def _load_frames_map(robot: str | None, frames: list[str], joints: list[str]):
    """The Pinocchio state map (imported here so joint states need no Pinocchio)."""
    if not robot:
        raise ValueError("robot: a frames: state needs the robot (example-robot-data name "
                         "or URDF path) whose kinematics give the frame positions")
    from policy_align_ros.kinematics import Robot
    from policy_align_ros.kinematics.task_space import LearningStateMap

    return LearningStateMap(Robot.load(robot, joints), frames)


def _current_model_check(path: Path, model: PolicyAlign, held: list[Trajectory],
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
        Joints of the state, in order (default: those of the first message). For a
        ``frames:`` state, the robot's moving joints (the others stay at the robot's
        reference posture).
    sigma : str or float
        PolicyAlign's ``sigma`` (rule or sigma^2 in squared state units).
    gap_s : float
        Split recordings at time gaps longer than this (s).
    holdout_fraction : float in [0, 0.9]
        Fraction of the (unique) demonstrations held out (:func:`holdout_split`).
    seed : int
        Seeds the hold-out split and the fit.
    state : str
        ``"joints"`` or ``"frames:F1,F2,..."``: learn in the stacked positions (m) of those
        frames of ``robot`` (Pinocchio, imported only then).
    robot : str, optional
        example-robot-data name or URDF path; needed for a ``frames:`` state.
    gates : Gates, optional
        Refusal thresholds (default ``Gates()``).
    force : bool
        Write the model even when a gate refuses it (the refusals stay in the summary).
    state_map : callable, optional
        Maps a joint Trajectory to a state Trajectory and has ``definition() -> dict``
        (like :class:`~policy_align_ros.kinematics.task_space.LearningStateMap`); given,
        it replaces the ``frames:`` map built from ``robot``.
    log : callable, optional
        Receives progress lines.

    Returns
    -------
    PipelineResult
        ``summary`` (also stored as ``PolicyAlign.load(model_path).fit_summary_
        ["pipeline"]``) holds: ``demonstrations`` {``found`` (int, every demonstration read
        including copies), ``training``, ``held_out``, ``discarded`` (training
        demonstrations outlier detection dropped), ``duplicates`` (skipped copies; a bag
        named twice gives ``"NAME (repeat)"``)} as lists of demonstration names;
        ``duplicate_of`` {copy: original}; ``training_fingerprints`` (:func:`fingerprint`
        of each training demonstration); ``cut_short_bags`` [{``bag``, ``reason``}]
        (damaged bags whose first part is used); ``skipped_bags`` [{``bag``, ``reason``}];
        ``sigma2``; ``fit_time_s``; ``heldout_ncpe_observed`` (float or None);
        ``state``; ``joints``; ``robot``; ``data`` (what was read, one line);
        ``current_model`` (its held-out nCPE on the demonstrations it was not trained on);
        ``gates``; ``refusals``; ``forced``.

    Raises
    ------
    ValueError
        Unusable input (the message names the path, joint, frame or parameter), fewer
        than 2 unique demonstrations, or a failed fit.
    OSError
        When the model file cannot be written.
    """
    say = log or (lambda _msg: None)
    gates = gates or Gates()
    sigma = parse_sigma(sigma)
    state = state_name(state)
    if not (isinstance(holdout_fraction, (int, float)) and 0.0 <= holdout_fraction <= 0.9):
        raise ValueError(f"holdout_fraction: must be in [0, 0.9], got {holdout_fraction!r}")
    # Checked before reading the data: NumPy's own complaint about a negative seed ("expected
    # non-negative integer") names no parameter, and came only after the whole dataset.
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: must be an integer >= 0, got {seed!r}")
    if isinstance(inputs, (str, Path)):
        inputs = [inputs]
    inputs = [Path(p).expanduser() for p in inputs]
    for p in inputs:
        if not p.exists():
            raise ValueError(f"{p}: no such file or directory")
    path = Path(model_path).expanduser().resolve()
    _check_writable(path)

    # 1. discovery
    trajs, names, report = load_dataset(inputs, joints=joints, gap_s=gap_s)
    demo_names = [d.name for d in report.demos]
    skipped_bags = [{"bag": bag, "reason": reason} for bag, reason in report.skipped_bags]
    cut_short = [{"bag": bag, "reason": reason} for bag, reason in report.cut_short_bags]
    say(f"read {report.summary()}")

    # 2. de-duplication (in joint space: copies there are copies in any state)
    duplicate_of: dict[str, str] = {}
    for bag in report.repeated_bags:
        resolved = Path(bag).resolve()
        for d in report.demos:
            if Path(d.bag).resolve() == resolved:
                duplicate_of[f"{d.name} (repeat)"] = d.name
    copies = find_duplicates([t.positions for t in trajs], gates.duplicate_tol)
    for j, i in sorted(copies.items()):
        duplicate_of[demo_names[j]] = demo_names[i]
    unique = [k for k in range(len(trajs)) if k not in copies]
    if duplicate_of:
        say(f"skipped {len(duplicate_of)} duplicate demonstration(s): "
            + ", ".join(f"{a} = {b}" for a, b in duplicate_of.items()))
    if len(unique) < 2:
        raise ValueError(
            f"{', '.join(map(str, inputs))}: PolicyAlign needs at least 2 distinct "
            f"demonstrations, found {len(unique)}"
            + (f" ({len(duplicate_of)} duplicates skipped)" if duplicate_of else "")
            + f" ({report.summary()})")

    # 3. hold-out split
    train_idx, test_idx = holdout_split(len(unique), holdout_fraction, seed)
    train_k = [unique[i] for i in train_idx]
    test_k = [unique[i] for i in test_idx]

    # 4. state map
    definition = None
    coords = list(names)
    if state != "joints" or state_map is not None:
        if state_map is None:
            state_map = _load_frames_map(robot, state.split(":", 1)[1].split(","), names)
        mapped = {k: state_map(trajs[k]) for k in unique}
        definition = state_map.definition()
        frames = definition.get("frames") if isinstance(definition, dict) else None
        if state == "joints":  # a caller's map: name the state after its frames
            state = "frames:" + ",".join(frames) if frames else "custom"
        dim = mapped[unique[0]].n_dims
        coords = ([f"{f}.{a}" for f in frames for a in "xyz"]
                  if frames and 3 * len(frames) == dim else None)
    else:
        mapped = {k: trajs[k] for k in unique}
    train = [mapped[k] for k in train_k]
    held = [mapped[k] for k in test_k]

    # 5. fit
    say(f"fitting on {len(train)} demonstrations ({len(held)} held out)")
    start = time.perf_counter()
    try:
        model = PolicyAlign(sigma=sigma, random_state=seed).fit(train, joint_names=coords)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as err:
        raise ValueError(f"fit failed on {len(train)} demonstrations: {err}") from None
    fit_s = time.perf_counter() - start
    model.state_definition_ = definition
    ncpe = json_float(observed_ncpe(model.policy, held), "null") if held else None

    # 6. summary and gates
    train_names = [demo_names[k] for k in train_k]
    held_names = [demo_names[k] for k in test_k]
    kept = set(int(i) for i in model.inliers_)
    discarded = [train_names[i] for i in range(len(train)) if i not in kept]
    unaligned = [train_names[i] for i in np.flatnonzero(model.groups_ != 0)]
    current = _current_model_check(path, model, held, held_names,
                                   [fingerprint(trajs[k]) for k in test_k], ncpe)
    refusals: list[str] = []
    X = np.concatenate([t.positions for t in train])
    variance = float(np.sum(np.var(X, axis=0)))
    if isinstance(sigma, str) and variance > 0 and (
            model.sigma2_ < gates.min_sigma2_fraction * variance):
        refusals.append(
            f"sigma^2 collapsed to {model.sigma2_:.3g}, {model.sigma2_ / variance:.2g} of "
            f"the data's variance {variance:.3g} (min_sigma2_fraction "
            f"{gates.min_sigma2_fraction:g}; near-identical demonstrations?)")
    if train and len(unaligned) > gates.max_discarded_fraction * len(train):
        refusals.append(
            f"outlier detection found {len(unaligned)} of {len(train)} training "
            f"demonstrations too weakly connected to align (max_discarded_fraction "
            f"{gates.max_discarded_fraction:g})")
    old, new = current.get("heldout_ncpe_observed"), current.get("new_ncpe_observed")
    if old is not None and new is not None and new > old + gates.heldout_tolerance:
        refusals.append(
            f"held-out nCPE {new:.4f} is worse than the current model's {old:.4f} on the "
            f"same {len(current['compared_on'])} demonstrations (heldout_tolerance "
            f"{gates.heldout_tolerance:g})")
    summary: dict[str, Any] = {
        "demonstrations": {
            "found": len(trajs) + sum(name.endswith(" (repeat)") for name in duplicate_of),
            "training": train_names,
            "held_out": held_names,
            "discarded": discarded,
            "unaligned": unaligned,
            "duplicates": list(duplicate_of),
        },
        "duplicate_of": duplicate_of,
        "training_fingerprints": [fingerprint(trajs[k]) for k in train_k],
        "skipped_bags": skipped_bags,
        "cut_short_bags": cut_short,
        "sigma2": float(model.sigma2_),
        "noise_to_step": json_float(model.fit_summary_["noise_to_step"], "null"),
        "fit_time_s": float(fit_s),
        "heldout_ncpe_observed": ncpe,
        "state": state,
        "joints": list(names),
        "robot": robot if definition is not None else None,
        "inputs": [str(p) for p in inputs],
        "data": report.summary(),
        "current_model": current,
        "gates": asdict(gates),
        "refusals": refusals,
        "forced": bool(force and refusals),
        "seed": int(seed),
        "holdout_fraction": float(holdout_fraction),
    }
    result = PipelineResult(summary=summary, model=model, model_path=path, written=False,
                            refusals=refusals)

    # 7. write (atomically) unless refused
    if refusals and not force:
        say(result.line())
        return result
    model.fit_summary_ = {**(model.fit_summary_ or {}), "pipeline": summary}
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    result.written = True
    return result
