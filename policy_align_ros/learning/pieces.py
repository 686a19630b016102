"""Demonstrations cut into pieces where no potential rule gets a step right, and the
pieces' learnt attributes merged back per demonstration.

Such steps span lost samples (:func:`~policy_align_ros.learning.potential.sampling_gaps`)
or a constraint switch inside a sample period
(:func:`~policy_align_ros.learning.potential.switch_cuts`): the pieces' shapes are fitted
apart, their levels tied across a switch by the midpoint drop (:func:`switch_junctions`)
and left to the alignment across lost samples.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from policy_align_ros.learning.potential import (
    best_timing,
    leading_rest,
    sampling_gaps,
    switch_cuts,
)
from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["MIN_PIECE_SAMPLES", "merge_pieces", "split_pieces", "switch_junctions"]

#: Fewest samples a piece of a trajectory split at constraint switches must keep to be
#: fitted; shorter ones (a switch in the first or last two steps) are left out.
MIN_PIECE_SAMPLES = 3


def split_pieces(trajs: list[Trajectory], masks: list[np.ndarray], integration: str,
                 noise: float
                 ) -> tuple[list[Trajectory], list[np.ndarray], np.ndarray, np.ndarray]:
    """Pieces of the trajectories between steps that no rule gets right, their masks,
    the ``(trajectory, first sample, end)`` each piece spans (P, 3), and whether each
    piece ends at a switch cut, one that lost no samples (P,) bool.

    Such steps span lost samples
    (:func:`~policy_align_ros.learning.potential.sampling_gaps`), or, where the
    velocities are sampled at the samples (timing ``"mid"``) and trusted, a constraint
    switch inside the sample period
    (:func:`~policy_align_ros.learning.potential.switch_cuts`). The pieces' levels
    are tied across a switch (:func:`switch_junctions`) and left to the alignment
    across lost samples. A demonstration's leading rest (the robot held still before
    its motion, :func:`~policy_align_ros.learning.potential.leading_rest`) is left
    out. Pieces of fewer than :data:`MIN_PIECE_SAMPLES` samples
    (a cut in the first or last steps, or two cuts close together) are left out of
    the fit; a trajectory that would keep no piece is kept whole. Nothing cut: the
    inputs themselves."""
    spans = np.array([(k, 0, t.n_samples) for k, t in enumerate(trajs)], dtype=np.int64)
    switches = (integration in ("auto", "trapezoid")
                and best_timing(trajs, noise) == "mid")
    pieces, piece_masks, out, switch_end = [], [], [], []
    for k, (t, m) in enumerate(zip(trajs, masks, strict=True)):
        gaps = sampling_gaps(t)
        switch = np.setdiff1d(switch_cuts(t), gaps) if switches else gaps[:0]
        cuts = np.union1d(gaps, switch)
        first = leading_rest(t.positions, noise)
        bounds = [first, *(int(i) + 1 for i in cuts if i >= first), t.n_samples]
        kept = [(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)
                if b - a >= MIN_PIECE_SAMPLES] or [(0, t.n_samples)]
        for a, b in kept:
            pieces.append(t if (a, b) == (0, t.n_samples) else Trajectory(
                t.positions[a:b], None if t.times is None else t.times[a:b],
                None if t.velocities is None else t.velocities[a:b],
                name=f"{t.name}[{a}:{b}]"))
            piece_masks.append(m[a:b])
            out.append((k, a, b))
            switch_end.append(b - 1 in switch)
    if len(pieces) == len(trajs) and all(
            p is t for p, t in zip(pieces, trajs, strict=True)):
        # The caller then redoes no per-trajectory work.
        return trajs, masks, spans, np.zeros(len(trajs), dtype=bool)
    return pieces, piece_masks, np.array(out, dtype=np.int64), np.array(switch_end)


def merge_pieces(spans: np.ndarray, parents: list[Trajectory], offsets: np.ndarray,
                 groups: np.ndarray, inliers: np.ndarray, potentials: list[np.ndarray],
                 estimate: Callable[[int, Trajectory], np.ndarray]
                 ) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]:
    """Learnt per-piece attributes back to the trajectories: offsets of each first
    piece, aligned potentials joined, a trajectory kept if any piece is, its group the
    best of its pieces'. Samples left out (pieces too short to fit, and the pieces of a
    kept trajectory that were not kept, whose level is their own group's) get the
    aligned potential of the nearest kept sample plus the chosen rule's own estimate
    of the drop between them, the best that is known there. The trajectories' groups
    are numbered again 0, 1, ... in the order of the pieces' groups (group 0, the
    aligned set, stays 0), so that ``groups.max() + 1`` counts them.

    Parameters
    ----------
    spans : ndarray of int, shape (P, 3)
        ``(trajectory, first sample, end)`` of each piece (:func:`split_pieces`).
    parents : list of Trajectory
        The whole trajectories.
    offsets, groups : ndarray, shape (P,)
        The pieces' offsets and alignment groups.
    inliers : ndarray of int
        The pieces fitted.
    potentials : list of ndarray
        The pieces' aligned potentials.
    estimate : callable
        ``estimate(k, trajectory)`` (N,): the chosen rule's potential estimate along the
        whole ``k``-th trajectory (called only where samples were left out).

    Returns
    -------
    offsets, potentials, groups, inliers
        The same per trajectory.
    """
    owner = spans[:, 0]
    first = np.searchsorted(owner, np.arange(len(parents)))
    offsets = offsets[first]
    kept = np.zeros(len(spans), dtype=bool)
    kept[inliers] = True
    aligned = []
    for k, t in enumerate(parents):
        rows = np.flatnonzero(owner == k)
        if kept[rows].any():
            rows = rows[kept[rows]]
        values = np.full(t.n_samples, np.nan)
        for j in rows:
            values[spans[j, 1]:spans[j, 2]] = potentials[j]
        known = np.flatnonzero(~np.isnan(values))
        if len(known) < t.n_samples:
            whole = estimate(k, t)
            gaps = np.flatnonzero(np.isnan(values))
            near = known[np.abs(gaps[:, None] - known[None, :]).argmin(axis=1)]
            values[gaps] = values[near] + whole[gaps] - whole[near]
        aligned.append(values)
    merged = np.array([groups[owner == k].min() for k in range(len(parents))])
    # A group whose pieces all belong to trajectories with a piece in a lower group
    # vanishes: renumber without gaps, keeping the order.
    groups = np.unique(merged, return_inverse=True)[1].reshape(-1).astype(np.int64)
    inliers = np.unique(owner[inliers])
    return offsets, aligned, groups, inliers


def switch_junctions(spans: np.ndarray, switch_end: np.ndarray, parents: list[Trajectory],
                     phi: list[np.ndarray], groups: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive pieces cut at a constraint switch, and the jump of their offsets there.

    Parameters
    ----------
    spans : ndarray of int, shape (P, 3)
        ``(trajectory, first sample, end)`` of each piece (:func:`split_pieces`).
    switch_end : ndarray of bool, shape (P,)
        Whether each piece ends at a switch cut that lost no samples (the same).
    parents : list of Trajectory
        The whole trajectories.
    phi : list of ndarray
        Each piece's potential estimate (starting at 0).
    groups : ndarray of int, shape (P,)
        The pieces' alignment groups; pieces are tied within a group only.

    Returns
    -------
    pairs : ndarray of int, shape (L, 2)
        Pieces ``(p, p + 1)`` that touch across a step ``i`` that lost no samples.
    jumps : ndarray, shape (L,)
        ``b_{p+1} - b_p`` that makes the aligned potential drop by
        ``dt_i (|v_i|^2 + |v_{i+1}|^2) / 2`` over the step: the drop is ``dt`` times the
        squared speed, the old constraint's before the switch and the new one's after.
    """
    pairs, jumps = [], []
    for p in np.flatnonzero(switch_end[:-1]):
        k, _, end = spans[p]
        t = parents[k]
        if spans[p + 1, 0] != k or spans[p + 1, 1] != end or groups[p] != groups[p + 1]:
            continue
        # A switch cut needs trusted velocities (timing "mid"), so they are there.
        i = int(end) - 1
        v, dt = t.velocities, float(t.dt[i])
        drop = -0.5 * dt * (v[i] @ v[i] + v[i + 1] @ v[i + 1])
        pairs.append((p, p + 1))
        jumps.append(drop + phi[p][-1] - phi[p + 1][0])
    return np.array(pairs, dtype=np.int64).reshape(-1, 2), np.array(jumps, dtype=float)
