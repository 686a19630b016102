"""The chosen global model refitted on the CV's training folds, and what the refits measure.

After :class:`~policy_align_ros.learning.PolicyAlign` has chosen its global model, the
same model (the hyperparameters its cross-validation chose, fixed, so a refit costs one
penalised solve rather than a search) is fitted again without each fold's demonstrations,
on the folds the regressor's CV used (``TrendKernelRegression.cv_folds_``; other
regressors: folds drawn alike, seeded). Each fold model is then scored on what it never
saw:

- :func:`heldout_vs_zero`: its error on the held-out demonstrations' observed velocities,
  beside the error of a zero policy. Along the observed motion ``u = N pi`` (``N`` the
  unknown constraint's projector), the error of a policy ``p`` is
  ``||u - P_u p||^2`` with ``P_u = u u^T / ||u||^2`` (the true policy scores 0 whatever
  the constraint; :func:`~policy_align_ros.data.quality.observed_ncpe` measures the same
  on the learn pipeline's held-out demonstrations) and a zero policy's is ``||u||^2``. A
  model whose held-out error is no smaller predicts the motion no better than standing
  still;
- :func:`fold_spread`: how far each fold model's nearest minimum lies from each minimum of
  the full model (:mod:`~policy_align_ros.learning.goal`);
- :func:`heldout_reach`: whether its policy takes the held-out demonstrations' starts to
  the goal in time (:mod:`~policy_align_ros.learning.reach`). The fit's own starts are
  no test of a new start: the fit saw them. A fold model's held-out start is, and the
  fit warns when one does not reach (:func:`heldout_reach_message`).

:func:`fit_checks` runs both with :func:`~policy_align_ros.learning.goal.goal_summary` and
warns when the model is no better than a zero policy, when it explains at most half of the
held-out motion (:data:`POOR_FIT_RATIO`), or when its potential has no minimum near the
data. The held-out demonstrations took part
in the alignment of the potentials the fold models are trained on (as in the regressor's
own CV): the estimate is leave-demonstrations-out for the global model, not for the
alignment. Notation as in :mod:`~policy_align_ros.learning.goal`.
"""

from __future__ import annotations

import copy
import dataclasses
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from policy_align_ros.learning.descent import data_box, learnt_minima
from policy_align_ros.learning.fitting import assign_folds
from policy_align_ros.learning.global_model import fixed_copy, training_set
from policy_align_ros.learning.goal import (
    GOAL_MERGE,
    demonstrated_goal,
    goal_summary,
    learnt_goal_index,
)
from policy_align_ros.learning.reach import REACH_TIME, starts_reach
from policy_align_ros.learning.regressors import (
    takes_drops,
    takes_free_groups,
    takes_min_curvature,
    takes_motion,
    takes_scored,
)
from policy_align_ros.learning.regressors.trend_kernel.stacked import stacked_gradient
from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["POOR_FIT_RATIO", "FoldModel", "fit_checks", "fold_models", "fold_refits",
           "fold_spread", "heldout_reach", "heldout_reach_message", "heldout_vs_zero",
           "along_motion_errors", "demonstration_ratios", "unfixed_goal"]

#: Folds drawn for a regressor that keeps none (as many as TrendKernelRegression's CV).
N_FOLDS = 10
#: Held-out samples scored per fold at most (evenly strided): the estimate needs a few
#: thousand, a 10^6-sample fit would otherwise spend seconds on it.
MAX_SCORED = 2000
#: A held-out error at or above this share of a zero policy's (the model explains at most
#: half of the held-out motion along its direction) is a poor fit: it warns, and is kept.
POOR_FIT_RATIO = 0.5


@dataclasses.dataclass
class FoldModel:
    """A global model fitted without the demonstrations ``held_out`` (their group ids)."""

    held_out: np.ndarray
    regressor: Any


