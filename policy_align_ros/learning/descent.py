"""Descents of a learnt potential: its local minima, and where its flow from given starts
stops.

A potential-based policy ``pi(x) = -grad f(x)`` stops where ``f`` has a minimum. The fit's
checks (:mod:`~policy_align_ros.learning.goal`, :mod:`~policy_align_ros.learning.anchor`,
:mod:`~policy_align_ros.learning.new_starts`, :mod:`~policy_align_ros.learning.folds`)
need both where those minima are and which of them a run from a given start reaches:

- :func:`learnt_minima`: the local minima, by projected Barzilai-Borwein descents with the
  analytic gradient, all starts at once, merged when closer than a tolerance tied to the
  data's scale; a descent that leaves the box around the data found no minimum (the
  policy runs away there);
- :func:`flow_stops`: where descents whose steps are capped at :data:`END_RADIUS` of the
  extent stop, so that they follow the flow a run takes instead of leaping into another
  basin;
- :func:`merge_points` and :func:`cluster_labels`: points closer than a tolerance as one.

Notation as in :mod:`~policy_align_ros.learning.goal`: states ``X`` (m, n) in state units,
the data's extent ``W`` (the largest side of its bounding box). ``docs/design/
goal_report.md`` gives the reasons for the tolerances.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = [
    "BOX_MARGIN",
    "END_RADIUS",
    "GRADIENT_TOL",
    "MINIMA_MERGE",
    "Field",
    "Minima",
    "cluster_labels",
    "data_box",
    "flow_stops",
    "learnt_minima",
    "merge_points",
]

#: The longest step of a descent that follows the learnt policy's flow (:func:`flow_stops`),
#: as a fraction of the extent.
END_RADIUS = 0.01
#: Learnt minima (and descent starts) closer than this fraction of the extent are one.
MINIMA_MERGE = 1e-3
#: The descent's box: the data's bounding box widened by this many extents on each side.
BOX_MARGIN = 1.0
#: The descent stops when the learnt speed is below this fraction of the speed scale: the
#: minimum is then located to about this fraction of the distance over which the learnt
#: speed reaches the typical speed.
GRADIENT_TOL = 1e-6

#: A learnt potential, or its gradient, at states ``X`` (m, n): (m,) or (m, n).
Field = Callable[[np.ndarray], np.ndarray]


class Minima(NamedTuple):
    """Local minima of a learnt potential (:func:`learnt_minima`).

    Attributes
    ----------
    points : ndarray (k, n)
        The minima (state units), lowest potential first.
    values : ndarray (k,)
        The potential there.
    n_escaped : int
        Descents that left the box around the data: no minimum there.
    """

    points: np.ndarray
    values: np.ndarray
    n_escaped: int


def learnt_minima(potential: Field, gradient: Field, starts: np.ndarray, *,
                  scale: float | None = None, speed: float | None = None,
                  bounds: tuple[np.ndarray, np.ndarray] | None = None,
                  merge_tol: float = MINIMA_MERGE, max_iter: int = 1000) -> Minima:
    """Local minima of a learnt potential, by descent from ``starts``.

    Parameters
    ----------
    potential, gradient : callable
        ``potential(X)`` (m,) and ``gradient(X)`` (m, n) of the learnt potential at states
        ``X`` (m, n); the policy is ``-gradient``.
    starts : ndarray (s, n)
        Where the descents start (state units); starts closer than ``merge_tol * scale``
        are descended once.
    scale : float, optional
        The data's extent (state units): the unit of ``merge_tol`` and of the box. Default:
        the largest side of the starts' bounding box (1 if they coincide).
    speed : float, optional
        The typical speed (state units per second): a descent stops where the learnt speed
        is below ``GRADIENT_TOL * speed``. Default: the largest learnt speed at the starts.
    bounds : (lo, hi) ndarrays (n,), optional
        The box of the descent (state units). Default: the starts' bounding box widened by
        ``BOX_MARGIN * scale`` on each side. A descent that ends on its boundary found no
        minimum and is counted in ``n_escaped``.
    merge_tol : float
        Minima closer than ``merge_tol * scale`` are one (the lowest is kept).
    max_iter : int
        Iterations of each descent.

    Returns
    -------
    Minima
        The merged minima (k, n), lowest potential first, their potential values (k,) and
        the number of descents that escaped.
    """
    starts = np.atleast_2d(np.asarray(starts, dtype=float))
    if starts.ndim != 2 or not len(starts) or not np.all(np.isfinite(starts)):
        raise ValueError(f"starts: need a finite (s, n) array, got shape {starts.shape}")
    n = starts.shape[1]
    if scale is None:
        side = float(np.max(np.ptp(starts, axis=0)))
        scale = side if side > 0 else 1.0
    if not scale > 0:
        raise ValueError(f"scale: must be positive, got {scale!r}")
    starts = merge_points(starts, np.zeros(len(starts)), merge_tol * scale)[0]
    if speed is None:
        speed = float(np.max(np.linalg.norm(gradient(starts), axis=1)))
    gtol = GRADIENT_TOL * (speed if speed > 0 else 1.0)
    if bounds is None:
        bounds = data_box(starts, scale)
    lo, hi = (np.asarray(b, dtype=float).reshape(n) for b in bounds)
    X = _descend(potential, gradient, np.clip(starts, lo, hi), lo, hi, gtol, scale,
                 max_iter)
    inside = _inside(X, lo, hi, scale)
    if not inside.any():
        return Minima(np.zeros((0, n)), np.zeros(0), int(len(X)))
    P, v = merge_points(X[inside], potential(X[inside]), merge_tol * scale)
    return Minima(P, v, int(np.count_nonzero(~inside)))


def data_box(X: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The bounding box of the states ``X`` (m, n) widened by ``BOX_MARGIN * scale`` on
    each side (state units): where descents of a learnt potential look for minima."""
    return X.min(axis=0) - BOX_MARGIN * scale, X.max(axis=0) + BOX_MARGIN * scale


