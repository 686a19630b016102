"""Thinning of demonstrations: which samples a computation keeps when there are too many.

Notation: ``X`` (m, n) states (state units) of several demonstrations stored one after the
other, each in time order; ``groups`` (m,) the demonstration of every sample. Consecutive
samples of a demonstration are nearly duplicates at the scale of most computations, and a
robot at rest or a high sampling rate multiplies them; thinning keeps the spacing between
demonstrations, which is what the models need.

One function, :func:`thin_trajectories`, with one rule per use:

- ``"share"``: at most about ``max_points`` samples; under the budget everything is kept,
  over it every demonstration keeps the same share of the budget (at least 2), evenly
  spaced in arc length, and one that does not move keeps its first and last samples;
- ``"cap"``: every demonstration longer than its share ``max(2, max_points // K)`` is
  thinned to it, evenly in arc length, even when the total is under the budget (one that
  does not move keeps its first sample);
- ``"stride"``: every demonstration keeps every ``s``-th sample from a random offset (``s``
  common, but at least ``MIN_SAMPLES_PER_GROUP`` of each kept), and whole demonstrations
  are dropped at random only when that is not enough; samples need not be contiguous;
- ``spacing=`` (instead of ``max_points``): the first sample of every ``spacing``-long
  piece of arc length, so every sample lies within ``spacing`` (along its demonstration)
  of the kept sample before it.

"Evenly in arc length" keeps, for ``p`` marks spaced evenly from 0 to the demonstration's
length, the first sample at or past each mark.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["MIN_SAMPLES_PER_GROUP", "RULES", "thin_each", "thin_trajectories"]

RULES = ("share", "cap", "stride")
#: Fewest samples kept per demonstration by the ``"stride"`` rule.
MIN_SAMPLES_PER_GROUP = 25


def thin_trajectories(
    X: np.ndarray | None,
    groups: np.ndarray,
    max_points: int | None = None,
    *,
    spacing: float | None = None,
    rule: str = "share",
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Indices of the samples kept when thinning demonstrations (module docstring).

    Parameters
    ----------
    X : ndarray, shape (m, n), or None
        States (state units); only the ``"stride"`` rule does without them.
    groups : ndarray of int, shape (m,)
        Demonstration of every sample; samples of one demonstration consecutive and in
        time order (the ``"stride"`` rule only needs the time order).
    max_points : int, optional
        Budget of samples (all rules but ``spacing``).
    spacing : float, optional
        Arc length (state units) of the pieces of which the first sample is kept, instead
        of a budget; ``<= 0`` keeps every sample.
    rule : {"share", "cap", "stride"}
        How the budget is spent (module docstring).
    rng : numpy.random.Generator, optional
        Random source of the ``"stride"`` rule.

    Returns
    -------
    ndarray of intp
        Sorted indices of the kept samples.
    """
    groups = np.asarray(groups)
    if spacing is not None:
        if max_points is not None:
            raise ValueError("thin_trajectories: give max_points or spacing, not both")
        return _by_spacing(X, groups, float(spacing))
    if rule not in RULES:
        raise ValueError(f"thin_trajectories: rule must be one of {RULES}, got {rule!r}")
    if max_points is None:
        raise ValueError("thin_trajectories: give max_points or spacing")
    m = len(groups)
    if rule == "stride":
        if rng is None:
            raise ValueError("thin_trajectories: the 'stride' rule needs an rng")
        return _by_stride(groups, max_points, rng)
    if rule == "share" and m <= max_points:
        return np.arange(m)
    change = np.flatnonzero(np.diff(groups) != 0) + 1
    starts = np.concatenate(([0], change))
    stops = np.concatenate((change, [m]))
    per = max(2, max_points // len(starts))
    out = [_even_in_arc(X, a, b, per, keep_ends=rule == "share")
           for a, b in zip(starts, stops, strict=True)]
    return np.concatenate(out)


def thin_each(trajectories: Sequence[np.ndarray], max_points: int) -> list[np.ndarray]:
    """The ``"cap"`` rule of :func:`thin_trajectories` on a list of demonstrations.

    Parameters
    ----------
    trajectories : sequence of ndarray, each of shape (N_k, n), N_k >= 1
    max_points : int

    Returns
    -------
    list of ndarray, each of shape (N'_k, n)
        The thinned demonstrations, in order.
    """
    if not trajectories:
        return []
    sizes = [len(x) for x in trajectories]
    X = np.concatenate(trajectories)
    groups = np.repeat(np.arange(len(trajectories)), sizes)
    idx = thin_trajectories(X, groups, max_points, rule="cap")
    counts = np.bincount(groups[idx], minlength=len(trajectories))
    return np.split(X[idx], np.cumsum(counts)[:-1])


def _even_in_arc(X: np.ndarray, a: int, b: int, per: int, keep_ends: bool) -> np.ndarray:
    """Indices of about ``per`` samples of ``X[a:b]`` evenly spaced in arc length."""
    if b - a <= per:
        return np.arange(a, b)
    arc = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(X[a:b], axis=0), axis=1))))
    if keep_ends and arc[-1] <= 0:
        return np.array([a, b - 1])
    pick = np.searchsorted(arc, np.linspace(0.0, arc[-1], per))
    return a + np.unique(np.minimum(pick, b - a - 1))


def _by_spacing(X: np.ndarray, groups: np.ndarray, spacing: float) -> np.ndarray:
    """First sample of every ``spacing``-long piece of arc length of each demonstration."""
    if spacing <= 0:
        return np.arange(len(X))
    steps = np.linalg.norm(np.diff(X, axis=0), axis=1)
    steps[groups[1:] != groups[:-1]] = 0.0
    arc = np.concatenate(([0.0], np.cumsum(steps)))
    bins = np.floor(arc / spacing).astype(np.int64)
    first = np.ones(len(X), dtype=bool)
    first[1:] = (bins[1:] != bins[:-1]) | (groups[1:] != groups[:-1])
    return np.flatnonzero(first)


def _by_stride(groups: np.ndarray, max_points: int, rng: np.random.Generator) -> np.ndarray:
    """Every ``s``-th sample of each demonstration; whole ones dropped when not enough."""
    m = len(groups)
    if m <= max_points:
        return np.arange(m)
    order = np.argsort(groups, kind="stable")
    _, starts, counts = np.unique(groups[order], return_index=True, return_counts=True)
    stride = np.clip(counts // MIN_SAMPLES_PER_GROUP, 1, math.ceil(m / max_points))
    kept = -(-counts // stride)
    chosen = rng.permutation(len(counts))
    total = np.cumsum(kept[chosen])
    chosen = np.sort(chosen[: int(np.searchsorted(total, max_points, side="right")) or 1])
    idx = [
        order[starts[g] + np.arange(int(rng.integers(stride[g])), counts[g], stride[g])]
        for g in chosen
    ]
    return np.sort(np.concatenate(idx))