def fold_refits(regressor, X: np.ndarray, y: np.ndarray, groups: np.ndarray,
                free_groups: np.ndarray | None = None, *, random_state: int | None = 0,
                motion: np.ndarray | None = None, drops: np.ndarray | None = None
                ) -> list[FoldModel]:
    """The fitted ``regressor`` refitted once per CV fold, without that fold's groups.

    Parameters
    ----------
    regressor : fitted regressor
        The chosen global model. A ``TrendKernelRegression`` with a CV is refitted with
        the hyperparameters it chose (``cv_best_``) on its own folds (``cv_folds_``);
        another regressor as a fresh copy of its parameters, on folds drawn with
        ``random_state``.
    X, y, groups : ndarrays (m, n), (m,), (m,)
        What it was fitted on: states, aligned potentials, demonstration ids.
    free_groups : ndarray of int, optional
        Demonstrations whose offsets it re-fits freely (passed on for those kept).
    random_state : int or None
        Seeds the folds when the regressor keeps none.
    motion : ndarray (m, n), optional
        Each sample's step: a regressor stationary at a goal was fitted with it, and
        each fold model is fitted the same way.
    drops : ndarray (m,), optional
        With ``motion``: the potential's change over each sample's step, likewise.

    Returns
    -------
    list of FoldModel
        One per fold with training data whose refit succeeded.
    """
    ids = np.unique(groups)
    folds = getattr(regressor, "cv_folds_", None)
    if not folds or set(folds) != set(int(g) for g in ids):
        drawn = assign_folds(ids, min(N_FOLDS, len(ids)), np.random.default_rng(random_state))
        folds = {int(g): int(f) for g, f in zip(ids, drawn, strict=True)}
    # The fixed grid needs no search, and no fold model's CV score is read (``scored`` below,
    # where the regressor takes it); two folds order the samples as a two-fold fit does.
    template = fixed_copy(regressor, n_folds=2)
    free = np.zeros(0, dtype=np.int64) if free_groups is None else np.asarray(free_groups)
    out = []
    for fold in sorted(set(folds.values())):
        held = np.array([g for g in ids if folds[int(g)] == fold])
        train = ~np.isin(groups, held)
        if not train.any():
            continue
        kept_free = np.intersect1d(free, groups[train])
        extra = ({"free_groups": kept_free}
                 if kept_free.size and takes_free_groups(template) else {})
        if takes_scored(template):
            extra["scored"] = False
        if getattr(regressor, "goal_", None) is not None:
            extra["goal"] = regressor.goal_  # the fold model is stationary there too
            bowl = getattr(regressor, "min_curvature_", None)
            if bowl is not None and takes_min_curvature(template):
                extra["min_curvature"] = bowl  # and as curved
            if motion is not None and takes_motion(template):
                extra["motion"] = motion[train]
                if drops is not None and takes_drops(template):
                    extra["drops"] = drops[train]
        try:
            model = copy.deepcopy(template).fit(X[train], y[train], groups=groups[train],
                                                **extra)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            continue  # a fold too small to fit says nothing either way
        out.append(FoldModel(held, model))
    return out


