"""Quality of a learnt model: nCPE along the observed motion and the degenerate-fit gates.

ROS-free; imports numpy and the learning core. nCPE is measured along the observed motion
(:func:`observed_ncpe`), so it needs no constraint, and so is the comparison with a zero
policy (:func:`zero_policy_comparison`); :func:`refusals` applies the thresholds of
:class:`Gates` to a fit of the learn pipeline (:mod:`policy_align_ros.data.pipeline`) and
refuses a model no better than a zero policy.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from policy_align_ros.learning.folds import POOR_FIT_RATIO, along_motion_errors

if TYPE_CHECKING:
    from policy_align_ros.learning import PolicyAlign, Trajectory

__all__ = ["Gates", "observed_ncpe", "poorly_explained", "refusals", "zero_policy_comparison"]


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
        other (:func:`~policy_align_ros.data.selection.find_duplicates`). Default 1e-3.
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


def refusals(model: PolicyAlign, sigma: str | float, train: Sequence[Trajectory],
             unaligned: Sequence[str], current: dict[str, Any], gates: Gates,
             heldout_zero: dict[str, Any] | None = None) -> list[str]:
    """Why a fit is degenerate, one line per gate it fails (empty when it passes).

    Parameters
    ----------
    model : PolicyAlign
        The fitted model (``sigma2_`` in squared state units).
    sigma : str or float
        The sigma asked for: the collapse gate applies to a rule only.
    train : sequence of Trajectory
        The training demonstrations, states ``(N_k, n)``.
    unaligned : sequence of str
        Training demonstrations outlier detection found too weakly connected to align.
    current : dict
        The comparison with the current model (``heldout_ncpe_observed`` of the current
        and ``new_ncpe_observed`` of the new model on ``compared_on``).
    gates : Gates
        The thresholds.
    heldout_zero : dict, optional
        The new model's along-motion error beside a zero policy's on the pipeline's
        held-out demonstrations (:func:`zero_policy_comparison`).

    A model no better than a zero policy is always refused: its own CV folds
    (``fit_summary_["worse_than_zero"]``, see :mod:`policy_align_ros.learning.folds`) or
    the held-out demonstrations found its error along the observed motion no smaller
    than that of standing still. So is a model whose potential has no minimum near the
    data (``fit_summary_["no_minimum"]``): it would not stop at a goal.
    """
    out: list[str] = []
    X = np.concatenate([t.positions for t in train])
    variance = float(np.sum(np.var(X, axis=0)))
    if isinstance(sigma, str) and variance > 0 and (
            model.sigma2_ < gates.min_sigma2_fraction * variance):
        out.append(
            f"sigma^2 collapsed to {model.sigma2_:.3g}, {model.sigma2_ / variance:.2g} of "
            f"the data's variance {variance:.3g} (min_sigma2_fraction "
            f"{gates.min_sigma2_fraction:g}; near-identical demonstrations?)")
    if train and len(unaligned) > gates.max_discarded_fraction * len(train):
        out.append(
            f"outlier detection found {len(unaligned)} of {len(train)} training "
            f"demonstrations too weakly connected to align (max_discarded_fraction "
            f"{gates.max_discarded_fraction:g})")
    old, new = current.get("heldout_ncpe_observed"), current.get("new_ncpe_observed")
    if old is not None and new is not None and new > old + gates.heldout_tolerance:
        out.append(
            f"held-out nCPE {new:.4f} is worse than the current model's {old:.4f} on the "
            f"same {len(current['compared_on'])} demonstrations (heldout_tolerance "
            f"{gates.heldout_tolerance:g})")
    summary = getattr(model, "fit_summary_", None) or {}
    cv = summary.get("heldout_vs_zero")
    if summary.get("worse_than_zero") and cv:
        out.append(
            f"no better than a zero policy: held-out error {cv['error']:.4g} vs a zero "
            f"policy's {cv['zero_error']:.4g} (ratio {cv['ratio']:.3g}, squared speed "
            f"along the observed motion, {cv['n_samples']} samples of {cv['n_folds']} CV "
            "folds)")
    goal = summary.get("goal") or {}
    if summary.get("no_minimum"):
        out.append(
            f"the learnt potential has no minimum: all {goal.get('n_escaped')} descents from "
            "where the demonstrations end left the data's region, so the policy would not "
            "stop at a goal")
    if heldout_zero and heldout_zero["ratio"] >= 1.0:
        out.append(
            f"no better than a zero policy on the held-out demonstrations: error "
            f"{heldout_zero['error']:.4g} vs a zero policy's {heldout_zero['zero_error']:.4g}"
            f" (ratio {heldout_zero['ratio']:.3g}, {heldout_zero['n_samples']} samples)")
    return out


def zero_policy_comparison(policy: Callable[[np.ndarray], np.ndarray],
                           trajectories: Sequence[Trajectory]) -> dict[str, Any] | None:
    """A policy's mean squared error along the observed motion beside a zero policy's.

    Parameters
    ----------
    policy : callable
        ``policy(X)`` (m, n) -> (m, n) in state units per second.
    trajectories : sequence of Trajectory
        Demonstrations the policy was not fitted on, with times (s).

    Returns
    -------
    dict or None
        ``error`` and ``zero_error`` ((state units/s)^2), ``ratio`` (1: no better than a
        zero policy), ``whole_velocity_ratio`` and ``n_samples``, as in
        :func:`policy_align_ros.learning.folds.heldout_vs_zero`; None when nothing moves.
    """
    sums, count = along_motion_errors(policy, trajectories)
    if count == 0 or sums[1] <= 0.0:
        return None
    return {"error": float(sums[0] / count), "zero_error": float(sums[1] / count),
            "ratio": float(sums[0] / sums[1]), "whole_velocity_ratio": float(sums[2] / sums[1]),
            "n_samples": int(count)}


def poorly_explained(policy: Callable[[np.ndarray], np.ndarray],
                     trajectories: Sequence[Trajectory], names: Sequence[str]
                     ) -> dict[str, float]:
    """The held-out demonstrations a policy explains at most half of: each one's error
    along its motion over a zero policy's (:func:`zero_policy_comparison`), where it is at
    least :data:`~policy_align_ros.learning.folds.POOR_FIT_RATIO`, the level at which a
    fit's own held-out error is a poor fit.

    Parameters
    ----------
    policy : callable
        ``policy(X)`` (m, n) -> (m, n) in state units per second.
    trajectories : sequence of Trajectory
        Held-out demonstrations, with times (s).
    names : sequence of str
        Their names, in the same order.

    Returns
    -------
    dict str -> float
        Name -> ratio (1: no better than a zero policy), in the given order; those
        without motion are left out.
    """
    out = {}
    for name, traj in zip(names, trajectories, strict=True):
        zero = zero_policy_comparison(policy, [traj])
        if zero is not None and zero["ratio"] >= POOR_FIT_RATIO:
            out[str(name)] = round(zero["ratio"], 4)
    return out
