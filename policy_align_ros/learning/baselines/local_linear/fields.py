"""Local linear models of the receptive fields: weighted statistics and ridge solves.

Notation and units: ``X`` (m, n) inputs (state units, shifted by a common origin), ``Y``
(m, d) outputs; ``C`` fields with centres (C, n) and width ``h`` (state units). Each local
model is weighted ridge least squares on the points within the field's cut-off.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from policy_align_ros.learning.baselines.local_linear.centres import (
    SPACING,
    CentreIndex,
    FarthestPointCover,
    adaptive_widths,
)

__all__ = [
    "FLOOR_SOFTNESS",
    "default_ridge",
    "extrapolation_floors",
    "fit_fields",
    "local_statistics",
    "solve_local_models",
]

#: Past the lowest output of its data, a floored local model levels off over this
#: fraction of the spread of its values on its data (see :func:`extrapolation_floors`).
FLOOR_SOFTNESS = 0.02


def _features(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Per-point sufficient statistics ``[1, x, y, x x^T (upper), x y^T]``, shape (m, p)."""
    m, n = X.shape
    iu, ju = np.triu_indices(n)
    xy = (X[:, :, None] * Y[:, None, :]).reshape(m, -1)
    return np.hstack([np.ones((m, 1)), X, Y, X[:, iu] * X[:, ju], xy])


def local_statistics(
    X: np.ndarray,
    Y: np.ndarray,
    index: CentreIndex,
    h: float,
    folds: np.ndarray | None = None,
    n_folds: int = 1,
    minima: np.ndarray | None = None,
) -> np.ndarray:
    """Weighted sums of the local sufficient statistics of every field, per fold.

    Parameters
    ----------
    X : ndarray, shape (m, n)
        Inputs, shifted by the same origin as the centres (state units).
    Y : ndarray, shape (m, d)
        Outputs.
    index : CentreIndex
        The ``C`` field centres.
    h : float
        Field width (state units).
    folds : ndarray of int, shape (m,), optional
        Fold of every point, non-decreasing (points sorted by fold); ``None`` puts all
        points in fold 0.
    n_folds : int
        Number of folds ``K``.
    minima : ndarray, shape (C, d), optional
        Lowered in place to the lowest output of every field's own data (the points
        within its cut-off), in the same pass.

    Returns
    -------
    ndarray, shape (K, C, p)
        ``sum_i w_ij [1, x_i, y_i, x_i x_i^T (upper), x_i y_i^T]`` over each fold's points.
    """
    n, d = X.shape[1], Y.shape[1]
    p = 1 + n + d + n * (n + 1) // 2 + n * d
    out = np.zeros((n_folds, len(index.centres), p))
    for start, stop, W in index.weight_blocks(X, h):
        F = _features(X[start:stop], Y[start:stop])
        if minima is not None:
            _lower_to_block_minima(minima, W, Y[start:stop])
        if folds is None:
            out[0] += W.T @ F
            continue
        bounds = np.searchsorted(folds[start:stop], np.arange(n_folds + 1))
        for k in range(n_folds):
            a, b = bounds[k], bounds[k + 1]
            if b > a:
                out[k] += W[a:b].T @ F[a:b]
    return out


def _lower_to_block_minima(minima: np.ndarray, W, Yb: np.ndarray) -> None:
    """Lower ``minima`` (C, d) to the outputs ``Yb`` (b, d) of the points with ``W > 0``."""
    if sp.issparse(W):
        W = W.tocoo()
        inside = W.data > 0
        rows, cols = W.row[inside], W.col[inside]
        for k in range(minima.shape[1]):
            np.minimum.at(minima[:, k], cols, Yb[rows, k])
        return
    inside = W > 0
    for k in range(minima.shape[1]):
        lowest = np.where(inside, Yb[:, k : k + 1], np.inf).min(axis=0)
        np.minimum(minima[:, k], lowest, out=minima[:, k])