def along_motion_errors(policy, trajs: Sequence[Trajectory], max_samples: int = MAX_SCORED
                        ) -> tuple[np.ndarray, int]:
    """A policy's squared error along the observed motion, and a zero policy's.

    Parameters
    ----------
    policy : callable
        ``policy(X)`` (m, n) -> (m, n), state units per second (per step without times).
    trajs : sequence of Trajectory
        Demonstrations; ``u`` is the forward-difference velocity at each sample but the
        last (samples that do not move are skipped).
    max_samples : int
        Samples scored at most, evenly strided over all of them.

    Returns
    -------
    ndarray (3,)
        Sums over the scored samples of ``||u - P_u pi_hat||^2``, of ``||u||^2`` (the
        zero policy's) and of ``||u - pi_hat||^2`` (the whole velocity's error, a fair
        measure only where nothing constrained the motion), in squared state units per
        second.
    count : int
        Samples scored.
    """
    us = [np.diff(t.positions, axis=0) / t.dt[:, None] for t in trajs]
    if not us:
        return np.zeros(3), 0
    u = np.concatenate(us)
    x = np.concatenate([t.positions[:-1] for t in trajs])
    norm2 = np.einsum("ij,ij->i", u, u)
    moving = np.flatnonzero(norm2 > 1e-12 * max(float(norm2.max(initial=0.0)), 1e-300))
    if not moving.size:
        return np.zeros(3), 0
    pick = moving[np.unique(np.linspace(0, len(moving) - 1, min(max_samples, len(moving)))
                            .round().astype(int))]
    u, x, norm2 = u[pick], x[pick], norm2[pick]
    pi_hat = policy(x)
    along = np.einsum("ij,ij->i", u, pi_hat) / norm2
    # ||u - (u.p / ||u||^2) u||^2 = ||u||^2 (1 - u.p / ||u||^2)^2
    sums = [np.sum(norm2 * (1.0 - along) ** 2), np.sum(norm2), np.sum((u - pi_hat) ** 2)]
    return np.array(sums, dtype=float), len(pick)


def heldout_vs_zero(folds: Sequence[FoldModel], trajs: Sequence[Trajectory]
                    ) -> dict[str, float | int] | None:
    """Every fold model's along-motion error on its held-out demonstrations, pooled.

    Parameters
    ----------
    folds : sequence of FoldModel
        Their ``held_out`` ids index ``trajs``.
    trajs : sequence of Trajectory
        The demonstrations (or pieces) the regressor's groups name.

    Returns
    -------
    dict or None
        ``error`` and ``zero_error``: mean squared along-motion error of the fold models
        and of a zero policy ((state units/s)^2); ``ratio`` = error / zero_error (1: no
        better than a zero policy); ``whole_velocity_ratio``, the same with the whole
        velocity's error ``||u - pi_hat||^2`` (what a zero policy is beaten by where nothing
        constrained the motion; under a constraint even the true policy scores above 0);
        ``n_samples``; ``n_folds``. None when nothing held out moves.
    """
    sums, count, per_fold = np.zeros(3), 0, []
    for fold in folds:
        held = [trajs[int(g)] for g in fold.held_out]
        s, c = along_motion_errors(lambda X, r=fold.regressor: -r.gradient(X), held)
        sums, count = sums + s, count + c
        if s[1] > 0.0:
            per_fold.append(float(s[0] / s[1]))
    err, zero, whole = sums
    if count == 0 or zero <= 0.0:
        return None
    return {"error": float(err / count), "zero_error": float(zero / count),
            "ratio": float(err / zero), "whole_velocity_ratio": float(whole / zero),
            "fold_ratios": per_fold, "n_samples": int(count), "n_folds": len(folds)}


def demonstration_ratios(folds: Sequence[FoldModel], pieces: Sequence[Trajectory],
                         owners: np.ndarray, n_demos: int) -> list[float | None]:
    """Per demonstration, :func:`heldout_vs_zero`'s ratio of the fold models that held it out.

    Parameters
    ----------
    folds : sequence of FoldModel
        Their ``held_out`` ids index ``pieces``.
    pieces : sequence of Trajectory
    owners : ndarray of int, shape (P,)
        The demonstration (0 .. ``n_demos`` - 1) each piece was cut from.
    n_demos : int

    Returns
    -------
    list of float or None, length ``n_demos``
        The along-motion error of the models fitted without a demonstration, on it, over
        a zero policy's (>= 1: the others' model predicts it no better than standing
        still); None for a demonstration never held out or that does not move.
    """
    sums = np.zeros((n_demos, 2))
    for fold in folds:
        held = np.asarray(fold.held_out, dtype=int)
        for k in np.unique(owners[held]):
            mine = [pieces[int(g)] for g in held if owners[g] == k]
            s, _ = along_motion_errors(lambda X, r=fold.regressor: -r.gradient(X), mine)
            sums[k] += s[:2]
    return [float(e / z) if z > 0.0 else None for e, z in sums]


