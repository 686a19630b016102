"""Global regression of the LWPR family with an exact analytic gradient.

PolicyAlign (paper section III-D, eq. 16) fits a global model ``f(x)`` of the potential on
the aligned data and uses ``pi_hat(x) = -grad f(x)`` as the policy. The paper uses LWPR;
this module implements LWPR's prediction rule with a batch fit. The measurements behind
the design choices and defaults are in ``docs/notes/local_linear.md``.

Notation and units
------------------
``x`` in ``R^n`` is a state (state units, e.g. rad or m); ``y`` in ``R^d`` an output (for
the potential ``d = 1``, in state units^2 per second). Receptive field ``j`` has centre
``c_j`` and width ``h_j`` (state units): the global width ``h``, or its own with per-field
widths. Its weight is a Gaussian with a smooth polynomial cut-off at ``R = CUTOFF h``, so
that sums over neighbours are exact and sparse::

    g(s; h^2) = exp(-s / (2 h^2)) (1 - (s / R^2)^2)^2  for s < R^2, else 0;  s = ||x - c||^2

Model
-----
Each field carries a local linear model ``l_j(x) = beta_j0 + B_j (x - c_j)`` (``B_j`` of
shape (d, n)). The prediction is the normalised blend (LWPR)::

    f(x) = sum_j v_j(x) l_j(x) / sum_j v_j(x),
    v_j(x) = g(||x - c_j||^2 - t(x); H_j^2(t(x))),   t(x) = min_k ||x - c_k||^2

Subtracting ``t`` cancels in the Gaussian factor and keeps every point's nearest field at
weight 1, so the prediction stays finite far from the data; the blending width ``H_j`` is
``h_j`` near the data and grows like ``FAR_WIDENING * sqrt(t)`` far from it, so that the
gradient stays bounded there too (:func:`blend_width2`). ``grad f`` follows from the
quotient rule, exactly, and is tested against finite differences.

Floors (scalar outputs, i.e. potentials): the trajectories end at the minimum of ``f``, so
the fields there see data on one side only, and their linear extrapolations would carry
the descent of ``f`` past it. So each local model levels off below the lowest output
``y_min,j`` of its own data: ``l_j(x) = beta_j0 + phi_j(B_j (x - c_j))`` with
``phi_j(u) = u`` above ``a_j = y_min,j - beta_j0`` and ``a_j - w_j (1 - exp((u - a_j) /
w_j))`` below, ``w_j`` being ``FLOOR_SOFTNESS`` times the spread of ``B_j x`` over the
field's data (:func:`floored`, :func:`extrapolation_floors`). Ascending extrapolation stays
linear, so far from the data ``-grad f`` still points back to them.

Fit
---
Centres: a farthest-point cover of (a subsample of) the data with spacing ``h`` (LWPR's
rule of adding a field where none is active), capped at ``max_centers``. Each local model
is weighted ridge least squares on the points within ``R``: with weighted mean ``mu_j`` and
covariance ``Sigma_j``, ``(Sigma_j + ridge h_j^2 I) B_j^T = Cov_j(x, y)``. ``ridge`` is
dimensionless and acts on the slopes only; directions in which the local data do not vary
(the data lie on trajectory manifolds) get zero slope, as in LWPR's projection regression;
its default is ``1e-3 (n / 2)^2``. Neighbours come from a k-d tree in few dimensions and
from blocks of BLAS distances in many; the final fit uses at most ``MAX_FIT_POINTS``
samples, thinned along the trajectories, so its cost stops growing beyond that size.

Per-field widths (``widths``): field ``j`` may get ``h_j = h clip((rho_j / median rho) **
a, lo, hi)``, with ``rho_j`` the distance from its centre to its ``k``-th nearest sample
(:func:`adaptive_widths`; fields only narrow, where the data are dense).

Choice of the width
-------------------
``h`` is chosen by K-fold cross-validation over whole held-out trajectories, as errors
along one trajectory are correlated. The default criterion scores the *increments* of the
prediction between consecutive held-out samples, since the potential of a trajectory is
known only up to an offset. The chosen width is the CV optimum divided by
``GRADIENT_NARROWING``, as the gradient wants narrower fields than the values. With
``widths="cv"`` (default), per-field widths are kept when their CV error at the
CV-optimal width is lower than that of the global width.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from policy_align_ros.learning.base import NotFittedError
from policy_align_ros.learning.regressors._common import (
    assign_folds,
    check_query,
    single_blas_thread,
)
from policy_align_ros.learning.regressors.registry import register

#: Below this many query points a prediction is too small for BLAS threads to matter,
#: and the executor's 1 kHz control step cannot afford even a cheap thread-limit switch.
SMALL_QUERY = 64

__all__ = ["LocalLinearRegression", "NotFittedError"]

#: Cut-off radius of a receptive field in units of its width ``h``.
CUTOFF = 3.0
#: Past the lowest output of its data, a floored local model levels off over this
#: fraction of the spread of its values on its data (see :func:`extrapolation_floors`).
FLOOR_SOFTNESS = 0.02
#: Growth of the blending width with the distance from the nearest centre, far away.
FAR_WIDENING = 0.5
#: Spacing of the cover of centres in units of ``h``.
SPACING = 1.0
#: Largest number of points used to place centres (a random subsample beyond).
MAX_COVER_POINTS = 20000
#: Largest number of points used for cross-validation (whole trajectories, thinned).
MAX_CV_POINTS = 20000
#: Largest number of points whose statistics make the final local models (thinned).
MAX_FIT_POINTS = 100_000
#: Fewest samples kept per trajectory when thinning.
MIN_SAMPLES_PER_GROUP = 25
#: Relative grid of candidate widths, times the RMS spread of the data.
GRID_FACTORS = np.geomspace(0.02, 2.0, 11)
#: Candidate slope penalties when ``ridge="cv"``.
RIDGE_GRID = (1e-3, 1e-2, 1e-1)
#: The chosen width is the CV-optimal one divided by this (gradients want narrower).
GRADIENT_NARROWING = 1.7
#: A local model enters a CV prediction only with this much training weight (points).
MIN_FIELD_WEIGHT = 0.5
#: Rows of data processed at once, to bound memory.
CHUNK = 20000
#: Up to this input dimension neighbours are found with a k-d tree, beyond with BLAS.
KDTREE_MAX_DIM = 4
#: Entries of one block of dense point-centre distances.
DENSE_BLOCK = 250_000
#: A dense block of weights is made sparse below this fraction of non-zeros.
DENSE_FRACTION = 0.1
#: Per-field widths (``widths="adaptive"``): exponent of the local spacing ratio,
#: neighbour rank defining the spacing, and the clip of the ratio (see :func:`adaptive_widths`).
ADAPT_EXPONENT = 0.5
ADAPT_NEIGHBOURS = 30
ADAPT_CLIP = (0.5, 1.0)
#: 2 added the optional arrays ``floors`` and ``softness`` (version 1: linear models);
#: 3 the optional per-field ``widths`` (without them a state has the global width).
_STATE_VERSION = 3
#: Constructor parameters of earlier versions, ignored when a saved state has them, so that
#: older model files still load: ``increment_weight`` (removed derivative equations, which
#: were off by default; a state with a positive weight loads with its fitted models as is).
_REMOVED_PARAMS = ("increment_weight",)


def _blas_context(n_queries: int) -> contextlib.AbstractContextManager:
    return contextlib.nullcontext() if n_queries < SMALL_QUERY else single_blas_thread()


# --------------------------------------------------------------------------- kernel


def kernel(s: np.ndarray, h2: float | np.ndarray, derivative: bool = True):
    """Receptive-field weight ``g(s; h^2)`` and its derivatives.

    Parameters
    ----------
    s : ndarray
        Squared distances (state units^2), ``s >= 0``.
    h2 : float or ndarray broadcastable to ``s``
        Squared width ``h^2`` (state units^2).
    derivative : bool
        Also return the derivatives.

    Returns
    -------
    g : ndarray, shape of ``s``
        Dimensionless, 0 for ``s >= CUTOFF^2 h^2``.
    dg_ds, dg_dh2 : ndarray, shape of ``s``
        In 1/state units^2; only when ``derivative``.
    """
    r2 = (CUTOFF * CUTOFF) * h2
    u = np.minimum(s / r2, 1.0)
    one_minus = 1.0 - u * u
    gauss = np.exp(-0.5 * s / h2)
    g = gauss * (one_minus * one_minus)
    if not derivative:
        return g
    dg_ds = -0.5 * g / h2 - 4.0 * gauss * u * one_minus / r2
    dg_dh2 = 0.5 * g * s / (h2 * h2) + 4.0 * gauss * u * u * one_minus / h2
    return g, dg_ds, dg_dh2


def blend_width2(t: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Squared blending width ``H^2(t)`` at squared distance ``t`` from the nearest centre.

    ``H^2 = h^2 + a^2 t^2 / (t + R^2)`` with ``a = FAR_WIDENING`` and ``R = CUTOFF h``:
    ``h^2`` near the data, growing like ``(a d_min)^2`` far from it. Without this, far
    away the blend would switch between diverging linear extrapolations over a width of
    ``h^2 / ||c_j - c_k||``, and its gradient would grow without bound with the distance.

    Parameters
    ----------
    t : ndarray
        Squared distances to the nearest centre (state units^2).
    h : float
        Field width (state units).

    Returns
    -------
    H2, dH2_dt : ndarray, shape of ``t``
    """
    r2 = (CUTOFF * h) ** 2
    a2 = FAR_WIDENING * FAR_WIDENING
    q = t + r2
    return h * h + a2 * t * t / q, a2 * t * (t + 2.0 * r2) / (q * q)