def solve_local_models(
    stats: np.ndarray,
    centres: np.ndarray,
    n_outputs: int,
    h: float,
    ridge: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted ridge least-squares local linear models from their statistics.

    ``(Sigma_j + ridge h_j^2 I) B_j^T = Cov_j(x, y)`` with the weighted covariance
    ``Sigma_j`` of field ``j``'s data: the slopes are shrunk toward zero in directions
    without local data.

    Parameters
    ----------
    stats : ndarray, shape (C, p)
        One fold of :func:`local_statistics` (same origin as ``centres``).
    centres : ndarray, shape (C, n)
        Field centres (state units, same origin).
    n_outputs : int
        ``d``.
    h : float or ndarray, shape (C,)
        Field width, common or per field (state units); the slope penalty is
        ``ridge * h^2``.
    ridge : float
        Dimensionless penalty on the slopes.

    Returns
    -------
    intercepts : ndarray, shape (C, d)
        ``beta_j0 = l_j(c_j)``.
    slopes : ndarray, shape (C, d, n)
        ``B_j``, output units per state unit.
    """
    n = centres.shape[1]
    mu, ybar, cov, cxy = _moments(stats, n, n_outputs)
    # A tiny floor keeps the systems solvable with ridge=0 on degenerate data.
    lam = np.reshape(max(ridge, 1e-10) * np.square(h), (-1, 1, 1))
    eye = np.eye(n)
    slopes = np.linalg.solve(cov + lam * eye, cxy)
    slopes = slopes.transpose(0, 2, 1)
    intercepts = ybar + np.einsum("cdn,cn->cd", slopes, centres - mu)
    return intercepts, slopes


def _moments(stats: np.ndarray, n: int, d: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Weighted means and covariances of every field from its :func:`local_statistics`.

    Returns
    -------
    mu : ndarray, shape (C, n)
    ybar : ndarray, shape (C, d)
    cov : ndarray, shape (C, n, n)
        ``Sigma_j`` (state units^2).
    cxy : ndarray, shape (C, n, d)
        ``Cov_j(x, y)``.
    """
    C = len(stats)
    iu, ju = np.triu_indices(n)
    W = stats[:, 0]
    mu = stats[:, 1 : 1 + n] / W[:, None]
    ybar = stats[:, 1 + n : 1 + n + d] / W[:, None]
    k = 1 + n + d
    sxx = np.zeros((C, n, n))
    sxx[:, iu, ju] = stats[:, k : k + len(iu)]
    sxx[:, ju, iu] = stats[:, k : k + len(iu)]
    sxy = stats[:, k + len(iu) :].reshape(C, n, d)
    cov = sxx / W[:, None, None] - mu[:, :, None] * mu[:, None, :]
    cxy = sxy / W[:, None, None] - mu[:, :, None] * ybar[:, None, :]
    return mu, ybar, cov, cxy


def extrapolation_floors(
    stats: np.ndarray,
    centres: np.ndarray,
    intercepts: np.ndarray,
    slopes: np.ndarray,
    minima: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Floors of the local models at the lowest output of their own data.

    A local linear model of a potential is fitted on the data within its field. Where
    these end on one side (the trajectories stop at the minimum), its extrapolation keeps
    sloping down through the minimum, and on curved data it already undershoots the
    lowest data inside the field; the policy ``-grad f`` then carries on past the
    minimum. So field ``j`` does not predict much below the lowest output ``y_min,j`` it
    has seen: its model levels off from ``y_min,j`` over ``FLOOR_SOFTNESS s_j``, with the
    weighted spread ``s_j = sqrt(B_j Sigma_j B_j^T)`` of ``B_j x`` over its data
    (:func:`floored`). At a sample of the field this only moves the model toward the
    sample's output (``y_i >= y_min,j``), and ascending extrapolation stays linear, so far
    from the data the potential still rises and ``-grad f`` points back to them.

    Parameters
    ----------
    stats : ndarray, shape (C, p)
        :func:`local_statistics` of the fields (same origin as ``centres``).
    centres : ndarray, shape (C, n)
    intercepts : ndarray, shape (C, d)
    slopes : ndarray, shape (C, d, n)
    minima : ndarray, shape (C, d)
        :func:`local_statistics`.

    Returns
    -------
    floors, softness : ndarray, shape (C, d)
        In ``u = B_j (x - c_j)`` (output units); ``softness > 0``.
    """
    _, _, cov, _ = _moments(stats, centres.shape[1], slopes.shape[1])
    spread = np.sqrt(np.maximum(np.einsum("cdn,cnm,cdm->cd", slopes, cov, slopes), 0.0))
    softness = np.maximum(FLOOR_SOFTNESS * spread, np.finfo(float).tiny)
    return minima - intercepts, softness


def fit_fields(
    X: np.ndarray,
    Y: np.ndarray,
    h: float,
    ridge: float,
    max_centers: int,
    rng: np.random.Generator,
    floors: bool = False,
    adaptive: bool = False,
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None
]:
    """Place the fields and fit their local models on all data.

    Parameters
    ----------
    X : ndarray, shape (m, n)
        Inputs (state units, shifted by a common origin).
    Y : ndarray, shape (m, d)
        Outputs.
    h, ridge, max_centers, rng
        Width, slope penalty, cap on fields, random source.
    floors : bool
        Also compute the :func:`extrapolation_floors` of the local models.
    adaptive : bool
        Give every field its own width (:func:`adaptive_widths`) instead of ``h``.

    Returns
    -------
    centres : ndarray, shape (C, n)
    intercepts : ndarray, shape (C, d)
    slopes : ndarray, shape (C, d, n)
    floors, softness : ndarray, shape (C, d), or None
        :func:`extrapolation_floors` of the local models; None unless ``floors``.
    widths : ndarray, shape (C,), or None
        Per-field widths (state units); None unless ``adaptive``.
    """
    centres = FarthestPointCover(X, max_centers, rng).centres(SPACING * h)
    index = CentreIndex(centres)
    widths = adaptive_widths(centres, X, h) if adaptive else None
    hw = h if widths is None else widths
    minima = np.full((len(centres), Y.shape[1]), np.inf) if floors else None
    stats = local_statistics(X, Y, index, hw, minima=minima)[0]
    intercepts, slopes = solve_local_models(stats, centres, Y.shape[1], hw, ridge)
    if not floors:
        return centres, intercepts, slopes, None, None, widths
    return (
        centres, intercepts, slopes,
        *extrapolation_floors(stats, centres, intercepts, slopes, minima), widths,
    )


def default_ridge(n: int) -> float:
    """Default slope penalty for ``n`` input dimensions: ``1e-3 (n / 2)^2``."""
    return 1e-3 * (n / 2.0) ** 2