def fold_spread(folds: Sequence[FoldModel], minima: np.ndarray, *, scale: float,
                speed: float, bounds: tuple[np.ndarray, np.ndarray]) -> list[float | None]:
    """Per minimum of the full model, the largest distance over the folds to the fold
    model's nearest minimum (state units).

    Each fold model is descended from the full model's minima (``scale``, ``speed`` and
    ``bounds`` as in :func:`~policy_align_ros.learning.goal.learnt_minima`). A fold model
    without any minimum there gives None for every minimum.
    """
    if not len(minima) or not folds:
        return [None] * len(minima)
    worst = np.zeros(len(minima))
    for fold in folds:
        found = learnt_minima(fold.regressor.predict, fold.regressor.gradient, minima,
                              scale=scale, speed=speed, bounds=bounds).points
        if not len(found):
            return [None] * len(minima)
        d = np.linalg.norm(minima[:, None, :] - found[None], axis=2).min(axis=1)
        worst = np.maximum(worst, d)
    return [float(d) for d in worst]


def fold_models(regressor, pieces: Sequence[Trajectory], masks: Sequence[np.ndarray],
                keep: np.ndarray, potentials: Sequence[np.ndarray], free: np.ndarray, *,
                random_state: int | None = 0, step_scale: float = 1.0) -> list[FoldModel]:
    """:func:`fold_refits` of a fitted global model on what it was fitted on: the pieces
    ``keep`` of ``pieces`` (their training samples ``masks``), their aligned
    ``potentials``, free offsets for ``free``, and the steps and drops of an anchored fit
    (times ``step_scale``, :func:`~policy_align_ros.learning.anchor.step_scale`);
    ``random_state`` seeds the folds of a regressor that keeps none."""
    # The bowl's bound fold_refits takes from the regressor; here only the samples.
    X, y, g, extra = training_set(pieces, masks, keep, potentials, free, regressor,
                                  getattr(regressor, "goal_", None), step_scale=step_scale)
    return fold_refits(regressor, X, y, g, free, random_state=random_state,
                       motion=extra.get("motion"), drops=extra.get("drops"))


def heldout_reach(folds: Sequence[FoldModel], spans: np.ndarray,
                  parents: Sequence[Trajectory], goal: np.ndarray | None, extent: float
                  ) -> dict[str, Any]:
    """Whether each fold model's policy reaches the goal from the starts of the
    demonstrations it was fitted without (:func:`~policy_align_ros.learning.reach.
    starts_reach`): the CV's estimate of whether a new start does.

    Parameters
    ----------
    folds : sequence of FoldModel
        Held-out groups are piece indices.
    spans : ndarray (P, 3)
        Every piece's demonstration, first and end sample
        (:func:`~policy_align_ros.learning.pieces.split_pieces`); a held-out piece that is
        its demonstration's first (after a leading rest, which no piece keeps) stands for
        that demonstration's start.
    parents : sequence of Trajectory
        The demonstrations.
    goal : ndarray (n,) or None
        Where most demonstrations end; None: nothing is run.
    extent : float
        The data's extent W (state units).

    Returns
    -------
    dict
        ``heldout_reach_ratios``: per held-out start, the fold model's arrival time over
        its demonstration's duration (None when it did not arrive within
        :data:`~policy_align_ros.learning.reach.REACH_TIME` of them; the list is None
        without a goal), and ``n_heldout_late``, the count of those None.
    """
    if goal is None:
        return {"heldout_reach_ratios": None, "n_heldout_late": 0}
    first = np.full(len(parents), np.iinfo(np.int64).max)
    np.minimum.at(first, spans[:, 0], spans[:, 1])
    runs, owner = [], []
    for j, fold in enumerate(folds):
        held = sorted({int(spans[p, 0]) for p in np.asarray(fold.held_out, dtype=np.int64)
                       if spans[p, 1] == first[spans[p, 0]]})
        runs += [parents[k] for k in held]
        owner += [j] * len(held)
    if not runs:
        return {"heldout_reach_ratios": [], "n_heldout_late": 0}
    models = [fold.regressor for fold in folds]
    # All runs at once: one call per Euler step rather than one per fold model.
    gradient = stacked_gradient(models) or _each_gradient(models)
    ratios = starts_reach(runs, gradient, goal, extent,
                          np.array(owner))["start_reach_ratios"]
    return {"heldout_reach_ratios": ratios,
            "n_heldout_late": sum(r is None for r in ratios)}


