"""Validation, thinning and cross-validation folds shared by the regressors.

Notation: ``X`` (m, n) states in state units, ``y`` (m,) outputs, ``groups`` (m,) the
demonstration of every sample; samples of one demonstration are consecutive and in time
order.
"""

from __future__ import annotations

import contextlib

import numpy as np

try:  # Optional: OpenBLAS threads slow the many small products of the fits down a lot.
    from threadpoolctl import ThreadpoolController
except ImportError:  # pragma: no cover - depends on the environment
    ThreadpoolController = None
_CONTROLLER = None  # built once: inspecting the loaded BLAS libraries takes ~10 ms

__all__ = ["assign_folds", "check_Xy", "check_query", "single_blas_thread",
           "thin_by_arc_length"]


def single_blas_thread() -> contextlib.AbstractContextManager:
    """Context limiting BLAS to one thread (when threadpoolctl is installed).

    The fit and the prediction run many small matrix products, which OpenBLAS's thread
    pool slows down on a shared machine.
    """
    global _CONTROLLER
    if ThreadpoolController is None:
        return contextlib.nullcontext()
    if _CONTROLLER is None:
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER.limit(limits=1, user_api="blas")


def check_Xy(X: np.ndarray, y: np.ndarray, groups: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate training data; ``groups=None`` makes every sample one demonstration.

    Returns
    -------
    X (m, n), y (m,), groups (m,) of int

    Raises
    ------
    ValueError
        Naming the argument and the problem.
    """
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    if X.ndim != 2 or len(X) < 2:
        raise ValueError(f"X must have shape (m >= 2, n), got {X.shape}")
    if y.shape != (len(X),):
        raise ValueError(f"y must have shape ({len(X)},), got {y.shape}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(y))):
        raise ValueError("X and y must be finite (no NaN or inf)")
    if groups is None:
        groups = np.zeros(len(X), dtype=np.int64)
    groups = np.asarray(groups)
    if groups.shape != (len(X),) or not np.issubdtype(groups.dtype, np.integer):
        raise ValueError(f"groups must be an int array of shape ({len(X)},), got "
                         f"{groups.dtype} {groups.shape}")
    return X, y, groups


def check_query(X: np.ndarray, n: int) -> np.ndarray:
    """Query states as a finite (m, n) float array (a single (n,) state is promoted)."""
    X = np.asarray(X, dtype=float)
    if X.ndim == 1:
        X = X[None, :]
    if X.ndim != 2 or X.shape[1] != n:
        raise ValueError(f"X must have shape (m, {n}), got {np.shape(X)}")
    if not np.all(np.isfinite(X)):
        bad = int(np.argwhere(~np.isfinite(X))[0, 0])
        raise ValueError(f"X contains NaN or inf (first at row {bad})")
    return X


def thin_by_arc_length(X: np.ndarray, groups: np.ndarray, max_points: int) -> np.ndarray:
    """Indices of at most about ``max_points`` samples, evenly spaced in arc length.

    Every demonstration keeps the same share of the budget (at least 2 samples), placed
    evenly along its path, so a robot at rest or a high sampling rate adds no weight.

    Parameters
    ----------
    X : ndarray (m, n)
    groups : ndarray of int (m,)
    max_points : int

    Returns
    -------
    ndarray of intp
        Sorted indices (all of them when ``m <= max_points``).
    """
    m = len(X)
    if m <= max_points:
        return np.arange(m)
    change = np.flatnonzero(np.diff(groups) != 0) + 1
    starts = np.concatenate(([0], change))
    stops = np.concatenate((change, [m]))
    per = max(2, max_points // len(starts))
    out = []
    for a, b in zip(starts, stops, strict=True):
        if b - a <= per:
            out.append(np.arange(a, b))
            continue
        arc = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(X[a:b], axis=0), axis=1))))
        if arc[-1] <= 0:
            out.append(np.array([a, b - 1]))
            continue
        pick = np.searchsorted(arc, np.linspace(0.0, arc[-1], per))
        out.append(a + np.unique(np.minimum(pick, b - a - 1)))
    return np.concatenate(out)


def assign_folds(groups: np.ndarray, n_folds: int, rng: np.random.Generator) -> np.ndarray:
    """Fold of every sample, whole groups per fold, folds balanced in size.

    Parameters
    ----------
    groups : ndarray of int, shape (m,)
    n_folds : int
    rng : numpy.random.Generator

    Returns
    -------
    ndarray of int, shape (m,)
        Fold index in ``0 .. n_folds - 1``.
    """
    ids, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
    order = rng.permutation(len(ids))
    order = order[np.argsort(-counts[order], kind="stable")]
    load = np.zeros(n_folds)
    fold_of = np.empty(len(ids), dtype=int)
    for g in order:
        k = int(np.argmin(load))
        fold_of[g] = k
        load[k] += counts[g]
    return fold_of[inverse]