def _inside(X: np.ndarray, lo: np.ndarray, hi: np.ndarray, scale: float) -> np.ndarray:
    """Rows of ``X`` (s, n) that ended off the box's boundary: descents that stopped."""
    edge = 1e-9 * scale
    return ~np.any((X <= lo + edge) | (X >= hi - edge), axis=1)


def _descend(potential: Field, gradient: Field, X: np.ndarray, lo: np.ndarray,
             hi: np.ndarray, gtol: float, scale: float, max_iter: int,
             max_step: float = math.inf) -> np.ndarray:
    """Projected gradient descent of every row of ``X`` (s, n) at once, inside the box
    ``[lo, hi]``; returns where the rows end (s, n).

    Each row takes Barzilai-Borwein steps (the secant estimate of the inverse curvature,
    which copes with the anisotropic bowls the trend fits), shrunk until the potential
    decreases (Armijo); a row stops when its projected gradient is below ``gtol`` or its
    steps no longer move it. All rows share one call of ``potential`` and ``gradient``
    per iteration: a descent costs a few hundred batched evaluations, not one per row.
    ``max_step`` (state units) caps every step's length: the descent then follows the
    policy's flow instead of leaping into another basin of lower potential.
    """
    X = X.copy()
    joint = _joint(potential, gradient)
    f, g = potential(X), gradient(X)
    alpha = 0.01 * scale / np.maximum(np.linalg.norm(g, axis=1), gtol)
    active = np.linalg.norm(_projected(g, X, lo, hi), axis=1) > gtol
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if not idx.size:
            break
        step_size = alpha[idx, None]
        if math.isfinite(max_step):
            # On the gradient's norm, not the step's: a Barzilai-Borwein step can overflow,
            # and so can its product with the norm (a step grown by 4 at every iteration
            # up a concave slope); an infinite product is a step to cap, not a warning.
            norm = np.linalg.norm(g[idx], axis=1, keepdims=True)
            with np.errstate(over="ignore"):
                too_long = step_size * norm > max_step
            step_size = np.where(too_long, max_step / np.maximum(norm, 1e-300), step_size)
        trial = np.clip(X[idx] - step_size * g[idx], lo, hi)
        step = trial - X[idx]
        f_trial, g_trial = joint(trial) if joint is not None else (potential(trial), None)
        ok = f_trial <= f[idx] + 1e-4 * np.einsum("ij,ij->i", g[idx], step)
        alpha[idx[~ok]] *= 0.25
        with np.errstate(over="ignore"):  # an overflowing step is not a vanishing one
            done = alpha[idx] * np.linalg.norm(g[idx], axis=1) < 1e-12 * scale
        if ok.any():
            acc = idx[ok]
            # Rows evaluated in another batch can differ in the last bit: the joint
            # evaluation is used when every row was accepted, as the results stay equal.
            g_new = g_trial if g_trial is not None and ok.all() else gradient(trial[ok])
            s, y = step[ok], g_new - g[acc]
            sy, ss = np.einsum("ij,ij->i", s, y), np.einsum("ij,ij->i", s, s)
            # On a nearly flat potential the secant step overflows to inf; the next step is
            # then capped (max_step, the box) and shrunk by the Armijo test, so the overflow
            # is not a warning the fit should pass on.
            with np.errstate(over="ignore"):
                alpha[acc] = np.where(sy > 0, ss / np.where(sy > 0, sy, 1.0),
                                      4.0 * alpha[acc])
            X[acc], f[acc], g[acc] = trial[ok], f_trial[ok], g_new
            done[ok] |= np.linalg.norm(_projected(g_new, X[acc], lo, hi), axis=1) <= gtol
        active[idx[done]] = False
    return X