# --------------------------------------------------------------------------- centres


class FarthestPointCover:
    """Centres in farthest-point order, giving a cover of the data for every radius.

    Each new centre is the (subsampled) data point farthest from the centres so far, so
    the first ``k`` centres lie at least ``radii[k - 1]`` apart and cover every point
    within ``radii[k]``, the distance of the next one: LWPR's rule of adding a receptive
    field where no field is active, for all widths at once. The order is extended lazily,
    as finer covers are asked for.

    Parameters
    ----------
    X : ndarray, shape (m, n)
        Data (state units).
    max_centers : int
        Cap on the number of centres.
    rng : numpy.random.Generator
        Picks the subsample (``MAX_COVER_POINTS``) and the first centre.
    """

    def __init__(self, X: np.ndarray, max_centers: int, rng: np.random.Generator) -> None:
        self.points = X[rng.permutation(X.shape[0])[:MAX_COVER_POINTS]]
        self.max_centers = min(max_centers, len(self.points))
        self.sq = np.einsum("ij,ij->i", self.points, self.points)
        self.order = [0]
        self.radii = [math.inf]
        self.dist = self._sqdist(0)

    def _sqdist(self, i: int) -> np.ndarray:
        d = self.sq + self.sq[i] - 2.0 * (self.points @ self.points[i])
        return np.maximum(d, 0.0, out=d)

    @property
    def capped(self) -> bool:
        """Whether the cap on centres has been reached."""
        return len(self.order) >= self.max_centers

    def centres(self, radius: float) -> np.ndarray:
        """Fewest leading centres covering the data within ``radius`` (or the cap).

        Returns
        -------
        ndarray, shape (C, n)
        """
        limit = radius * radius
        while not self.capped:
            i = int(np.argmax(self.dist))
            if self.dist[i] <= limit:
                break
            self.order.append(i)
            self.radii.append(math.sqrt(self.dist[i]))
            np.minimum(self.dist, self._sqdist(i), out=self.dist)
        count = max(1, int(np.sum(np.asarray(self.radii) > radius)))
        return self.points[self.order[:count]]

    @property
    def radius(self) -> float:
        """Cover radius of all centres placed so far (state units)."""
        return float(np.sqrt(self.dist.max()))


# --------------------------------------------------------------------------- neighbours


