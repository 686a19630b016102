"""Validation, BLAS threads and cross-validation folds shared by the estimators.

Notation: ``X`` (m, n) states in state units, ``y`` (m,) outputs, ``groups`` (m,) the
demonstration of every sample; samples of one demonstration are consecutive and in time
order.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence

import numpy as np

try:  # Optional: OpenBLAS threads slow the many small products of the fits down a lot.
    from threadpoolctl import ThreadpoolController
except ImportError:  # pragma: no cover - depends on the environment
    ThreadpoolController = None
_CONTROLLER = None  # built once: inspecting the loaded BLAS libraries takes ~10 ms

__all__ = ["assign_folds", "check_Xy", "check_finite", "check_masks", "check_query",
           "single_blas_thread"]


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


def check_finite(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float array of ``shape`` with finite entries (a ``ValueError`` naming
    ``name`` otherwise)."""
    array = np.asarray(value, dtype=float)
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be a finite {shape} array, got shape {array.shape}")
    return array


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


def check_masks(train_mask: Sequence[np.ndarray] | None, trajs: Sequence
                ) -> list[np.ndarray]:
    """The training masks of ``trajs`` (Trajectory), all True when ``train_mask`` is None;
    ValueError naming the mask that is not a bool array of its trajectory's length."""
    if train_mask is None:
        return [np.ones(t.n_samples, dtype=bool) for t in trajs]
    masks = list(train_mask)
    if len(masks) != len(trajs):
        raise ValueError(f"train_mask has {len(masks)} entries for {len(trajs)} trajectories")
    out = []
    for k, (m, t) in enumerate(zip(masks, trajs, strict=True)):
        m = np.asarray(m)
        if m.shape != (t.n_samples,) or m.dtype != bool:
            raise ValueError(
                f"train_mask {k}: must be a bool array of shape ({t.n_samples},), "
                f"got {m.dtype} {m.shape}"
            )
        out.append(m)
    return out


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