def _each_gradient(models: Sequence) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``g(X, owner)``: the gradient of ``models[owner[i]]`` at ``X[i]``, one call per
    model (for regressors :func:`stacked_gradient` cannot stack)."""

    def gradient(X: np.ndarray, owner: np.ndarray) -> np.ndarray:
        out = np.empty_like(X)
        for j in np.unique(owner):
            out[owner == j] = models[j].gradient(X[owner == j])
        return out

    return gradient


def heldout_reach_message(goal: dict[str, Any]) -> str | None:
    """The warning of held-out starts that do not reach the goal, when every start of the
    fit's own does (otherwise the goal report's warnings already say so)."""
    late = goal.get("n_heldout_late") or 0
    if not late or goal.get("n_starts_elsewhere") or goal.get("n_starts_late"):
        return None
    return (f"PolicyAlign: from every demonstration's start the learnt policy reaches the "
            f"goal, but from {late} of {len(goal['heldout_reach_ratios'])} the model fitted "
            f"without that demonstration (its CV fold) does not within {REACH_TIME:g} times "
            "its duration: from a new start near the demonstrated ones it may not either "
            "(fit_summary_['goal']['heldout_reach_ratios'])")


def fit_checks(regressor, folds: Sequence[FoldModel], pieces: Sequence[Trajectory],
               parents: Sequence[Trajectory], *,
               starts_check: dict[str, Any] | None = None,
               owners: np.ndarray | None = None) -> dict[str, Any]:
    """The goal report and the zero-policy comparison of a fitted global model.

    Parameters
    ----------
    regressor : fitted regressor
        The global model of the potential.
    folds : sequence of FoldModel
        Its :func:`fold_models`.
    pieces : sequence of Trajectory
        What the regressor's groups index.
    parents : sequence of Trajectory
        The whole demonstrations (their ends are where they rest).
    starts_check : dict, optional
        :func:`~policy_align_ros.learning.goal.starts_elsewhere` of ``parents`` and this
        regressor, if already computed.
    owners : ndarray of int, shape (P,), optional
        The parent each piece was cut from; the pieces are the parents when omitted.

    Returns
    -------
    dict
        ``goal`` (:func:`~policy_align_ros.learning.goal.goal_summary`, with
        ``fold_spread`` per minimum, ``fold_spread_max`` and its ``fold_spread_fraction``
        of the extent, and :func:`~policy_align_ros.learning.reach.starts_reach`'s
        ``start_reach_ratios`` and ``n_starts_late``), ``heldout_vs_zero``
        (:func:`heldout_vs_zero`) and ``worse_than_zero``, ``poor_fit`` (held-out error at
        least :data:`POOR_FIT_RATIO` of a zero policy's, but below it) and ``no_minimum``
        (no descent found a minimum) and ``unfixed_goal`` (:func:`unfixed_goal`); a
        ``UserWarning`` names the numbers when any is
        True, and when starts are late beyond those stranded. A poor or worse fit's
        ``heldout_vs_zero`` holds ``demonstration_ratios`` (:func:`demonstration_ratios`,
        None otherwise), and its warning names the demonstrations the others' models
        predict no better than standing still.
    """
    heldout = heldout_vs_zero(folds, pieces)
    goal = goal_summary(parents, regressor.predict, regressor.gradient,
                        starts_check=starts_check)
    minima = np.array([m["point"] for m in goal["minima"]]).reshape(-1, parents[0].n_dims)
    Xall = np.concatenate([t.positions for t in parents])
    extent = goal["extent"]
    spread = fold_spread(folds, minima, scale=extent, speed=goal["typical_speed"],
                         bounds=data_box(Xall, extent))
    for entry, d in zip(goal["minima"], spread, strict=True):
        entry["fold_spread"] = d
    known = [d for d in spread if d is not None]
    goal["fold_spread_max"] = max(known) if known and len(known) == len(spread) else None
    goal["fold_spread_fraction"] = (None if goal["fold_spread_max"] is None
                                    else goal["fold_spread_max"] / extent)
    goal["n_folds"] = len(folds)
    goal.update(starts_reach(parents, regressor.gradient, demonstrated_goal(parents), extent))
    worse = heldout is not None and heldout["error"] >= heldout["zero_error"]
    poor = heldout is not None and not worse and heldout["ratio"] >= POOR_FIT_RATIO
    no_minimum = not goal["minima"]
    for message in _goal_messages(goal, [t.name for t in parents]):
        warnings.warn(message, UserWarning, stacklevel=3)
    if heldout is not None:
        # Only where the pooled error is poor: which demonstrations the others contradict.
        heldout["demonstration_ratios"] = None if not (worse or poor) else demonstration_ratios(
            folds, pieces, np.arange(len(pieces)) if owners is None else owners, len(parents))
    if worse or poor:
        warnings.warn(_heldout_message(heldout, worse, parents), UserWarning, stacklevel=3)
    return {"goal": goal, "heldout_vs_zero": heldout, "worse_than_zero": bool(worse),
            "poor_fit": bool(poor), "no_minimum": bool(no_minimum),
            "unfixed_goal": unfixed_goal(goal)}


def _goal_messages(goal: dict[str, Any], names: Sequence[str | None]) -> list[str]:
    """The goal report's warnings: no minimum, starts that stop elsewhere, starts still on
    their way after :data:`~policy_align_ros.learning.reach.REACH_TIME` durations (naming
    the demonstrations of ``names``, one per demonstration, whose runs did not arrive),
    and a learnt goal the CV folds' models leave open (:func:`unfixed_goal`)."""
    extent = goal["extent"]
    n_demos = len(names)
    # Every descent from where the demonstrations end left the data's box widened by its
    # extent: the policy has no goal to stop at (it would run to the executor's guard).
    if not goal["minima"]:
        return [f"PolicyAlign: the learnt potential has no minimum: all {goal['n_escaped']} "
                f"descents from where the demonstrations end left the data's box widened by "
                f"its extent {extent:.4g}; the policy would not stop at a goal (do the "
                "demonstrations end where the task ends?)"]
    messages = []
    elsewhere, escaped = goal["n_starts_elsewhere"], goal["n_starts_escaped"]
    if elsewhere:
        far = goal["starts_elsewhere_fraction"]
        where = [] if far is None else [
            f"{elsewhere - escaped} at a minimum up to {100 * far:.3g} % of the data's "
            "extent away"]
        where += [f"{escaped} out of the data's region"] if escaped else []
        messages.append(
            f"PolicyAlign: from {elsewhere} of {n_demos} demonstrations' starts the "
            f"learnt policy stops where no demonstration's end leads ({', '.join(where)}):"
            " its potential has minima or slopes on the way that the demonstrations did "
            "not follow (a path that loops or crosses itself?)")
    late = goal["n_starts_late"] - elsewhere
    if late > 0:
        ratios = goal.get("start_reach_ratios") or []
        unarrived = [names[k] or f"#{k}" for k, r in enumerate(ratios)
                     if r is None and k < n_demos]
        messages.append(
            f"PolicyAlign: from {late} of {n_demos} demonstrations' starts a run of the "
            f"learnt policy is still on its way to the goal after {REACH_TIME:g} times the "
            "demonstration's duration: its potential is nearly flat on the way (a teacher "
            "who set off slowly, or one much faster than the others?), where a robot would "
            "stall (fit_summary_['goal']['start_reach_ratios']; runs not arrived: "
            f"{_some_names(unarrived)})")
    if unfixed_goal(goal):
        entry = goal["minima"][learnt_goal_index(goal)]
        spread = entry["fold_spread"]
        moves = ("a CV fold's model, fitted without some of the demonstrations, has no "
                 "minimum near the learnt goal" if spread is None else
                 f"the learnt goal moves by up to {100 * spread / extent:.3g} % of the data's "
                 f"extent between the models of the {goal['n_folds']} CV folds, each fitted "
                 "without some of the demonstrations")
        messages.append(
            f"PolicyAlign: {moves}: they do not fix it, and a run may stop far from where "
            f"they meant (it lies {100 * entry['data_fraction']:.3g} % of the extent from "
            "the nearest sample; record demonstrations that end at rest where the task "
            "ends)")
    return messages


def _some_names(names: Sequence[str], shown: int = 4) -> str:
    """The first ``shown`` of ``names`` and how many more there are."""
    more = len(names) - shown
    return ", ".join(names[:shown]) + (f" and {more} more" if more > 0 else "")


def unfixed_goal(goal: dict[str, Any]) -> bool:
    """Whether the CV folds' models leave the learnt goal open. ``goal`` is a fit's
    ``fit_summary_["goal"]``; its goal is :func:`~policy_align_ros.learning.goal.
    learnt_goal_index`'s. Open when some fold model has no minimum near it, or puts one more
    than :data:`~policy_align_ros.learning.goal.GOAL_MERGE` of the extent from it
    (``fold_spread``); False without minima or fold models."""
    # Farther apart than two rests that count as one goal: the data do not fix the goal
    # (demonstrations cut while moving, teachers heading for different places, or held
    # off it by constraints that leave it to extrapolation). Other minima, which only a
    # few demonstrations lead to, the starts' and new starts' checks cover.
    if not goal["minima"] or not goal.get("n_folds"):
        return False
    spread = goal["minima"][learnt_goal_index(goal)]["fold_spread"]
    return spread is None or spread > GOAL_MERGE * goal["extent"]


def _heldout_message(heldout: dict[str, Any], worse: bool,
                     parents: Sequence[Trajectory] = ()) -> str:
    """The warning of a fit no better than a zero policy (``worse``), or of a poor fit,
    naming the demonstrations of ``parents`` the others' models predict no better than
    standing still (``heldout["demonstration_ratios"]``)."""
    numbers = (f"mean squared error along the observed motion of {heldout['n_samples']} "
               f"held-out samples over {heldout['n_folds']} CV folds")
    if worse:
        text = (f"PolicyAlign: held-out error {heldout['error']:.4g} is no better than a zero "
                f"policy's {heldout['zero_error']:.4g} (ratio {heldout['ratio']:.3g}, "
                f"{numbers}): the learnt policy predicts the demonstrations no better than "
                "standing still")
    else:
        # A teacher's timing under changing constraints, or paths no potential follows:
        # the policy's speeds and directions then differ from the demonstrations'.
        text = (f"PolicyAlign: held-out error {heldout['error']:.4g} is {heldout['ratio']:.2g} "
                f"of a zero policy's {heldout['zero_error']:.4g} ({numbers}): the learnt "
                "policy explains at most half of the demonstrated motion, so where it leads "
                "may not be where they went (do they follow one potential? a teacher's own "
                "timing, paths that loop)")
    ratios = heldout.get("demonstration_ratios") or []
    against = [f"{parents[k].name or f'#{k}'} ({r:.2g})" for k, r in enumerate(ratios)
               if r is not None and r >= 1.0 and k < len(parents)]
    if against and len(against) < len(ratios):
        # A few demonstrations the rest contradict: motion that is not the task.
        text += (f"; the models fitted without them predict {len(against)} of "
                 f"{len(ratios)} demonstrations no better than standing still: "
                 f"{', '.join(against)} (the ratio of errors; teachers heading for other "
                 "places, or a recording left running while the teacher went back to the "
                 "start?)")
    return text
