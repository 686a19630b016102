"""Choice of the field width of the local-linear regression by cross-validation over whole
held-out trajectories.
"""

from __future__ import annotations

import math

import numpy as np

from policy_align_ros.learning.baselines.local_linear.blend import blend
from policy_align_ros.learning.baselines.local_linear.centres import (
    SPACING,
    CentreIndex,
    FarthestPointCover,
    adaptive_widths,
)
from policy_align_ros.learning.baselines.local_linear.fields import (
    local_statistics,
    solve_local_models,
)
from policy_align_ros.learning.fitting import assign_folds
from policy_align_ros.learning.thinning import thin_trajectories

__all__ = ["auto_grid", "cross_validate", "cv_errors", "select_bandwidth"]

#: Largest number of points used for cross-validation (whole trajectories, thinned).
MAX_CV_POINTS = 20000
#: Relative grid of candidate widths, times the RMS spread of the data.
GRID_FACTORS = np.geomspace(0.02, 2.0, 11)
#: The chosen width is the CV-optimal one divided by this (gradients want narrower).
GRADIENT_NARROWING = 1.7
#: A local model enters a CV prediction only with this much training weight (points).
MIN_FIELD_WEIGHT = 0.5


def auto_grid(X: np.ndarray) -> np.ndarray:
    """Candidate widths: a geometric grid times the RMS spread of the data.

    Parameters
    ----------
    X : ndarray, shape (m, n)

    Returns
    -------
    ndarray, shape (11,)
        Widths (state units), increasing.
    """
    spread = float(np.sqrt(np.sum(np.var(X, axis=0))))
    if spread <= 0.0:
        spread = 1.0
    return spread * GRID_FACTORS


def cross_validate(
    X: np.ndarray,
    Y: np.ndarray,
    groups: np.ndarray | None,
    grid: np.ndarray,
    ridge: float,
    rng: np.random.Generator,
    *,
    n_folds: int,
    max_centers: int,
    increments: bool,
    widths: str,
) -> tuple[float, dict[float, float], bool]:
    """Width chosen by K-fold CV over whole held-out trajectories, and per-field widths.

    The candidate widths are evaluated from wide to narrow: narrow widths cost most (many
    fields), so once two in a row are clearly worse than the best so far, or the cap on
    centres leaves holes between fields, narrower ones are not evaluated.

    Parameters
    ----------
    X : ndarray, shape (m, n)
        Inputs (state units, shifted by a common origin).
    Y : ndarray, shape (m, d)
        Outputs.
    groups : ndarray of int, shape (m,), or None
        Trajectory of every sample; None (or a single one) uses contiguous blocks.
    grid : ndarray, shape (G,)
        Candidate widths, increasing (state units).
    ridge : float
        Slope penalty.
    rng : numpy.random.Generator
        Thinning, folds and the first centre of the cover.
    n_folds, max_centers : int
        Folds of whole trajectories; cap on the fields.
    increments : bool
        Score the increments along each held-out trajectory (else the values).
    widths : {"global", "adaptive", "cv"}
        "cv" compares per-field widths with the global one at the CV-optimal width.

    Returns
    -------
    h : float
        Chosen width (state units), :func:`select_bandwidth`.
    scores : dict of float to float
        Mean held-out error (outputs scaled to unit variance) per evaluated width.
    adaptive : bool
        Whether the fields get their own widths.
    """
    Xc, Yc, gc, folds = _cv_sample(X, Y, groups, n_folds, rng)
    tracks = gc if increments else None
    # One farthest-point order serves every width: its prefixes are the covers.
    cover = FarthestPointCover(Xc, max_centers, rng)
    errors = []
    for h in grid[::-1]:
        centres = cover.centres(SPACING * h)
        if cover.capped and cover.radius > 2.0 * SPACING * h and len(errors) >= 3:
            break
        errors.append(cv_errors(Xc, Yc, folds, centres, float(h), ridge, tracks))
        if len(errors) >= 3 and _clearly_worse(errors):
            break
    grid = grid[::-1][: len(errors)][::-1]
    curve = np.array(errors[::-1])  # (G, K)
    scores = {float(h): float(e) for h, e in zip(grid, curve.mean(axis=1), strict=True)}
    adaptive = widths == "adaptive"
    if widths == "cv":
        best = int(np.argmin(curve.mean(axis=1)))
        adapted = cv_errors(
            Xc, Yc, folds, cover.centres(SPACING * grid[best]), float(grid[best]), ridge,
            tracks, adaptive=True,
        )
        adaptive = bool(adapted.mean() < curve[best].mean())
    return select_bandwidth(grid, curve), scores, adaptive


def _cv_sample(X, Y, groups, n_folds, rng):
    """CV data: thinned, in folds of whole trajectories, sorted by fold, ``Y`` scaled.

    Returns ``X`` (m', n), ``Y`` (m', d) with unit-variance columns, ``groups`` (m',) and
    ``folds`` (m',), non-decreasing.
    """
    m = X.shape[0]
    if groups is None or len(np.unique(groups)) < 2:
        # Contiguous blocks stand in for trajectories: neighbours in time stay together.
        blocks = min(max(n_folds, 10 * n_folds), m)
        groups = (np.arange(m) * blocks) // m
    idx = thin_trajectories(None, groups, MAX_CV_POINTS, rule="stride", rng=rng)
    Xc, Yc, gc = X[idx], Y[idx], groups[idx]
    folds = assign_folds(gc, min(n_folds, len(np.unique(gc))), rng)
    by_fold = np.argsort(folds, kind="stable")
    Xc, Yc, gc, folds = Xc[by_fold], Yc[by_fold], gc[by_fold], folds[by_fold]
    scale = Yc.std(axis=0)
    Yc = (Yc - Yc.mean(axis=0)) / np.where(scale > 0, scale, 1.0)
    return Xc, Yc, gc, folds