def _joint(potential: Field, gradient: Field
           ) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None:
    """``X -> (potential(X), gradient(X))`` in one call when both are a model's ``predict``
    and ``gradient`` and it has ``value_and_gradient`` (one kernel evaluation per step
    of a descent instead of two); None otherwise."""
    owner = getattr(potential, "__self__", None)
    joint = getattr(owner, "value_and_gradient", None)
    if (joint is None or getattr(gradient, "__self__", None) is not owner
            or getattr(potential, "__name__", "") != "predict"
            or getattr(gradient, "__name__", "") != "gradient"):
        return None
    return joint


def _projected(g: np.ndarray, X: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The gradient ``g`` (m, n) without the components that push ``X`` out of the box."""
    out = g.copy()
    out[(X <= lo) & (g > 0)] = 0.0
    out[(X >= hi) & (g < 0)] = 0.0
    return out


def merge_points(points: np.ndarray, values: np.ndarray, tol: float
           ) -> tuple[np.ndarray, np.ndarray]:
    """Points closer than ``tol`` (chained) as one: the lowest ``values`` of each group,
    the groups ordered by it."""
    if len(points) < 2 or tol <= 0:
        order = np.argsort(values, kind="stable")
        return points[order], values[order]
    labels = cluster_labels(points, tol)
    keep = [int(np.flatnonzero(labels == c)[np.argmin(values[labels == c])])
            for c in range(labels.max() + 1)]
    keep = sorted(keep, key=lambda i: values[i])
    return points[keep], values[keep]


def cluster_labels(points: np.ndarray, tol: float) -> np.ndarray:
    """Single-linkage cluster label of every point (chains of points closer than ``tol``)."""
    pairs = cKDTree(points).query_pairs(tol, output_type="ndarray")
    m = len(points)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
    return connected_components(graph, directed=False)[1]


def flow_stops(potential: Field, gradient: Field, starts: np.ndarray, X: np.ndarray,
               extent: float, speed: float) -> tuple[np.ndarray, np.ndarray]:
    """Where runs of the learnt policy from ``starts`` (s, n) stop, by a descent whose steps
    are at most ``END_RADIUS`` of the extent (so that it follows the flow a run takes
    instead of leaping into another basin) inside :func:`data_box` of the samples ``X``
    (m, n); and which of them stopped inside that box (s,) rather than leaving it.

    ``extent`` and ``speed`` are the data's extent W (state units) and typical speed (state
    units/s), as :func:`data_extent` and :func:`typical_speed` give them.
    """
    lo, hi = data_box(X, extent)
    gtol = GRADIENT_TOL * (speed if speed > 0 else 1.0)
    ends = _descend(potential, gradient, starts, lo, hi, gtol, extent, 4000,
                    max_step=END_RADIUS * extent)
    return ends, _inside(ends, lo, hi, extent)