class CentreIndex:
    """Kernel weights between points and fixed centres, block by block.

    Below ``KDTREE_MAX_DIM`` dimensions neighbours come from a k-d tree and blocks are
    sparse. Above, k-d trees lose their edge, and blocks of squared distances
    ``|x|^2 + |c|^2 - 2 x.c`` come from one matrix product; a block stays dense when more
    than ``DENSE_FRACTION`` of its weights are non-zero, else it is made sparse.

    Parameters
    ----------
    centres : ndarray, shape (C, n)
        Centres (state units).
    """

    def __init__(self, centres: np.ndarray) -> None:
        self.centres = centres
        self.tree = cKDTree(centres) if centres.shape[1] <= KDTREE_MAX_DIM else None
        self.sq = np.einsum("ij,ij->i", centres, centres)

    def _starts(self, m: int) -> tuple[range, int]:
        step = CHUNK if self.tree is not None else DENSE_BLOCK // len(self.centres)
        step = max(1, min(step, CHUNK))
        return range(0, m, step), step

    def _sqdist(self, X: np.ndarray) -> np.ndarray:
        d2 = np.einsum("ij,ij->i", X, X)[:, None] + self.sq[None, :]
        d2 -= 2.0 * (X @ self.centres.T)
        return np.maximum(d2, 0.0, out=d2)

    def _exact(self, X: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        diff = X[rows] - self.centres[cols]
        return np.einsum("ij,ij->i", diff, diff)

    def weight_blocks(self, X: np.ndarray, h: float):
        """Kernel weights ``g(||x_i - c_j||^2)`` for consecutive blocks of points.

        Parameters
        ----------
        X : ndarray, shape (m, n)
        h : float or ndarray, shape (C,)
            Field width, common or per field (state units).

        Yields
        ------
        start, stop : int
            The block is ``X[start:stop]``.
        W : ndarray or scipy.sparse.csr_matrix, shape (stop - start, C)
        """
        C = len(self.centres)
        hs = np.asarray(h, dtype=float)
        per_field = hs.ndim > 0
        radius = CUTOFF * float(hs.max())
        starts, step = self._starts(X.shape[0])
        for start in starts:
            Xb = X[start : start + step]
            b = len(Xb)
            if self.tree is not None:
                res = cKDTree(Xb).sparse_distance_matrix(
                    self.tree, radius, output_type="ndarray"
                )
                rows, cols = res["i"].astype(np.intp), res["j"].astype(np.intp)
            else:
                d2 = self._sqdist(Xb)
                mask = d2 < radius * radius
                if mask.mean() > DENSE_FRACTION:
                    yield start, start + b, kernel(d2, hs * hs, derivative=False)
                    continue
                rows, cols = np.nonzero(mask)
            h2 = hs[cols] ** 2 if per_field else hs * hs
            w = kernel(self._exact(Xb, rows, cols), h2, derivative=False)
            yield start, start + b, sp.csr_matrix((w, (rows, cols)), shape=(b, C))

    def relative_blocks(self, X: np.ndarray, h: float | np.ndarray, derivative: bool = True):
        """Blending weights of every point on the centres, by blocks.

        ``v_j = g(rel_j; H_j^2)`` with ``rel_j = ||x - c_j||^2 - t``, ``t = d_min(x)^2``, and
        the width ``H_j^2 = blend_width2(t, h_j)``, which equals ``h_j^2`` near the data and
        grows with the distance far from it. Every point keeps at least its nearest centre
        (``v = 1``), however far it is.

        Parameters
        ----------
        X : ndarray, shape (m, n)
        h : float or ndarray, shape (C,)
            Field width, common or per field (state units). Per field, ``d H_j^2 / d t``
            differs between fields, so it is folded into the returned ``dv/dH^2`` and
            ``dwidth`` is 1.
        derivative : bool
            Also compute the derivatives (else they are None).

        Yields
        ------
        start, stop : int
            The block is ``X[start:stop]``.
        nearest : ndarray of intp, shape (b,)
            Index of each point's nearest centre.
        dwidth : ndarray, shape (b,), or None
            ``d H^2 / d t`` per point.
        weights : tuple
            Dense ``(v, dv/drel, dv/dH^2)``, each (b, C); or sparse
            ``(rows, cols, v, dv/drel, dv/dH^2)``, each (nnz,).
        """
        hs = np.asarray(h, dtype=float)
        per_field = hs.ndim > 0
        hmax = float(hs.max())
        a2 = FAR_WIDENING * FAR_WIDENING
        starts, step = self._starts(X.shape[0])
        for start in starts:
            Xb = X[start : start + step]
            b = len(Xb)
            if self.tree is None:
                d2 = self._sqdist(Xb)
                nearest = np.argmin(d2, axis=1)
                t = d2[np.arange(b), nearest]
            else:
                dmin, nearest = self.tree.query(Xb, k=1)
                nearest = np.asarray(nearest, dtype=np.intp)
                t = dmin * dmin
            # Support of every field: rel < CUTOFF^2 H_j^2. Per field, H^2 is not monotonic
            # in h, but H_j^2 <= h_j^2 + a^2 t bounds it.
            reach = hmax * hmax + a2 * t if per_field else blend_width2(t, hmax)[0]
            reach *= CUTOFF * CUTOFF
            if self.tree is None:
                rel = d2 - t[:, None]
                mask = rel < reach[:, None]
                if mask.mean() > DENSE_FRACTION:
                    rel = np.maximum(rel, 0.0, out=rel)
                    yield start, start + b, nearest, *self._weights(rel, t, hs, derivative)
                    continue
                rows, cols = np.nonzero(mask)
            else:
                lists = self.tree.query_ball_point(Xb, np.sqrt(t + reach), return_sorted=False)
                lens = np.fromiter(map(len, lists), dtype=np.intp, count=len(lists))
                chain = itertools.chain.from_iterable(lists)
                rows = np.repeat(np.arange(b), lens)
                cols = np.fromiter(chain, dtype=np.intp, count=int(lens.sum()))
            # Exact pairwise distances: the weights are then exactly smooth functions of x.
            t = self._exact(Xb, np.arange(b), nearest)
            rel = np.maximum(self._exact(Xb, rows, cols) - t[rows], 0.0)
            rel[cols == nearest[rows]] = 0.0
            dwidth, weights = self._weights(rel, t, hs, derivative, rows, cols)
            yield start, start + b, nearest, dwidth, (rows, cols, *weights)

    @staticmethod
    def _weights(rel, t, hs, derivative, rows=None, cols=None):
        """``dwidth`` and the weights ``(v, dv/drel, dv/dH^2)`` of a block.

        ``rel`` is dense, (b, C), without ``rows`` and ``cols``, else per pair (nnz,).
        """
        if hs.ndim == 0:
            # A common width is the per-field case with all h_j equal, but H^2 is then one
            # per point: computing it per pair and folding dH^2/dt into every weight would
            # slow the common case down for nothing.
            w2, dw2 = blend_width2(t, float(hs))
            w2 = w2[:, None] if rows is None else w2[rows]
        elif rows is None:
            w2, dw2 = blend_width2(t[:, None], hs[None, :])
        else:
            w2, dw2 = blend_width2(t[rows], hs[cols])
        if not derivative:
            return None, (kernel(rel, w2, derivative=False), None, None)
        v, dvs, dvh = kernel(rel, w2)
        if hs.ndim == 0:
            return dw2, (v, dvs, dvh)
        # dH_j^2/dt differs between fields: folded in here, the blend's common factor is 1.
        return np.ones(len(t)), (v, dvs, dvh * dw2)


# --------------------------------------------------------------------------- local fits


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
    smoothing: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted ridge least-squares local linear models from their statistics.

    With ``smoothing > 0`` the slopes are shrunk toward a prior slope instead of toward
    zero: the common slope of the neighbouring fields (kernel of width ``smoothing * h``),
    each centred on its own mean, so directions without local data are learnt from the
    neighbours' data.

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
    smoothing : float
        Width of the neighbour average in units of ``h``; 0 shrinks toward zero.

    Returns
    -------
    intercepts : ndarray, shape (C, d)
        ``beta_j0 = l_j(c_j)``.
    slopes : ndarray, shape (C, d, n)
        ``B_j``, output units per state unit.
    """
    C, n = centres.shape
    d = n_outputs
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
    # A tiny floor keeps the systems solvable with ridge=0 on degenerate data.
    lam = np.reshape(max(ridge, 1e-10) * np.square(h), (-1, 1, 1))
    eye = np.eye(n)
    if smoothing > 0 and C > 1:
        # Prior slopes: one common slope fitted to the neighbouring fields' data, each
        # field around its own mean, so a direction one field has not seen is learnt from
        # neighbours that have, without the bias of one wide field on curved data.
        A = neighbour_matrix(centres, smoothing * float(np.median(h))) @ sp.diags(W)
        norm = np.asarray(A.sum(axis=1)).ravel()
        pcov = (A @ cov.reshape(C, n * n)).reshape(C, n, n) / norm[:, None, None]
        pcxy = (A @ cxy.reshape(C, n * d)).reshape(C, n, d) / norm[:, None, None]
        prior = np.linalg.solve(pcov + lam * eye, pcxy)
        slopes = np.linalg.solve(cov + lam * eye, cxy + lam * prior)
    else:
        slopes = np.linalg.solve(cov + lam * eye, cxy)
    slopes = slopes.transpose(0, 2, 1)
    intercepts = ybar + np.einsum("cdn,cn->cd", slopes, centres - mu)
    return intercepts, slopes


def neighbour_matrix(centres: np.ndarray, width: float) -> sp.csr_matrix:
    """Kernel weights ``g(||c_j - c_k||^2)`` of width ``width`` between centres, (C, C)."""
    blocks = [sp.csr_matrix(W) for _, _, W in CentreIndex(centres).weight_blocks(centres, width)]
    return sp.vstack(blocks).tocsr()


# --------------------------------------------------------------------------- prediction


def floored(
    u: np.ndarray, floor: np.ndarray, softness: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Linear above a floor, smoothly levelling off below it, and its derivative.

    ``phi(u) = u`` for ``u >= a``, ``a - w (1 - exp((u - a) / w))`` below: continuous with
    its derivative at ``a``, decreasing by at most ``w`` past it, with a slope that decays
    over ``w``. ``a = -inf`` leaves ``u`` linear.

    Parameters
    ----------
    u : ndarray
        Local model increments ``B_j (x - c_j)`` (output units).
    floor, softness : ndarray, broadcastable to ``u``
        ``a`` and ``w > 0`` (output units).

    Returns
    -------
    phi, dphi_du : ndarray, shape of ``u``
    """
    z = np.minimum((u - floor) / softness, 0.0)
    e = np.exp(z)
    below = z < 0.0
    return np.where(below, floor + softness * (e - 1.0), u), e


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
    C, n = centres.shape
    iu, ju = np.triu_indices(n)
    W = stats[:, 0]
    mu = stats[:, 1 : 1 + n] / W[:, None]
    k = 1 + n + slopes.shape[1]
    sxx = np.zeros((C, n, n))
    sxx[:, iu, ju] = stats[:, k : k + len(iu)]
    sxx[:, ju, iu] = stats[:, k : k + len(iu)]
    cov = sxx / W[:, None, None] - mu[:, :, None] * mu[:, None, :]
    spread = np.sqrt(np.maximum(np.einsum("cdn,cnm,cdm->cd", slopes, cov, slopes), 0.0))
    softness = np.maximum(FLOOR_SOFTNESS * spread, np.finfo(float).tiny)
    return minima - intercepts, softness


def blend(
    X: np.ndarray,
    index: CentreIndex,
    intercepts: np.ndarray,
    slopes: np.ndarray,
    h: float,
    gradient: bool = False,
    floors: np.ndarray | None = None,
    softness: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Normalised blend of the local models and its exact gradient.

    Parameters
    ----------
    X : ndarray, shape (m, n)
        Query states (state units, same origin as the centres).
    index : CentreIndex
        The field centres, shape (C, n).
    intercepts : ndarray, shape (C, d)
        Local model values at their centres.
    slopes : ndarray, shape (C, d, n)
        Local model slopes.
    h : float or ndarray, shape (C,)
        Field width, common or per field (state units).
    gradient : bool
        Also return ``d f / d x``.
    floors, softness : ndarray, shape (C, d), optional
        Floors of the local models (:func:`floored`); None keeps them linear.

    Returns
    -------
    f : ndarray, shape (m, d)
        Prediction.
    grad : ndarray, shape (m, d, n), or None
        Exact gradient of ``f`` (output units per state unit) when requested.
    """
    m, n = X.shape
    C, d = intercepts.shape
    centres = index.centres
    # l_j(x) = a_j + B_j x, with the centre folded into the offset.
    offsets = intercepts - np.einsum("cdn,cn->cd", slopes, centres)
    f = np.empty((m, d))
    grad = np.empty((m, d, n)) if gradient else None
    # With v_j = g(rel_j; H^2(t)), rel_j = ||x - c_j||^2 - t and t = ||x - c_*||^2:
    #   d rel_j/dx = 2 (c_* - c_j),   d H^2/dx = H^2'(t) 2 (x - c_*),
    #   grad f = [sum_j v_j B_j + sum_j (l_j - f) grad v_j] / sum_j v_j;
    # a floored model l_j = b_j + phi_j(u_j), u_j = B_j (x - c_j), replaces B_j by
    # phi_j'(u_j) B_j.
    for start, stop, nearest, dw2, weights in index.relative_blocks(X, h, gradient):
        Xb = X[start:stop]
        b = stop - start
        cn = centres[nearest]
        if len(weights) == 3:
            v, dvs, dvh = weights
            V = v.sum(axis=1)
            for k in range(d):
                L = offsets[None, :, k] + Xb @ slopes[:, k, :].T
                vd = v
                if floors is not None:
                    b0 = intercepts[None, :, k]
                    p, dp = floored(L - b0, floors[None, :, k], softness[None, :, k])
                    L = b0 + p
                    vd = v * dp
                fk = np.einsum("ij,ij->i", v, L) / V
                f[start:stop, k] = fk
                if gradient:
                    L -= fk[:, None]
                    Es = dvs * L
                    eh = np.einsum("ij,ij->i", dvh, L)
                    g = vd @ slopes[:, k, :] + 2.0 * (Es.sum(axis=1)[:, None] * cn - Es @ centres)
                    g += (2.0 * eh * dw2)[:, None] * (Xb - cn)
                    grad[start:stop, k] = g / V[:, None]
            continue
        rows, cols, v, dvs, dvh = weights
        V = np.bincount(rows, v, minlength=b)
        Vmat = sp.csr_matrix((v, (rows, cols)), shape=(b, C)) if gradient else None
        for k in range(d):
            L = offsets[cols, k] + np.einsum("ij,ij->i", slopes[cols, k], Xb[rows])
            if floors is not None:
                b0 = intercepts[cols, k]
                p, dp = floored(L - b0, floors[cols, k], softness[cols, k])
                L = b0 + p
                if gradient:
                    Vmat = sp.csr_matrix((v * dp, (rows, cols)), shape=(b, C))
            fk = np.bincount(rows, v * L, minlength=b) / V
            f[start:stop, k] = fk
            if gradient:
                L -= fk[rows]
                es = dvs * L
                Es = sp.csr_matrix((es, (rows, cols)), shape=(b, C))
                esum = np.bincount(rows, es, minlength=b)
                eh = np.bincount(rows, dvh * L, minlength=b)
                g = Vmat @ slopes[:, k, :] + 2.0 * (esum[:, None] * cn - Es @ centres)
                g += (2.0 * eh * dw2)[:, None] * (Xb - cn)
                grad[start:stop, k] = g / V[:, None]
    return f, grad


# --------------------------------------------------------------------------- fit pieces


def fit_fields(
    X: np.ndarray,
    Y: np.ndarray,
    h: float,
    ridge: float,
    max_centers: int,
    rng: np.random.Generator,
    smoothing: float = 0.0,
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
    h, ridge, max_centers, rng, smoothing
        Width, slope penalty, cap on fields, random source, slope smoothing.
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
    intercepts, slopes = solve_local_models(stats, centres, Y.shape[1], hw, ridge, smoothing)
    if not floors:
        return centres, intercepts, slopes, None, None, widths
    return (
        centres, intercepts, slopes,
        *extrapolation_floors(stats, centres, intercepts, slopes, minima), widths,
    )


def neighbour_distance(centres: np.ndarray, X: np.ndarray, k: int) -> np.ndarray:
    """Distance from every centre to its ``k``-th nearest sample of ``X``.

    Parameters
    ----------
    centres : ndarray, shape (C, n)
    X : ndarray, shape (m, n)
    k : int
        Rank, clipped to ``m`` (a centre that is a sample counts itself as the first).

    Returns
    -------
    ndarray, shape (C,)
        State units.
    """
    k = max(1, min(k, len(X)))
    if X.shape[1] <= KDTREE_MAX_DIM:
        dist, _ = cKDTree(X).query(centres, k=[k])
        return dist[:, 0]
    sq = np.einsum("ij,ij->i", X, X)
    out = np.empty(len(centres))
    step = max(1, DENSE_BLOCK // len(X))
    for a in range(0, len(centres), step):
        c = centres[a : a + step]
        d2 = np.einsum("ij,ij->i", c, c)[:, None] + sq[None, :] - 2.0 * (c @ X.T)
        out[a : a + step] = np.partition(d2, k - 1, axis=1)[:, k - 1]
    return np.sqrt(np.maximum(out, 0.0))


def adaptive_widths(centres: np.ndarray, X: np.ndarray, h: float) -> np.ndarray:
    """Per-field widths ``h_j = h clip((rho_j / median(rho)) ** a, lo, hi)``.

    ``rho_j`` is the distance from centre ``j`` to its ``ADAPT_NEIGHBOURS``-th nearest
    sample (of at most ``MAX_COVER_POINTS``, taken at a regular stride), a measure of the
    local spacing of the data; ``a = ADAPT_EXPONENT`` and ``(lo, hi) = ADAPT_CLIP``. Fields
    where the data are denser than typical get narrower, as LWPR's adapted metrics do.

    Parameters
    ----------
    centres : ndarray, shape (C, n)
    X : ndarray, shape (m, n)
        Same origin as ``centres``.
    h : float
        Global width (state units).

    Returns
    -------
    ndarray, shape (C,)
        Widths (state units), positive.
    """
    stride = max(1, math.ceil(len(X) / MAX_COVER_POINTS))
    rho = neighbour_distance(centres, X[::stride], ADAPT_NEIGHBOURS)
    scale = float(np.median(rho))
    if not scale > 0.0:
        return np.full(len(centres), float(h))
    lo, hi = ADAPT_CLIP
    ratio = np.maximum(rho / scale, np.finfo(float).tiny)
    return float(h) * np.clip(ratio**ADAPT_EXPONENT, lo, hi)


def default_ridge(n: int) -> float:
    """Default slope penalty for ``n`` input dimensions: ``1e-3 (n / 2)^2``."""
    return 1e-3 * (n / 2.0) ** 2


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


def thin_trajectories(
    groups: np.ndarray, max_points: int, rng: np.random.Generator
) -> np.ndarray:
    """Indices of at most about ``max_points`` samples: trajectories thinned, then dropped.

    Every trajectory keeps every ``s``-th sample (``s`` the same for all, but keeping at
    least ``MIN_SAMPLES_PER_GROUP`` of each); consecutive samples are close to each other,
    so this keeps the spacing between trajectories, which sets the width. Whole
    trajectories are dropped at random only when thinning is not enough.

    Parameters
    ----------
    groups : ndarray of int, shape (m,)
        Trajectory id of every sample, samples of one trajectory in time order.
    max_points : int
        Target number of samples.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray of intp
        Sorted sample indices (all of them when ``m <= max_points``).
    """
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


def cv_errors(
    X: np.ndarray,
    Y: np.ndarray,
    folds: np.ndarray,
    centres: np.ndarray,
    h: float,
    ridges: Sequence[float],
    smoothing: float = 0.0,
    groups: np.ndarray | None = None,
    adaptive: bool = False,
) -> np.ndarray:
    """Held-out error of each fold for one width and several slope penalties.

    The centres are placed on all CV inputs (no outputs are used to place them); each
    fold's local models are solved from the statistics of the other folds, and fields with
    less than ``MIN_FIELD_WEIGHT`` of training weight are left out of its prediction. The
    models of all penalties are blended together, as extra outputs, since the blending
    weights do not depend on the penalty.

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
    ridges : sequence of float, length R
        Slope penalties.
    smoothing : float
        Slope smoothing.
    groups : ndarray of int, shape (m,), optional
        Trajectory ids, samples in time order: when given, the error is that of the
        increments between consecutive held-out samples of one trajectory (the
        "increments" criterion), else the plain mean squared error.
    adaptive : bool
        Per-field widths :func:`adaptive_widths` around ``h`` (from the CV inputs).

    Returns
    -------
    ndarray, shape (R, K)
        Error per penalty and held-out fold (summed over outputs).
    """
    n_folds = int(folds.max()) + 1
    d = Y.shape[1]
    hw = adaptive_widths(centres, X, h) if adaptive else h
    fold_stats = local_statistics(X, Y, CentreIndex(centres), hw, folds, n_folds)
    errors = np.empty((len(ridges), n_folds))
    for k in range(n_folds):
        train = fold_stats[np.arange(n_folds) != k].sum(axis=0)
        valid = train[:, 0] >= MIN_FIELD_WEIGHT
        held = folds == k
        g = None if groups is None else groups[held]
        if not np.any(valid):
            errors[:, k] = _held_out_error(-Y[held], g)
            continue
        hv = hw[valid] if adaptive else h
        models = [
            solve_local_models(train[valid], centres[valid], d, hv, r, smoothing) for r in ridges
        ]
        b0 = np.concatenate([m[0] for m in models], axis=1)
        B = np.concatenate([m[1] for m in models], axis=1)
        pred, _ = blend(X[held], CentreIndex(centres[valid]), b0, B, hv)
        for i in range(len(ridges)):
            errors[i, k] = _held_out_error(pred[:, i * d : (i + 1) * d] - Y[held], g)
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
    at a wider width than errors of its *gradient* (the policy): on trajectory data in
    2-D, 6-D and 22-D the gradient error was least 1.4 to 2 times narrower, and a
    one-standard-error rule toward wider widths made it worse (``docs/notes/local_linear.md``).

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


# --------------------------------------------------------------------------- estimator


@register
class LocalLinearRegression:
    """Receptive fields with local linear models (LWPR prediction), batch fit, exact gradient.

    Parameters
    ----------
    bandwidth : "cv" or float
        Width ``h`` of the Gaussian receptive fields (state units), or ``"cv"`` to choose it
        by cross-validation over whole held-out trajectories.
    bandwidth_grid : sequence of float, optional
        Candidate widths for CV (state units); ``None`` is the RMS spread of the data times
        ``geomspace(0.02, 2, 11)``, evaluated from wide to narrow until clearly worse.
    n_folds : int
        CV folds of whole groups (of contiguous blocks of samples without groups).
    ridge : None, "cv" or float
        Dimensionless penalty on the local slopes (relative to ``h^2``); it sets slopes to
        zero in directions without local data. ``None`` is ``1e-3 (n / 2)^2`` (measured,
        see ``docs/notes/local_linear.md``); ``"cv"`` chooses it from ``RIDGE_GRID`` with
        the width.
    max_centers : int
        Cap on the number of receptive fields.
    smoothing : float
        0 shrinks slopes toward zero; ``s > 0`` toward the common slope of the neighbouring
        fields within ``s h`` (not better on average in the measurements, so off).
    cv_criterion : "increments" or "mse"
        Held-out score: squared errors of the increments along each held-out trajectory
        (for a potential, known up to an offset per trajectory), or of the values.
    extrapolation : "auto", "floor" or "linear"
        "floor" levels every local model off below the lowest output of its own data
        (:func:`extrapolation_floors`), so that descending ``f`` stops where the data
        end; "linear" keeps LWPR's linear models; "auto" floors a scalar output (a
        potential) and keeps multi-output models linear.
    widths : "cv", "global" or "adaptive"
        "global": every field has the width ``h``; "adaptive": field ``j`` has
        ``h_j = h clip((rho_j / median rho) ** ADAPT_EXPONENT, *ADAPT_CLIP)`` with the
        local data spacing ``rho_j`` at its centre (:func:`adaptive_widths`), ``h`` still
        chosen by CV with a common width; "cv" (default) takes "adaptive" when it has
        the lower CV error at the CV-optimal width (one more CV evaluation), else
        "global" (see ``docs/notes/local_linear.md``). Needs ``bandwidth="cv"`` or
        ``ridge="cv"``; with a fixed width and penalty, "cv" means "global".
    random_state : int, numpy.random.Generator or None
        Seeds the subsamples, the folds and the first centre of the cover.

    Attributes
    ----------
    bandwidth_ : float
        Width used (state units).
    ridge_ : float
        Slope penalty used.
    cv_scores_ : dict of float to float, or None
        Mean held-out error (outputs scaled to unit variance) per evaluated width, at the
        chosen penalty; None without cross-validation.
    centers_ : ndarray, shape (C, n)
        Field centres (state units).
    intercepts_ : ndarray, shape (C, d)
        Local model values at the centres.
    slopes_ : ndarray, shape (C, d, n)
        Local model slopes (output units per state unit).
    floors_, softness_ : ndarray, shape (C, d), or None
        Floors of the local models in ``B_j (x - c_j)`` and the scale over which they
        level off (output units); None for linear models.
    widths_ : ndarray, shape (C,), or None
        Per-field widths (state units) with ``widths="adaptive"``, else None.
    n_features_in_ : int
        ``n``.

    Notes
    -----
    Samples of one trajectory must be consecutive and in time order for the
    ``"increments"`` criterion and for thinning large data (``MAX_CV_POINTS``,
    ``MAX_FIT_POINTS``).
    """

    def __init__(
        self,
        *,
        bandwidth: str | float = "cv",
        bandwidth_grid: Sequence[float] | None = None,
        n_folds: int = 5,
        ridge: str | float | None = None,
        max_centers: int = 3000,
        smoothing: float = 0.0,
        cv_criterion: str = "increments",
        extrapolation: str = "auto",
        widths: str = "cv",
        random_state: int | np.random.Generator | None = None,
    ) -> None:
        self.bandwidth = bandwidth
        self.bandwidth_grid = bandwidth_grid
        self.n_folds = n_folds
        self.ridge = ridge
        self.max_centers = max_centers
        self.smoothing = smoothing
        self.cv_criterion = cv_criterion
        self.extrapolation = extrapolation
        self.widths = widths
        self.random_state = random_state

    # -- scikit-learn style parameters

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Constructor parameters, as given."""
        return {
            "bandwidth": self.bandwidth,
            "bandwidth_grid": self.bandwidth_grid,
            "n_folds": self.n_folds,
            "ridge": self.ridge,
            "max_centers": self.max_centers,
            "smoothing": self.smoothing,
            "cv_criterion": self.cv_criterion,
            "extrapolation": self.extrapolation,
            "widths": self.widths,
            "random_state": self.random_state,
        }

    def set_params(self, **params: Any) -> LocalLinearRegression:
        """Set constructor parameters; returns self."""
        valid = self.get_params()
        for key, value in params.items():
            if key not in valid:
                raise ValueError(f"unknown parameter {key!r} for LocalLinearRegression")
            setattr(self, key, value)
        return self

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"LocalLinearRegression({args})"

    # -- fit

    def _check_params(self) -> None:
        bw = self.bandwidth
        if isinstance(bw, str):
            if bw != "cv":
                raise ValueError(f"bandwidth must be 'cv' or a positive float, got {bw!r}")
        elif not (isinstance(bw, (int, float, np.floating)) and math.isfinite(bw) and bw > 0):
            raise ValueError(f"bandwidth must be 'cv' or a positive float, got {bw!r}")
        if self.bandwidth_grid is not None:
            grid = np.asarray(self.bandwidth_grid, dtype=float)
            if grid.ndim != 1 or grid.size == 0 or not np.all(np.isfinite(grid) & (grid > 0)):
                raise ValueError(
                    "bandwidth_grid must be a non-empty 1-D sequence of positive floats, "
                    f"got {self.bandwidth_grid!r}"
                )
        if isinstance(self.n_folds, bool) or not isinstance(self.n_folds, (int, np.integer)):
            raise ValueError(f"n_folds must be an integer >= 2, got {self.n_folds!r}")
        if self.n_folds < 2:
            raise ValueError(f"n_folds must be an integer >= 2, got {self.n_folds!r}")
        rg = self.ridge
        if rg is None:
            pass
        elif isinstance(rg, str):
            if rg != "cv":
                raise ValueError(f"ridge must be None, 'cv' or a float >= 0, got {rg!r}")
        elif not (isinstance(rg, (int, float, np.floating)) and math.isfinite(rg) and rg >= 0):
            raise ValueError(f"ridge must be None, 'cv' or a float >= 0, got {rg!r}")
        sm = self.smoothing
        if not (isinstance(sm, (int, float, np.floating)) and math.isfinite(sm) and sm >= 0):
            raise ValueError(f"smoothing must be a float >= 0, got {sm!r}")
        if self.cv_criterion not in ("increments", "mse"):
            raise ValueError(
                f"cv_criterion must be 'increments' or 'mse', got {self.cv_criterion!r}"
            )
        if self.extrapolation not in ("auto", "floor", "linear"):
            raise ValueError(
                "extrapolation must be 'auto', 'floor' or 'linear', "
                f"got {self.extrapolation!r}"
            )
        if self.widths not in ("global", "adaptive", "cv"):
            raise ValueError(
                f"widths must be 'global', 'adaptive' or 'cv', got {self.widths!r}"
            )
        mc = self.max_centers
        if isinstance(mc, bool) or not isinstance(mc, (int, np.integer)) or mc < 1:
            raise ValueError(f"max_centers must be an integer >= 1, got {mc!r}")

    def fit(
        self,
        X: np.ndarray,
        y: np.ndarray,
        groups: np.ndarray | None = None,
    ) -> LocalLinearRegression:
        """Fit the receptive fields and local models.

        Parameters
        ----------
        X : array_like, shape (m, n)
            Inputs (state units).
        y : array_like, shape (m,) or (m, d)
            Outputs.
        groups : array_like of int, shape (m,), optional
            Trajectory id of every sample; CV holds out whole groups. ``None`` uses
            contiguous blocks of samples.

        Returns
        -------
        self
        """
        self._check_params()
        X = np.asarray(X, dtype=float)
        y = np.asarray(y, dtype=float)
        if X.ndim != 2 or X.shape[0] < 2 or X.shape[1] < 1:
            raise ValueError(f"X must have shape (m, n) with m >= 2, got {X.shape}")
        if y.ndim not in (1, 2) or y.shape[0] != X.shape[0]:
            raise ValueError(
                f"y must have shape ({X.shape[0]},) or ({X.shape[0]}, d), got {y.shape}"
            )
        if y.ndim == 2 and y.shape[1] < 1:
            raise ValueError("y has zero columns")
        if not np.all(np.isfinite(X)):
            bad = int(np.argwhere(~np.isfinite(X))[0, 0])
            raise ValueError(f"X contains NaN or inf (first at row {bad})")
        if not np.all(np.isfinite(y)):
            bad = int(np.argwhere(~np.isfinite(y.reshape(len(y), -1)))[0, 0])
            raise ValueError(f"y contains NaN or inf (first at row {bad})")
        m = X.shape[0]
        if groups is None:
            g = None
        else:
            g = np.asarray(groups)
            if g.shape != (m,):
                raise ValueError(f"groups must have shape ({m},), got {g.shape}")
            if not np.issubdtype(g.dtype, np.integer):
                raise ValueError(f"groups must be integer trajectory ids, got dtype {g.dtype}")
        with single_blas_thread():
            self._fit(X, y.reshape(m, -1), g)
        self.y_ndim_ = y.ndim
        return self

    def _fit(self, X: np.ndarray, Y: np.ndarray, g: np.ndarray | None) -> None:
        m = X.shape[0]
        rng = np.random.default_rng(self.random_state)
        origin = X.mean(axis=0)
        Xs = X - origin

        if self.bandwidth == "cv" or self.ridge == "cv":
            if self.bandwidth != "cv":
                grid = np.array([float(self.bandwidth)])
            elif self.bandwidth_grid is None:
                grid = auto_grid(Xs)
            else:
                grid = np.sort(np.asarray(self.bandwidth_grid, dtype=float))
            h, ridge, scores = self._cross_validate(Xs, Y, g, grid, rng)
        else:
            h, ridge, scores = float(self.bandwidth), self._ridge(X.shape[1]), None
            self.adaptive_ = self.widths == "adaptive"
        # Consecutive samples of a trajectory are nearly duplicates at the scale of h:
        # beyond MAX_FIT_POINTS, thinning them changes the local statistics little.
        keep = thin_trajectories(np.zeros(m, dtype=int) if g is None else g, MAX_FIT_POINTS, rng)
        # A scalar output is taken for a potential, which is descended: floors stop the
        # descent where the data end (module docstring).
        floored_models = self.extrapolation == "floor" or (
            self.extrapolation == "auto" and Y.shape[1] == 1
        )
        centres, intercepts, slopes, floors, softness, widths = fit_fields(
            Xs[keep], Y[keep], h, ridge, int(self.max_centers), rng, float(self.smoothing),
            floored_models, self.adaptive_,
        )
        self.widths_ = widths
        self.bandwidth_ = h
        self.ridge_ = ridge
        self.cv_scores_ = scores
        self.origin_ = origin
        self.centers_ = centres + origin
        self.intercepts_ = intercepts
        self.slopes_ = slopes
        self.floors_ = floors
        self.softness_ = softness
        self.n_features_in_ = X.shape[1]
        self.n_outputs_ = Y.shape[1]
        self._index()

    def _width(self) -> float | np.ndarray:
        return self.bandwidth_ if self.widths_ is None else self.widths_

    def _index(self) -> None:
        # Shifted centres and their tree, rebuilt identically by fit and from_state.
        self._index_ = CentreIndex(self.centers_ - self.origin_)

    def _ridge(self, n: int) -> float:
        # Measured on trajectory data (docs/notes/local_linear.md): the best penalty grows with
        # the dimension, about 1e-3 in 2-D and 6-D and 0.1 in 22-D.
        return default_ridge(n) if self.ridge is None else float(self.ridge)

    def _cross_validate(self, X, Y, groups, grid, rng):
        m = X.shape[0]
        if groups is None or len(np.unique(groups)) < 2:
            # Contiguous blocks stand in for trajectories: neighbours in time stay together.
            blocks = min(max(self.n_folds, 10 * self.n_folds), m)
            groups = (np.arange(m) * blocks) // m
        idx = thin_trajectories(groups, MAX_CV_POINTS, rng)
        Xc, Yc, gc = X[idx], Y[idx], groups[idx]
        n_folds = min(self.n_folds, len(np.unique(gc)))
        folds = assign_folds(gc, n_folds, rng)
        by_fold = np.argsort(folds, kind="stable")
        Xc, Yc, gc, folds = Xc[by_fold], Yc[by_fold], gc[by_fold], folds[by_fold]
        scale = Yc.std(axis=0)
        Yc = (Yc - Yc.mean(axis=0)) / np.where(scale > 0, scale, 1.0)
        ridges = RIDGE_GRID if self.ridge == "cv" else (self._ridge(X.shape[1]),)
        # One farthest-point order serves every width: its prefixes are the covers.
        cover = FarthestPointCover(Xc, int(self.max_centers), rng)
        # From wide to narrow: narrow widths cost most (many fields), and once two in a row
        # are clearly worse than the best so far, narrower ones are not worth evaluating.
        errors = []
        for h in grid[::-1]:
            centres = cover.centres(SPACING * h)
            if cover.capped and cover.radius > 2.0 * SPACING * h and len(errors) >= 3:
                # The cap leaves holes between fields this narrow: stop here.
                break
            errors.append(
                cv_errors(
                    Xc, Yc, folds, centres, float(h), ridges, self.smoothing,
                    gc if self.cv_criterion == "increments" else None,
                )
            )
            if len(errors) >= 3 and _clearly_worse([e.min(axis=0) for e in errors]):
                break
        grid = grid[::-1][: len(errors)][::-1]
        errors = np.array(errors[::-1])  # (G, R, K)
        means = errors.mean(axis=2)
        best_ridge = int(np.unravel_index(np.argmin(means), means.shape)[1])
        curve = errors[:, best_ridge, :]
        scores = {float(h): float(e) for h, e in zip(grid, curve.mean(axis=1), strict=True)}
        h = select_bandwidth(grid, curve) if self.bandwidth == "cv" else float(grid[0])
        adaptive = self.widths == "adaptive"
        if self.widths == "cv":
            # Per-field widths if they beat the common one at the CV-optimal width.
            best = int(np.argmin(curve.mean(axis=1)))
            adapted = cv_errors(
                Xc, Yc, folds, cover.centres(SPACING * grid[best]), float(grid[best]),
                (ridges[best_ridge],), self.smoothing,
                gc if self.cv_criterion == "increments" else None, adaptive=True,
            )
            adaptive = bool(adapted.mean() < curve[best].mean())
        self.adaptive_ = adaptive
        return h, ridges[best_ridge], scores

    # -- prediction

    def _check_fitted(self) -> None:
        if not hasattr(self, "centers_"):
            raise NotFittedError(
                "this LocalLinearRegression is not fitted yet: call fit() or from_state()"
            )

    def _check_X(self, X: np.ndarray) -> np.ndarray:
        self._check_fitted()
        return check_query(X, self.n_features_in_) - self.origin_

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Prediction ``f(x)``.

        Parameters
        ----------
        X : array_like, shape (m, n)

        Returns
        -------
        ndarray, shape (m,) or (m, d)
            As the ``y`` given to ``fit``.
        """
        Xs = self._check_X(X)
        with _blas_context(len(Xs)):
            f, _ = blend(
                Xs, self._index_, self.intercepts_, self.slopes_, self._width(),
                floors=self.floors_, softness=self.softness_,
            )
        return f[:, 0] if self.y_ndim_ == 1 else f

    def gradient(self, X: np.ndarray) -> np.ndarray:
        """Exact gradient ``d f / d x``.

        Parameters
        ----------
        X : array_like, shape (m, n)

        Returns
        -------
        ndarray, shape (m, n) for 1-D ``y``, (m, d, n) otherwise
            Output units per state unit.
        """
        Xs = self._check_X(X)
        with _blas_context(len(Xs)):
            _, g = blend(
                Xs, self._index_, self.intercepts_, self.slopes_, self._width(),
                gradient=True, floors=self.floors_, softness=self.softness_,
            )
        return g[:, 0, :] if self.y_ndim_ == 1 else g

    # -- state

    def get_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Numeric arrays and a JSON-serialisable header that rebuild this model exactly.

        Returns
        -------
        arrays : dict of str to ndarray
            ``centers`` (C, n), ``intercepts`` (C, d), ``slopes`` (C, d, n), ``origin`` (n,);
            ``floors`` and ``softness`` (C, d) when the local models are floored.
        meta : dict
            Format version, hyperparameters, width and CV scores.
        """
        self._check_fitted()
        params = self.get_params()
        if isinstance(params["random_state"], np.random.Generator):
            params["random_state"] = None
        if params["bandwidth_grid"] is not None:
            params["bandwidth_grid"] = [float(v) for v in params["bandwidth_grid"]]
        meta = {
            "version": _STATE_VERSION,
            "params": params,
            "bandwidth": float(self.bandwidth_),
            "ridge": float(self.ridge_),
            "cv_scores": None
            if self.cv_scores_ is None
            else [[h, e] for h, e in self.cv_scores_.items()],
            "n_features_in": int(self.n_features_in_),
            "n_outputs": int(self.n_outputs_),
            "y_ndim": int(self.y_ndim_),
        }
        arrays = {
            "centers": self.centers_.copy(),
            "intercepts": self.intercepts_.copy(),
            "slopes": self.slopes_.copy(),
            "origin": self.origin_.copy(),
        }
        if self.floors_ is not None:
            arrays["floors"] = self.floors_.copy()
            arrays["softness"] = self.softness_.copy()
        if self.widths_ is not None:
            arrays["widths"] = self.widths_.copy()
        return arrays, meta

    @classmethod
    def from_state(
        cls, arrays: dict[str, np.ndarray], meta: dict[str, Any]
    ) -> LocalLinearRegression:
        """Rebuild a fitted model from :meth:`get_state` output.

        Raises
        ------
        ValueError
            On a missing or inconsistent array or header field, or a newer format version.
        """
        try:
            version = int(meta["version"])
            n = int(meta["n_features_in"])
            d = int(meta["n_outputs"])
            y_ndim = int(meta["y_ndim"])
            h = float(meta["bandwidth"])
            ridge = float(meta["ridge"])
            params = dict(meta["params"])
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"regressor state: bad or missing header field ({err})") from None
        if version > _STATE_VERSION:
            raise ValueError(
                f"regressor state: format version {version} is newer than supported "
                f"({_STATE_VERSION})"
            )
        missing = [k for k in ("centers", "intercepts", "slopes", "origin") if k not in arrays]
        if missing:
            raise ValueError(f"regressor state: missing arrays {missing}")
        centres = np.asarray(arrays["centers"], dtype=float)
        intercepts = np.asarray(arrays["intercepts"], dtype=float)
        slopes = np.asarray(arrays["slopes"], dtype=float)
        origin = np.asarray(arrays["origin"], dtype=float)
        C = centres.shape[0] if centres.ndim == 2 else -1
        expected = {
            "centers": (centres.shape, (C, n)),
            "intercepts": (intercepts.shape, (C, d)),
            "slopes": (slopes.shape, (C, d, n)),
            "origin": (origin.shape, (n,)),
        }
        floors = softness = None
        if ("floors" in arrays) != ("softness" in arrays):
            raise ValueError("regressor state: floors and softness must come together")
        if "floors" in arrays:
            floors = np.asarray(arrays["floors"], dtype=float)
            softness = np.asarray(arrays["softness"], dtype=float)
            expected["floors"] = (floors.shape, (C, d))
            expected["softness"] = (softness.shape, (C, d))
        widths = None
        if "widths" in arrays:
            widths = np.asarray(arrays["widths"], dtype=float)
            expected["widths"] = (widths.shape, (C,))
        for name, (got, want) in expected.items():
            if C < 1 or got != want:
                raise ValueError(f"regressor state: {name} has shape {got}, expected {want}")
        if widths is not None and not np.all(np.isfinite(widths) & (widths > 0)):
            raise ValueError("regressor state: widths must be positive")
        if softness is not None and not np.all(softness > 0):
            raise ValueError("regressor state: softness must be positive")
        if y_ndim not in (1, 2) or (y_ndim == 1 and d != 1) or not (h > 0):
            raise ValueError("regressor state: inconsistent y_ndim, n_outputs or bandwidth")
        for name in _REMOVED_PARAMS:
            params.pop(name, None)
        model = cls(**params)
        model.bandwidth_ = h
        model.ridge_ = ridge
        scores = meta.get("cv_scores")
        model.cv_scores_ = None if scores is None else {float(a): float(b) for a, b in scores}
        model.origin_ = origin
        model.centers_ = centres
        model.intercepts_ = intercepts
        model.slopes_ = slopes
        model.floors_ = floors
        model.softness_ = softness
        model.widths_ = widths
        model.n_features_in_ = n
        model.n_outputs_ = d
        model.y_ndim_ = y_ndim
        model._index()
        return model