def cv_errors(
    X: np.ndarray,
    Y: np.ndarray,
    folds: np.ndarray,
    centres: np.ndarray,
    h: float,
    ridge: float,
    groups: np.ndarray | None = None,
    adaptive: bool = False,
) -> np.ndarray:
    """Held-out error of each fold for one width.

    The centres are placed on all CV inputs (no outputs are used to place them); each
    fold's local models are solved from the statistics of the other folds, and fields with
    less than ``MIN_FIELD_WEIGHT`` of training weight are left out of its prediction.

    Parameters
    ----------
    X : ndarray, shape (m, n)
    Y : ndarray, shape (m, d)
        Outputs, each column scaled to unit variance.
    folds : ndarray of int, shape (m,)
        Non-decreasing (points sorted by fold).
    centres : ndarray, shape (C, n)
    h : float
        Width (state units).
    ridge : float
        Slope penalty.
    groups : ndarray of int, shape (m,), optional
        Trajectory ids, samples in time order: when given, the error is that of the
        increments between consecutive held-out samples of one trajectory (the
        "increments" criterion), else the plain mean squared error.
    adaptive : bool
        Per-field widths :func:`adaptive_widths` around ``h`` (from the CV inputs).

    Returns
    -------
    ndarray, shape (K,)
        Error per held-out fold (summed over outputs).
    """
    n_folds = int(folds.max()) + 1
    d = Y.shape[1]
    hw = adaptive_widths(centres, X, h) if adaptive else h
    fold_stats = local_statistics(X, Y, CentreIndex(centres), hw, folds, n_folds)
    errors = np.empty(n_folds)
    for k in range(n_folds):
        train = fold_stats[np.arange(n_folds) != k].sum(axis=0)
        valid = train[:, 0] >= MIN_FIELD_WEIGHT
        held = folds == k
        g = None if groups is None else groups[held]
        if not np.any(valid):
            errors[k] = _held_out_error(-Y[held], g)
            continue
        hv = hw[valid] if adaptive else h
        b0, B = solve_local_models(train[valid], centres[valid], d, hv, ridge)
        pred, _ = blend(X[held], CentreIndex(centres[valid]), b0, B, hv)
        errors[k] = _held_out_error(pred - Y[held], g)
    return errors


def _held_out_error(residual: np.ndarray, groups: np.ndarray | None) -> float:
    """Held-out error: mean squared residual, or of its increments along each group.

    With groups, the error is that of the predicted *differences* between consecutive
    samples of each held-out trajectory: a potential is known only up to an offset per
    trajectory, and errors in the estimated potential drift along a trajectory, while the
    increments measure the directional derivative, which the policy needs.
    """
    if groups is None:
        return float(np.mean(np.sum(residual**2, axis=1)))
    same = groups[1:] == groups[:-1]
    if not np.any(same):
        return float(np.mean(np.sum(residual**2, axis=1)))
    step = np.diff(residual, axis=0)[same]
    return float(np.mean(np.sum(step**2, axis=1)))


def _clearly_worse(errors: list[np.ndarray]) -> bool:
    """True when the last two fold-error vectors exceed the best mean by its SE."""
    means = [e.mean() for e in errors]
    best = int(np.argmin(means))
    e = errors[best]
    se = e.std(ddof=1) / math.sqrt(len(e)) if len(e) > 1 else 0.0
    return best < len(errors) - 2 and min(means[-2:]) > means[best] + se


def select_bandwidth(grid: np.ndarray, fold_errors: np.ndarray) -> float:
    """Width for the gradient: the CV-optimal width, narrowed by ``GRADIENT_NARROWING``.

    The minimum of the mean held-out error is refined by a parabola in ``log h`` through
    the best grid point and its neighbours. Held-out errors of the *potential* are least
    at a wider width than errors of its *gradient* (the policy), hence the narrowing.

    Parameters
    ----------
    grid : ndarray, shape (G,)
        Candidate widths, increasing (state units).
    fold_errors : ndarray, shape (G, K)
        Held-out error of every fold.

    Returns
    -------
    float
        Width (state units), within ``[grid[0], grid[-1]]``.
    """
    mean = fold_errors.mean(axis=1)
    best = int(np.nanargmin(mean))
    log_h = math.log(grid[best])
    if 0 < best < len(grid) - 1:
        x = np.log(grid[best - 1 : best + 2])
        a, b, _ = np.polyfit(x, mean[best - 1 : best + 2], 2)
        if a > 0:
            log_h = float(np.clip(-b / (2.0 * a), x[0], x[2]))
    return float(np.clip(math.exp(log_h) / GRADIENT_NARROWING, grid[0], grid[-1]))
