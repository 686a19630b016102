"""A global quadratic trend plus a kernel residual, chosen by CV over whole demonstrations.

Notation
--------
States ``x`` (n,) in state units are standardised as ``z = (x - mu) / s`` with the data's
mean ``mu`` and one scalar scale ``s`` (the RMS spread over all coordinates, so that the
geometry of the state space is kept); outputs (the aligned potential) as
``u = (y - y_mean) / y_std``. The model is::

    u(z) = c + b.z + p ||z||^2 / 2 + z' S z + sum_j alpha_j exp(-||z - c_j||^2 / (2 l^2))

- the *trend* ``c + b.z + p ||z||^2 / 2 + z' S z`` is a quadratic (``S`` symmetric,
  ``n (n + 1) / 2`` free entries) whose anisotropic part ``S`` is penalised with
  ``trend_ridge ||S||_F^2``: the trend shrinks toward an isotropic bowl rather than toward
  a flat plane, so directions the demonstrations barely explore keep a sensible
  curvature and the policy points back to the data far from them;
- the *residual* is a Gaussian kernel expansion on ``m`` centres ``c_j`` (a subset of the
  data) with the RKHS penalty ``kernel_ridge alpha' K_cc alpha`` (subset of regressors),
  which captures what a quadratic cannot (several minima, a task-space potential seen
  in joint space).

Both parts are fitted jointly by penalised least squares on the mean squared error;
``grad_x f`` is analytic (:meth:`TrendKernelRegression.gradient`).

Offsets
-------
The outputs are potentials estimated along each demonstration and shifted by the offsets
the alignment found; the offsets are its least certain part, in many dimensions most of
all (trajectories pass far from each other). So the fit may correct them: it minimises
``sum_i (u_i - f(z_i) - b_k(i))^2 / m + offset_ridge sum_k b_k^2`` over ``f`` and per
demonstration corrections ``b_k`` together (``offset_ridge = 0``: free offsets, the
demonstrations then tie together through the shape of ``f`` alone; ``inf``: the
alignment's offsets). The ``b_k`` are eliminated in closed form, so this costs no more
than the fit without them. Demonstrations named in ``fit(..., free_groups=...)`` always
have free offsets, whatever ``offset_ridge``: the alignment could not level them (weakly
connected trajectories), so only their shape is data (``docs/notes/outliers.md``). On a
22-D quadratic (``policy-align bench suite --cases quad_aniso_22 --seed 1000``), free
offsets brought the trend's nUPE on new starts from 0.24 to 0.03; see
``docs/notes/trend_kernel.md``.

Choosing the hyperparameters
----------------------------
``trend_ridge``, ``length_scale``, ``kernel_ridge`` and ``offset_ridge`` (an infinite
``kernel_ridge`` drops the residual, an infinite ``trend_ridge`` keeps the isotropic bowl
only) are chosen by 10-fold cross-validation in which every fold holds out *whole
demonstrations*. A held-out demonstration is scored by its *shape*: the squared error of
the model's values along it after the best constant shift, over the spread of its values.
That is the error of every potential difference between its samples (start to end as
well as step to step), which is what a policy must get right along a path from a new
start, and it does not charge the model for the alignment's error in the held-out
demonstration's offset. The trend's penalty and the offsets' are scored first with the
trend alone; the residual's length scale and penalty are searched at the best of those
and at the best trend penalty with free offsets (the trend alone can rank the offset
penalties wrongly where a quadratic does not fit). The better of the two paths is kept,
and on it the candidate with the fewest effective degrees of freedom
(:func:`effective_dof`) among those scored within one standard error of its best (the
trend alone among them). When a residual is kept, the trend's and the offsets' penalties
are scored again with it. Scores closer than :data:`CV_RESOLUTION` are ties, settled
toward the simpler model; a trend alone that fits to that resolution skips the residual's
search. All fold errors come from per-fold sums (one pass over the data per length
scale), so the search costs a few small Cholesky solves per candidate;
``docs/notes/trend_kernel.md`` has the measurements. The data are thinned evenly in arc
length along each demonstration first (a robot at rest adds samples but no information),
to at most ``max_fit_points`` samples.

By default (``trend_form="cv"``) the CV also scores the single-index trend of
:mod:`.single_index` (a rising profile of one fitted quadratic form, for potentials that
flatten or steepen away from the goal), with its index re-fitted without each fold, and
keeps it if it scores lower.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import numpy as np
import scipy.linalg
import scipy.linalg.blas
import scipy.optimize
import scipy.sparse

from policy_align_ros.learning.fitting import (
    NotFittedError,
    assign_folds,
    check_query,
    check_Xy,
    single_blas_thread,
)
from policy_align_ros.learning.model_io import to_json
from policy_align_ros.learning.regressors import single_index
from policy_align_ros.learning.thinning import thin_trajectories

__all__ = ["TrendKernelRegression", "effective_dof", "quadratic_features"]

#: Candidate trend penalties (on standardised data); ``inf`` is the isotropic bowl.
TREND_RIDGE_GRID = (1e-6, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, math.inf)
#: Candidate kernel penalties; ``inf`` drops the kernel residual. The smallest lets a long
#: length scale act as a smooth global correction of the trend (near the flat limit,
#: Gaussian features span low-order polynomials only with large weights).
KERNEL_RIDGE_GRID = (1e-8, 1e-6, 1e-4, 1e-2, math.inf)
#: Candidate offset penalties (standardised units): 0 re-fits every demonstration's offset
#: freely, ``inf`` keeps the alignment's.
OFFSET_RIDGE_GRID = (0.0, 1e-4, 1e-2, math.inf)
#: Candidate length scales, as factors of the median distance between centres: from local
#: features (two minima) to about the data's diameter, where the residual bends the whole
#: trend (a potential that grows faster or slower than a quadratic; the arm case).
LENGTH_FACTORS = (0.16, 0.32, 0.64, 1.28, 2.56)
#: Smallest eigenvalue of the trend's Hessian, relative to its largest (keeps a minimum).
CURVATURE_FLOOR = 0.01
#: CV scores (shape error over the spread) closer than this are not told apart: the
#: potential is then known to 1e-5 of its spread either way, and differences come from
#: round-off (an exact quadratic scored 1e-21 with the trend alone, 1e-18 with a residual).
CV_RESOLUTION = 1e-10
#: Effective degrees of freedom closer than this are the same complexity (see
#: ``TrendKernelRegression._fewest_dof_within``).
DOF_RESOLUTION = 0.5
#: Added to the penalty of every coefficient: keeps the solves well posed.
JITTER = 1e-9
#: Rows per block when evaluating kernels (bounds memory on large queries).
CHUNK = 8192
#: Trend forms the CV chooses from: the quadratic, and the single-index trend of
#: :mod:`.single_index` (a profile of one quadratic form; no residual on top).
TREND_FORMS = ("quadratic", "single_index")
#: Samples (a random subset of the thinned data) on which the single-index trend's index is
#: fitted, and the residual evaluations allowed, for the final fit and every fold's alike
#: (the folds score the procedure the final fit runs).
INDEX_FIT_POINTS = 2000
INDEX_NFEV = 20
_STATE_VERSION = 3
_HYPER = ("trend_ridge", "length_scale", "kernel_ridge", "offset_ridge")


def quadratic_features(Z: np.ndarray) -> np.ndarray:
    """Trend features ``[1, z, ||z||^2 / 2, z_i z_j (i <= j, off-diagonal * sqrt 2)]``.

    Parameters
    ----------
    Z : ndarray (m, n)
        Standardised states.

    Returns
    -------
    ndarray (m, 2 + n + n (n + 1) / 2)
        The ``sqrt 2`` makes the squared coefficients of the last block equal
        ``||S||_F^2`` for ``z' S z``.
    """
    m, n = Z.shape
    iu, ju = np.triu_indices(n)
    scale = np.where(iu == ju, 1.0, math.sqrt(2.0))
    quad = Z[:, iu] * Z[:, ju] * scale
    return np.hstack([np.ones((m, 1)), Z, 0.5 * np.einsum("ij,ij->i", Z, Z)[:, None], quad])


def _n_trend(n: int) -> int:
    return 2 + n + n * (n + 1) // 2


def _gaussian(Z: np.ndarray, C: np.ndarray, ell: float) -> np.ndarray:
    sq = (np.einsum("ij,ij->i", Z, Z)[:, None] - 2.0 * Z @ C.T
          + np.einsum("ij,ij->i", C, C)[None, :])
    return np.exp(-0.5 * np.maximum(sq, 0.0) / ell**2)


class _FoldGrams:
    """Per-fold and per-demonstration sums of a design, for CV with per-demo offsets.

    ``A`` (m, p) is the design at the samples, ``u`` (m,) the targets, ``demo`` (m,) the
    demonstration of every sample as ``0..K-1`` and ``demo_fold`` (K,) the fold of every
    demonstration. The offsets ``b_k`` are eliminated in closed form: with
    ``c_k = 1 / (n_k + m lambda)``, the objective profiled over ``b`` has the Gram
    ``sum_i a_i a_i' - sum_k c_k A_k A_k'`` (``A_k`` the sum of ``a_i`` over demonstration
    ``k``), so every score below costs one (p, p) solve per fold.
    """

    def __init__(self, A: np.ndarray, u: np.ndarray, demo: np.ndarray, demo_fold: np.ndarray,
                 n: int, base: _FoldGrams | None = None, free: np.ndarray | None = None,
                 nonneg: bool = False):
        """``base``, when given, holds the sums of the first columns of ``A`` (the trend,
        shared by every length scale), so only the blocks of the new columns are summed.
        ``free`` (K,) bool: demonstrations whose offsets are free at every
        ``offset_ridge`` (default: none). The folds' solves: by default the first columns
        of ``A`` are :func:`quadratic_features`, whose Hessian :func:`_convex_solve` keeps
        positive definite; with ``nonneg``, ``A`` is the single-index design ``[1, B]``,
        whose profile weights :func:`_nonneg_solve` keeps >= 0."""
        self.n = n
        self.nonneg = nonneg
        self.free = (np.zeros(len(demo_fold), dtype=bool) if free is None
                     else np.asarray(free, dtype=bool))
        n_demos = len(demo_fold)
        onehot = scipy.sparse.csr_matrix(
            (np.ones(len(u)), (demo, np.arange(len(u)))), shape=(n_demos, len(u)))
        self.sk = onehot @ u                          # (K,)
        self.nk = np.bincount(demo, minlength=n_demos).astype(float)
        self.demo_fold = demo_fold
        n_folds = int(demo_fold.max()) + 1
        fold = demo_fold[demo]
        if np.any(np.diff(fold) < 0):
            raise ValueError("_FoldGrams: samples must be sorted by fold")
        bounds = np.searchsorted(fold, np.arange(n_folds + 1))
        rows = [slice(bounds[f], bounds[f + 1]) for f in range(n_folds)]
        q = 0 if base is None else base.G.shape[1]
        new = A[:, q:]
        Ak = np.asarray(onehot @ new)
        self.Ak = Ak if base is None else np.hstack([base.Ak, Ak])  # (K, p) per-demo sums
        p = A.shape[1]
        self.G = np.empty((n_folds, p, p))
        for f, r in enumerate(rows):
            self.G[f, q:, q:] = _gram(new[r])
            if base is not None:
                self.G[f, :q, :q] = base.G[f]
                self.G[f, :q, q:] = A[r, :q].T @ new[r]
                self.G[f, q:, :q] = self.G[f, :q, q:].T
        # The design itself is kept to score held-out folds from their residuals: at a
        # near-perfect fit the expanded sums (u'u - 2 w'r + w'Gw) cancel to round-off.
        self.A, self.u, self.demo, self.rows = A, u, demo, rows
        self.r = np.stack([A[r].T @ u[r] for r in rows])
        self.uu = np.array([u[r] @ u[r] for r in rows])
        self.G_all, self.r_all = self.G.sum(axis=0), self.r.sum(axis=0)
        self._free: tuple[np.ndarray, ...] | None = None
        # Held-out error is scored against the within-demonstration spread of u.
        self.shape_ss = max(float(self.uu.sum() - np.sum(self.sk**2 / self.nk)), 1e-300)

    def free_offset_sums(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per fold, the Gram and right-hand side terms that free offsets remove
        (``offset_ridge = 0``: ``c_k = 1 / n_k``), and their sums over all folds; they do
        not depend on the other folds, and are summed on first use (the final fit never
        needs them)."""
        if self._free is None:
            per_demo = self.Ak / self.nk[:, None]
            folds = [self.demo_fold == f for f in range(len(self.G))]
            G0 = np.stack([per_demo[k].T @ self.Ak[k] for k in folds])
            r0 = np.stack([per_demo[k].T @ self.sk[k] for k in folds])
            self._free = (G0, r0, G0.sum(axis=0), r0.sum(axis=0))
        return self._free

    def scores(self, penalties: list[np.ndarray], offset_ridge: float, shared: int = 0
               ) -> list[tuple[float, float]]:
        """Held-out shape error per penalty, and its standard error over the folds.

        The shape error sums the squared residuals of the held-out demonstrations about
        their own mean (every held-out demonstration gets its best offset), over their
        spread. ``shared``: the penalties are block diagonal and equal in their first
        ``shared`` rows and columns (negative: in their last ``-shared``; see
        :func:`_solve_shared`).
        """
        n_folds = len(self.G)
        err = np.array([self.fold_errors(f, penalties, offset_ridge, shared)
                        for f in range(n_folds)]).T
        return _fold_summary(err, self.shape_ss)

    def fold_errors(self, f: int, penalties: list[np.ndarray], offset_ridge: float,
                    shared: int = 0, accept=None) -> list[float]:
        """Held-out squared shape residuals of fold ``f`` per penalty, fitted on the other
        folds (``inf`` where the solve fails or ``accept(w)`` is false)."""
        G, r, m = self.without(f, offset_ridge)
        M = G / m
        if self.nonneg:
            solved = [_nonneg_solve(M + penalty, r / m, 1) for penalty in penalties]
        else:
            first = _solve_shared(M, r / m, penalties, shared)
            solved = [_convex_solve(M + penalty, r / m, self.n, w)
                      for penalty, w in zip(penalties, first, strict=True)]
        out = []
        for w in solved:
            ok = w is not None and np.all(np.isfinite(w)) and (accept is None or accept(w))
            out.append(self.shape_error(f, w) if ok else math.inf)
        return out

    def without(self, f: int, offset_ridge: float) -> tuple[np.ndarray, np.ndarray, float]:
        """:meth:`profiled` over every demonstration outside fold ``f``."""
        held = self.demo_fold == f
        if offset_ridge == 0.0:
            G0, r0, G0_all, r0_all = self.free_offset_sums()
            G = self.G_all - self.G[f] - (G0_all - G0[f])
            r = self.r_all - self.r[f] - (r0_all - r0[f])
            return G, r, float(self.nk[~held].sum())
        return self.profiled(~held, self.G_all - self.G[f], self.r_all - self.r[f],
                             offset_ridge)

    def shape_error(self, fold: int, w: np.ndarray) -> float:
        """Squared residuals of fold ``fold``'s demonstrations about their own means."""
        r = self.rows[fold]
        e = self.u[r] - self.A[r] @ w
        demo = self.demo[r]
        mean = np.bincount(demo, weights=e, minlength=len(self.nk)) / np.maximum(self.nk, 1)
        return float(np.sum((e - mean[demo]) ** 2))

    def profiled_all(self, offset_ridge: float) -> tuple[np.ndarray, np.ndarray, float]:
        """:meth:`profiled` over every demonstration: the system of a fit on all data."""
        return self.profiled(np.ones(len(self.nk), bool), self.G_all, self.r_all, offset_ridge)

    def profiled(self, train: np.ndarray, G: np.ndarray, r: np.ndarray, offset_ridge: float
                 ) -> tuple[np.ndarray, np.ndarray, float]:
        """Gram and right-hand side of demonstrations ``train`` (bool, K) whose sums are
        ``G, r``, with their offsets eliminated; and their number of samples."""
        m = float(self.nk[train].sum())
        free = self.free[train]
        if math.isfinite(offset_ridge) or free.any():
            nk = self.nk[train]
            c = (np.zeros_like(nk) if math.isinf(offset_ridge)
                 else 1.0 / (nk + m * offset_ridge))
            c[free] = 1.0 / nk[free]
            Ak = self.Ak[train]
            G = G - (Ak * c[:, None]).T @ Ak
            r = r - Ak.T @ (c * self.sk[train])
        return G, r, m


@dataclasses.dataclass(frozen=True)
class _CVData:
    """The standardised data of one CV search, samples sorted by fold.

    ``F`` (m, p_t) trend features, ``Z`` (m, n) states, ``u`` (m,) targets, ``C`` (m_c, n)
    kernel centres, ``demo`` (m,) and ``demo_fold`` (K,) as in :class:`_FoldGrams`;
    ``trend`` the fold sums of ``F``, shared by every length scale.
    """

    F: np.ndarray
    Z: np.ndarray
    u: np.ndarray
    C: np.ndarray
    demo: np.ndarray
    demo_fold: np.ndarray
    trend: _FoldGrams

    @property
    def n(self) -> int:
        """State dimension."""
        return self.Z.shape[1]

    def kernel_sums(self, ell: float) -> tuple[_FoldGrams, np.ndarray]:
        """Fold sums of the trend and kernel features at length scale ``ell``, and the
        centres' Gram (m_c, m_c)."""
        A = np.hstack([self.F, _gaussian(self.Z, self.C, ell)])
        return (_FoldGrams(A, self.u, self.demo, self.demo_fold, self.n, base=self.trend,
                           free=self.trend.free),
                _gaussian(self.C, self.C, ell))


def _fold_summary(err: np.ndarray, shape_ss: float) -> list[tuple[float, float]]:
    """CV score and its standard error per candidate from the held-out squared shape
    residuals ``err`` (candidates, folds) and the spread ``shape_ss`` of all samples."""
    n_folds = err.shape[1]
    # Per fold scaled so that the mean over folds is the total error over the spread.
    err = err * (n_folds / shape_ss)
    with np.errstate(invalid="ignore"):
        se = np.std(err, axis=1, ddof=1) / math.sqrt(n_folds)
    return [(float(e), float(s)) for e, s in zip(err.mean(axis=1), se, strict=True)]


def _gram(A: np.ndarray) -> np.ndarray:
    """``A' A`` (p, p) through the symmetric rank-k update (half the work of ``A.T @ A``)."""
    if A.shape[0] == 0:
        return np.zeros((A.shape[1], A.shape[1]))
    upper = scipy.linalg.blas.dsyrk(1.0, np.asarray(A, dtype=float), trans=1)
    return upper + np.triu(upper, 1).T  # dsyrk leaves the strict lower triangle at zero


def effective_dof(M: np.ndarray, P: np.ndarray) -> float:
    """Effective degrees of freedom ``tr((M + P)^-1 M)`` of a penalised least-squares fit.

    Parameters
    ----------
    M : ndarray (p, p)
        Normal matrix ``A' A / m`` of the design ``A`` (m, p).
    P : ndarray (p, p)
        Penalty on the coefficients (positive semi-definite).

    Returns
    -------
    float
        The trace of the hat matrix ``A (A' A + m P)^-1 A'``: the number of coefficients
        without a penalty (``M`` of full rank), fewer the more the penalty shrinks them;
        ``inf`` if ``M + P`` is singular.
    """
    try:
        factor = scipy.linalg.cho_factor(M + P, check_finite=False)
    except np.linalg.LinAlgError:
        return math.inf
    return float(np.trace(scipy.linalg.cho_solve(factor, M, check_finite=False)))


def _convex_solve(M: np.ndarray, b: np.ndarray, n: int, w: np.ndarray | None = None
                  ) -> np.ndarray | None:
    """Solve ``M w = b`` for the coefficients, keeping the trend's Hessian positive definite.

    The trend decides the policy far from the data: a saddle sends rollouts away along
    its negative-curvature directions (on the suite's arm case, to hundreds of spacings
    from the data). So when the solved trend's Hessian ``H = p I + 2 S`` has an eigenvalue
    below ``CURVATURE_FLOOR`` times its largest, those eigenvalues are raised to that
    bound, the quadratic part is fixed there, and the other coefficients (constant,
    linear part, kernel weights) are solved again given it. ``w``: the solution of
    ``M w = b`` if already known.
    """
    if w is None:
        w = _solve(M, b)
    if w is None:
        return None
    p_t = _n_trend(n)
    lam, V = np.linalg.eigh(_trend_hessian(w, n))
    floor = CURVATURE_FLOOR * (lam[-1] if lam[-1] > 0 else 1.0)
    if lam[0] >= floor:
        return w
    S = 0.5 * ((V * np.maximum(lam, floor)) @ V.T - w[1 + n] * np.eye(n))
    iu, ju, scale = _upper(n)
    quad = np.arange(1 + n, p_t)
    w[2 + n:p_t] = scale * S[iu, ju]
    rest = np.setdiff1d(np.arange(len(w)), quad)
    w_rest = _solve(M[np.ix_(rest, rest)], b[rest] - M[np.ix_(rest, quad)] @ w[quad])
    if w_rest is None:
        return None
    w[rest] = w_rest
    return w


def _trend_hessian(w: np.ndarray, n: int) -> np.ndarray:
    """Hessian ``p I + 2 S`` (n, n) of the quadratic trend whose coefficients lead ``w``."""
    return w[1 + n] * np.eye(n) + 2.0 * _symmetric(w[2 + n:_n_trend(n)], n)


def _solve_shared(M: np.ndarray, b: np.ndarray, penalties: list[np.ndarray], q: int
                  ) -> list[np.ndarray | None]:
    """Solve ``(M + P) w = b`` for every ``P`` in ``penalties``.

    When the penalties are block diagonal with the same leading ``q x q`` block (the
    trend's, while the kernel's penalty varies; ``q < 0``: the same trailing ``-q x -q``
    block, the kernel's, while the trend's varies), that block is factored once and every
    penalty costs one factorisation of the other block's Schur complement: on the
    22-D trend (277 coefficients) and 300 centres this is about a third of the work of
    factoring each full system.
    """
    p = M.shape[0]
    if q == 0 or abs(q) >= p or len(penalties) < 2:
        return [_solve(M + P, b) for P in penalties]
    # Slices, not a permuted copy: the 22-D stage 3 spent a tenth of its fit copying.
    s, o = (slice(0, q), slice(q, p)) if q > 0 else (slice(p + q, p), slice(0, p + q))
    try:
        L = scipy.linalg.cholesky(M[s, s] + penalties[0][s, s], lower=True,
                                  check_finite=False)
    except np.linalg.LinAlgError:
        return [_solve(M + P, b) for P in penalties]
    W = scipy.linalg.solve_triangular(L, M[s, o], lower=True, check_finite=False)
    z = scipy.linalg.solve_triangular(L, b[s], lower=True, check_finite=False)
    schur = M[o, o] - _gram(W)
    rhs = b[o] - W.T @ z
    out: list[np.ndarray | None] = []
    for P in penalties:
        w_other = _solve(schur + P[o, o], rhs)
        if w_other is None:
            out.append(_solve(M + P, b))
            continue
        w = np.empty(p)
        w[o] = w_other
        w[s] = scipy.linalg.solve_triangular(L, z - W @ w_other, lower=True, trans="T",
                                             check_finite=False)
        out.append(w)
    return out


@functools.lru_cache(maxsize=8)
def _upper(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices of the upper triangle of an (n, n) matrix, and the feature scale of each
    entry (1 on the diagonal, sqrt 2 off it; see :func:`quadratic_features`)."""
    iu, ju = np.triu_indices(n)
    out = (iu, ju, np.where(iu == ju, 1.0, math.sqrt(2.0)))
    for a in out:
        a.flags.writeable = False  # shared between calls
    return out


def _symmetric(coef: np.ndarray, n: int) -> np.ndarray:
    """The symmetric ``S`` whose scaled upper triangle is ``coef`` (see quadratic_features)."""
    iu, ju, scale = _upper(n)
    S = np.zeros((n, n))
    S[iu, ju] = coef / scale
    S[ju, iu] = coef / scale
    return S


def _nonneg_solve(M: np.ndarray, b: np.ndarray, free: int) -> np.ndarray | None:
    """Minimise ``w' M w - 2 b' w`` over ``w`` (p,) with ``w[free:] >= 0`` (the
    single-index profile's weights after its constant); None if ``M`` is not positive
    definite.

    The first ``free`` entries are eliminated in closed form; the rest is the NNLS problem
    ``min ||R w - R^-T c||`` on the Cholesky factor ``R`` of their Schur complement.
    """
    try:
        F = scipy.linalg.cho_factor(M[:free, :free], check_finite=False)
        X = scipy.linalg.cho_solve(F, np.column_stack([M[:free, free:], b[:free]]),
                                   check_finite=False)
        R = scipy.linalg.cholesky(M[free:, free:] - M[free:, :free] @ X[:, :-1],
                                  check_finite=False)
        c = b[free:] - M[free:, :free] @ X[:, -1]
        t = scipy.linalg.solve_triangular(R, c, trans="T", check_finite=False)
        beta = scipy.optimize.nnls(R, t, maxiter=50 * len(t))[0]
    except (np.linalg.LinAlgError, ValueError, RuntimeError):
        return None
    return np.concatenate([X[:, -1] - X[:, :-1] @ beta, beta])


def _solve(M: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    try:
        return scipy.linalg.cho_solve(scipy.linalg.cho_factor(M, check_finite=False), b,
                                      check_finite=False)
    except np.linalg.LinAlgError:
        try:
            return scipy.linalg.solve(M, b, assume_a="sym", check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return None


class TrendKernelRegression:
    """Quadratic trend plus Gaussian-kernel residual with an analytic gradient.

    Parameters
    ----------
    trend_form : "cv", "quadratic" or "single_index"
        The trend: the quadratic (with the residual), or the single-index trend of
        :mod:`.single_index` (a profile of one fitted quadratic form, no residual), or
        ``"cv"`` (default) to choose between them. The single-index trend is only tried
        when the quadratic does not already fit the held-out shapes to
        :data:`CV_RESOLUTION`. On velocity-limited and quartic attractors in 3-22
        dimensions it took the median nUPE from new starts from 0.17 to 0.0003 (16 data
        sets, tuning seeds) and from 0.12 to 0.001 (8 others), and it ties on
        ``bench suite``, at 1.6-2.6 times the fit time of its 22-D quadratics
        (``docs/notes/trend_kernel.md``).
    trend_ridge : "cv" or float
        Penalty on the anisotropic part ``S`` of the quadratic trend (standardised units;
        ``inf``: an isotropic bowl only), or ``"cv"`` to choose from ``TREND_RIDGE_GRID``.
    length_scale : "cv" or float
        Kernel length scale in standardised units, or ``"cv"`` (``LENGTH_FACTORS`` times
        the median distance between centres).
    kernel_ridge : "cv" or float
        RKHS penalty of the residual (``inf``: no residual; a finite value always keeps
        the residual), or ``"cv"`` (``KERNEL_RIDGE_GRID``, ``inf`` included).
    offset_ridge : "cv" or float
        Penalty on corrections of every demonstration's offset (0: free; ``inf``: none),
        or ``"cv"`` (``OFFSET_RIDGE_GRID``).
    n_centres : int
        Kernel centres (a random subset of the thinned data).
    max_fit_points : int
        Samples kept after thinning in arc length along each demonstration.
    n_folds : int
        Cross-validation folds, each of whole demonstrations (``groups``); at most one
        per demonstration. Ten: with five, which demonstrations shared a fold decided
        the arm case's fit (nUPE 0.02 or 0.15 for the same data).
    random_state : int, numpy.random.Generator or None
        Seeds the choice of centres and folds.

    Attributes
    ----------
    trend_form_ : str
        The trend used.
    trend_ridge_, length_scale_, kernel_ridge_, offset_ridge_ : float
        Hyperparameters used (``trend_ridge_`` is NaN for the single-index trend).
    cv_scores_ : dict
        Held-out shape error (over the within-demonstration spread) per evaluated
        ``(trend_form, trend_ridge, length_scale, kernel_ridge, offset_ridge)``;
        ``length_scale`` is NaN for the trend alone, ``trend_ridge`` for the single-index
        trend. The single-index trend's folds stop once it cannot beat the quadratic
        family's pick; its scores are then lower bounds.
    cv_standard_errors_ : dict
        Standard error over the folds of every entry of ``cv_scores_`` (NaN for a lower
        bound).
    cv_dof_ : dict
        Effective degrees of freedom (:func:`effective_dof`) of the candidates the
        residual's choice compared: those within one standard error of the best score.
    cv_best_ : tuple or None
        The key of ``cv_scores_`` chosen (None without cross-validation).
    mean_, scale_ : ndarray (n,), float
        Standardisation of the states (state units).
    y_mean_, y_scale_ : float
        Standardisation of the outputs.
    trend_ : ndarray (2 + n + n (n + 1) / 2,) or (2 + 2 len(KNEES),)
        Trend coefficients (standardised units): of :func:`quadratic_features`, or the
        constant and the profile weights of the single-index trend.
    index_matrix_, index_goal_, index_scale_ : ndarray (n, n), ndarray (n,), float
        The single-index trend's ``L``, ``z0`` and ``s`` (standardised units; ``L`` empty
        (0, n) for the quadratic).
    centres_ : ndarray (m, n)
        Kernel centres, standardised; ``alpha_`` (m,) their weights.
    n_features_in_ : int
    """

    def __init__(
        self,
        *,
        trend_form: str = "cv",
        trend_ridge: str | float = "cv",
        length_scale: str | float = "cv",
        kernel_ridge: str | float = "cv",
        offset_ridge: str | float = "cv",
        n_centres: int = 300,
        max_fit_points: int = 6000,
        n_folds: int = 10,
        random_state: int | np.random.Generator | None = 0,
    ) -> None:
        self.trend_form = trend_form
        self.trend_ridge = trend_ridge
        self.length_scale = length_scale
        self.kernel_ridge = kernel_ridge
        self.offset_ridge = offset_ridge
        self.n_centres = n_centres
        self.max_fit_points = max_fit_points
        self.n_folds = n_folds
        self.random_state = random_state

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Constructor parameters, as given."""
        return {
            "trend_form": self.trend_form,
            "trend_ridge": self.trend_ridge,
            "length_scale": self.length_scale,
            "kernel_ridge": self.kernel_ridge,
            "offset_ridge": self.offset_ridge,
            "n_centres": self.n_centres,
            "max_fit_points": self.max_fit_points,
            "n_folds": self.n_folds,
            "random_state": self.random_state,
        }

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"TrendKernelRegression({args})"

    def _check_params(self) -> None:
        if self.trend_form not in ("cv", *TREND_FORMS):
            raise ValueError(f"trend_form must be 'cv' or one of {TREND_FORMS}, got "
                             f"{self.trend_form!r}")
        for name in ("trend_ridge", "length_scale", "kernel_ridge"):
            value = getattr(self, name)
            if value == "cv":
                continue
            if not isinstance(value, (int, float)) or not value > 0 or math.isnan(value):
                raise ValueError(f"{name} must be 'cv' or a positive float, got {value!r}")
        if self.length_scale != "cv" and math.isinf(self.length_scale):
            raise ValueError("length_scale must be finite")
        o = self.offset_ridge
        if o != "cv" and (not isinstance(o, (int, float)) or not o >= 0):
            raise ValueError(f"offset_ridge must be 'cv' or a float >= 0, got {o!r}")
        for name, low in (("n_centres", 1), ("max_fit_points", 10), ("n_folds", 2)):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"{name} must be an int >= {low}, got {value!r}")

    # -- fit --------------------------------------------------------------------------
    def fit(self, X: np.ndarray, y: np.ndarray, groups: np.ndarray | None = None,
            free_groups: np.ndarray | None = None) -> TrendKernelRegression:
        """Fit on states ``X`` (m, n), outputs ``y`` (m,) and demonstration ids ``groups``.

        Samples of one demonstration must be consecutive and in time order (they are
        thinned in arc length). Without ``groups`` all samples form one demonstration and
        the hyperparameters that are ``"cv"`` fall back to mid-grid values.
        ``free_groups`` (ids in ``groups``) are demonstrations whose offsets are always
        re-fitted freely: ``y`` carries their shape only.

        Returns
        -------
        self
        """
        self._check_params()
        X, y, groups = check_Xy(X, y, groups)
        free = np.zeros(0, dtype=groups.dtype) if free_groups is None else np.asarray(
            free_groups)
        if free.ndim != 1 or (free.size and not np.issubdtype(free.dtype, np.integer)):
            raise ValueError(f"free_groups must be a 1-D int array, got {free.dtype} "
                             f"{free.shape}")
        unknown = np.setdiff1d(free, groups)
        if unknown.size:
            raise ValueError(f"free_groups names ids not in groups: {unknown[:5].tolist()}")
        # Hundreds of factorisations of a few hundred unknowns: OpenBLAS's threads cost
        # more than they bring there (22-D, 6000 samples: 1.9 s with them, 0.75 s without).
        with single_blas_thread():
            return self._fit(X, y, groups, free)

    def _fit(self, X: np.ndarray, y: np.ndarray, groups: np.ndarray, free_groups: np.ndarray
             ) -> TrendKernelRegression:
        rng = np.random.default_rng(self.random_state)
        idx = thin_trajectories(X, groups, self.max_fit_points)
        X, y, groups = X[idx], y[idx], groups[idx]
        m, n = X.shape
        self.n_features_in_ = n
        self.mean_ = X.mean(axis=0)
        self.scale_ = float(np.sqrt(np.mean(np.var(X, axis=0)))) or 1.0
        # Demonstrations with free offsets carry no level: the outputs' scale (the unit of
        # every penalty) comes from the others.
        levelled = ~np.isin(groups, free_groups)
        if not levelled.any():
            levelled[:] = True
        self.y_mean_ = float(y[levelled].mean())
        self.y_scale_ = float(y[levelled].std()) or 1.0
        Z = (X - self.mean_) / self.scale_
        u = (y - self.y_mean_) / self.y_scale_

        centre_idx = np.sort(rng.choice(m, size=min(self.n_centres, m), replace=False))
        C = Z[centre_idx]
        demo_ids, demo = np.unique(groups, return_inverse=True)
        free = np.isin(demo_ids, free_groups)
        n_folds = min(self.n_folds, len(demo_ids))
        demo_fold = np.zeros(len(demo_ids), dtype=np.int64)
        if n_folds >= 2:
            demo_fold[demo] = assign_folds(groups, n_folds, rng)
            # Samples grouped by fold: every fold's sums come from a slice, not a copy.
            order = np.argsort(demo_fold[demo], kind="stable")
            Z, u, demo = Z[order], u[order], demo[order]
        F = quadratic_features(Z)

        d_med = _median_distance(C)
        lengths = _grid(self.length_scale, [f * d_med for f in LENGTH_FACTORS])
        t_grid = _grid(self.trend_ridge, TREND_RIDGE_GRID)
        k_grid = _grid(self.kernel_ridge, KERNEL_RIDGE_GRID)
        o_grid = _grid(self.offset_ridge, OFFSET_RIDGE_GRID)
        forms = list(TREND_FORMS) if self.trend_form == "cv" else [self.trend_form]
        self.cv_scores_: dict[tuple, float] = {}
        self.cv_standard_errors_: dict[tuple, float] = {}
        self.cv_dof_: dict[tuple, float] = {}
        self.cv_best_ = None
        self._index: tuple[np.ndarray, np.ndarray, float] | None = None
        mid = (lengths[len(lengths) // 2], k_grid[len(k_grid) // 2])
        # Without CV, and as the fallback of a single-index trend whose profile fails to rise.
        self._quadratic_pick = ("quadratic", t_grid[len(t_grid) // 2], *mid, o_grid[-1])
        if n_folds < 2:
            best = self._quadratic_pick
            if forms == ["single_index"]:
                best = ("single_index", math.nan, mid[0], math.inf, o_grid[-1])
                self._fit_index(_FoldGrams(F, u, demo, demo_fold, n, free=free), Z, u, demo,
                                t_grid[len(t_grid) // 2], rng)
        else:
            cv = _CVData(F, Z, u, C, demo, demo_fold,
                         _FoldGrams(F, u, demo, demo_fold, n, free=free))
            best = self.cv_best_ = self._cv_search(cv, forms, lengths, t_grid, k_grid, o_grid,
                                                   rng)
            if math.isnan(best[2]):
                best = (*best[:2], mid[0], *best[3:])
        self._final_fit(best, F, Z, u, C, n, demo, free)
        return self

    def _cv_search(self, cv: _CVData, forms: list[str], lengths: list[float],
                   t_grid: list[float], k_grid: list[float], o_grid: list[float],
                   rng: np.random.Generator) -> tuple:
        """Score the candidates of every trend form into ``cv_scores_``; return the pick.

        The single-index trend is fitted and scored when the quadratic's pick does not
        fit the held-out shapes to :data:`CV_RESOLUTION`, and kept if it scores lower."""
        quadratic = None
        if "quadratic" in forms:
            quadratic = self._quadratic_pick = self._quadratic_search(cv, lengths, t_grid,
                                                                      k_grid, o_grid)
            if "single_index" not in forms or self.cv_scores_[quadratic] <= CV_RESOLUTION:
                return quadratic
        # The index starts from the quadratic trend alone with free offsets, at its best
        # trend penalty (the fit that ranks shapes, not levels).
        keys = [("quadratic", t, math.nan, math.inf, 0.0) for t in t_grid]
        if all(key in self.cv_scores_ for key in keys):
            t_init = min(keys, key=self.cv_scores_.get)[1]
        else:
            scores = cv.trend.scores([self._trend_penalty(cv.n, t) for t in t_grid], 0.0)
            t_init = t_grid[int(np.argmin([score for score, _ in scores]))]
        bound = math.inf if quadratic is None else self.cv_scores_[quadratic] - CV_RESOLUTION
        index = self._index_search(cv, t_init, o_grid, rng, bound)
        if quadratic is None and not math.isfinite(self.cv_scores_[index]):
            # No fold's profile rose (two minima, say): the quadratic as the CV picks it,
            # not at mid-grid penalties.
            quadratic = self._quadratic_pick = self._quadratic_search(cv, lengths, t_grid,
                                                                      k_grid, o_grid)
        if quadratic is None or (self.cv_scores_[index]
                                 < self.cv_scores_[quadratic] - CV_RESOLUTION):
            return index
        return quadratic

    def _fit_index(self, grams: _FoldGrams, Z: np.ndarray, u: np.ndarray, demo: np.ndarray,
                   t_init: float, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fit the single-index trend's index on a random subset of the samples, from the
        quadratic trend with free offsets and penalty ``t_init`` (sums in ``grams``);
        store it in ``_index`` and return the subset's indices."""
        n = Z.shape[1]
        L0, z0 = _quadratic_index(grams, n, self._trend_penalty(n, t_init))
        sub = np.sort(rng.choice(len(u), size=min(INDEX_FIT_POINTS, len(u)), replace=False))
        s = _profile_scale(Z[sub], L0, z0)
        L, z = single_index.fit_index(Z[sub], u[sub], demo[sub], L0, z0, s, INDEX_NFEV)
        self._index = (L, z, s)
        return sub

    def _index_search(self, cv: _CVData, t_init: float, o_grid: list[float],
                      rng: np.random.Generator, bound: float = math.inf) -> tuple:
        """Score the single-index trend per offset penalty; return its best key.

        The folds stop once those scored already sum to ``bound`` (the score it has to
        beat) for every offset penalty: the rest can only add error. The scores recorded
        are then those lower bounds, with standard error NaN.

        Its index is fitted on all data (the final fit's), then again without every fold's
        demonstrations, started from the quadratic trend fitted without them: a held-out
        demonstration never shapes the index it is scored with, nor its start or scale.
        (Started from the fit on all data, four demonstrations in 7-D scored an index that
        had seen them, and the CV preferred it to the quadratic wrongly.)"""
        n = cv.n
        sub = self._fit_index(cv.trend, cv.Z, cv.u, cv.demo, t_init, rng)
        start_penalty = self._trend_penalty(n, t_init)
        Zs, us, ds = cv.Z[sub], cv.u[sub], cv.demo[sub]
        n_folds = int(cv.demo_fold.max()) + 1
        penalty = [JITTER * np.eye(_n_index_weights())]
        err = np.zeros((len(o_grid), n_folds))
        stopped = False
        for f in range(n_folds):
            keep = cv.demo_fold[ds] != f
            L0, z0 = _quadratic_index(cv.trend, n, start_penalty, fold=f)
            s = _profile_scale(Zs[keep], L0, z0)
            Lf, zf = single_index.fit_index(Zs[keep], us[keep], ds[keep], L0, z0, s,
                                            INDEX_NFEV)
            A, q_max = _index_design(cv.Z, Lf, zf, s)
            grams = _FoldGrams(A, cv.u, cv.demo, cv.demo_fold, n, free=cv.trend.free,
                               nonneg=True)

            def rises(w: np.ndarray, q_max: float = q_max, s: float = s) -> bool:
                return single_index.increasing(w[1:], s, q_max)

            for i, o in enumerate(o_grid):
                err[i, f] = grams.fold_errors(f, penalty, o, accept=rises)[0]
            stopped = f + 1 < n_folds and err.sum(axis=1).min() / cv.trend.shape_ss >= bound
            if stopped:
                break
        keys = [("single_index", math.nan, math.nan, math.inf, o) for o in o_grid]
        summary = _fold_summary(err, cv.trend.shape_ss)
        if stopped:
            summary = [(score, math.nan) for score, _ in summary]
        self._record(keys, summary)
        return _simplest_within(self.cv_scores_, keys, 0.0, lambda key: -key[4])

    def _quadratic_search(self, cv: _CVData, lengths: list[float], t_grid: list[float],
                          k_grid: list[float], o_grid: list[float]) -> tuple:
        """Score the quadratic trend's candidates in three stages; return its pick."""
        n = cv.n
        # 1. The trend alone scores its penalties and the offsets' ...
        for o in o_grid:
            self._record([("quadratic", t, math.nan, math.inf, o) for t in t_grid],
                         cv.trend.scores([self._trend_penalty(n, t) for t in t_grid], o))
        # 2. ... then the residual its length scale and penalty, jointly with the trend: at
        # the first stage's pick, and with free offsets at their best trend penalty. Where
        # a quadratic does not fit, the trend alone can rank the offset penalties wrongly
        # (a 7-D velocity-limited attractor: CV 0.044 and nUPE 0.21 through the first
        # stage's pick, 0.005 and 0.067 through free offsets).
        scores = self.cv_scores_
        stage_one = _simplest_within(scores, list(scores), 0.0, _simpler_trend)
        paths = {stage_one[4]: stage_one[1]}  # offset penalty -> trend penalty
        if 0.0 in o_grid and 0.0 not in paths:
            paths[0.0] = _simplest_within(scores, [key for key in scores if key[4] == 0.0],
                                          0.0, _simpler_trend)[1]
        finite_k = [k for k in k_grid if math.isfinite(k)]
        if scores[stage_one] <= CV_RESOLUTION and math.inf in k_grid:
            # The trend alone fits the held-out shapes to round-off: a residual can only tie
            # with it, and ties go to the simpler model (bench scale's exact 22-D quadratic
            # spent most of its fit here for nothing).
            finite_k = []
        for ell in lengths if finite_k else ():
            grams, Kcc = cv.kernel_sums(ell)
            for o, t in paths.items():
                self._record([("quadratic", t, ell, k, o) for k in finite_k],
                             grams.scores([self._penalty(n, t, k, Kcc) for k in finite_k], o,
                                          shared=_n_trend(n)))
        # The better path, and on it the model with the fewest effective degrees of freedom
        # within one standard error of its best score (no residual only if the kernel
        # penalty is left to the CV).
        keys = [key for key in scores if paths.get(key[4]) == key[1]
                and (math.inf in k_grid or math.isfinite(key[3]))]
        path = _simplest_within(scores, keys, 0.0, _simpler_trend)
        keys = [key for key in keys if key[4] == path[4]]
        error = self.cv_standard_errors_[min(keys, key=scores.get)]
        best = self._fewest_dof_within(cv, keys, error if math.isfinite(error) else 0.0)
        # 3. With a residual, the trend's and the offsets' penalties again: the trend alone
        # cannot tell them apart where a quadratic does not fit (suite arm case: offset
        # penalties 1e-4 and 1e-2 scored within 6 % with the trend alone, 3x apart with the
        # residual, whose nUPE they took from 0.02 to 0.15).
        if math.isfinite(best[3]) and (len(t_grid) > 1 or len(o_grid) > 1):
            ell, k = best[2], best[3]
            # Summed again rather than kept from stage 2: every length scale's sums held at
            # once doubled the peak memory of a 22-D fit.
            grams, Kcc = cv.kernel_sums(ell)
            for o in o_grid:
                self._record([("quadratic", t, ell, k, o) for t in t_grid],
                             grams.scores([self._penalty(n, t, k, Kcc) for t in t_grid], o,
                                          shared=-len(cv.C)))
            best = _simplest_within(scores, [key for key in scores if key[2:4] == (ell, k)],
                                    0.0, _simpler_trend)
        return best

    def _fewest_dof_within(self, cv: _CVData, keys: list[tuple], margin: float) -> tuple:
        """Of ``keys`` (one trend and offset penalty; residuals, and the trend alone), the
        one with the fewest effective degrees of freedom (:func:`effective_dof`, fitted on
        all samples) among those scored within ``margin``, or :data:`CV_RESOLUTION`, of the
        best; recorded in ``cv_dof_``. Counts within :data:`DOF_RESOLUTION` of the fewest
        are ties, settled toward no residual, then the larger kernel penalty, then the
        longer length scale: a residual of long length scale and large penalty adds
        nothing to a 22-D trend of 130 degrees of freedom, and round-off ranked it below
        the trend alone.

        A length scale and a penalty trade against each other, so neither orders the
        residuals by itself: with 10 demonstrations of the suite's arm, "the larger kernel
        penalty first" took length scale 0.50 and penalty 1e-4 (133 degrees of freedom,
        nUPE 0.21) over 2.0 and 1e-6 (80, nUPE 0.04); ``docs/notes/trend_kernel.md``.
        """
        scores = self.cv_scores_
        within = _within(scores, keys, margin)
        if len(within) == 1:
            return within[0]
        n = cv.n
        # Per length scale (None: the trend alone), the sums of all samples and Kcc.
        designs: dict[float | None, tuple[_FoldGrams, np.ndarray | None]] = {}
        one_fold = np.zeros(len(cv.demo_fold), dtype=np.int64)
        for key in within:
            _, t, ell, k, o = key
            where = None if math.isinf(k) else ell
            if where not in designs:
                A, Kcc = cv.F, None
                if where is not None:
                    A, Kcc = np.hstack([cv.F, _gaussian(cv.Z, cv.C, ell)]), _gaussian(
                        cv.C, cv.C, ell)
                designs[where] = (_FoldGrams(A, cv.u, cv.demo, one_fold, n,
                                             free=cv.trend.free), Kcc)
            grams, Kcc = designs[where]
            P = self._trend_penalty(n, t) if Kcc is None else self._penalty(n, t, k, Kcc)
            G, _, m = grams.profiled_all(o)
            self.cv_dof_[key] = effective_dof(G / m, P)
        fewest = min(self.cv_dof_[key] for key in within)
        simplest = [key for key in within if self.cv_dof_[key] <= fewest + DOF_RESOLUTION]
        return max(simplest, key=lambda key: (_simpler_residual(key), -scores[key]))

    def _record(self, keys: list[tuple],
                scores: list[tuple[float, float]]) -> None:
        """Store the CV score and standard error of every candidate ``keys[i]``."""
        for key, (score, error) in zip(keys, scores, strict=True):
            self.cv_scores_[key], self.cv_standard_errors_[key] = score, error

    @staticmethod
    def _trend_penalty(n: int, trend_ridge: float) -> np.ndarray:
        p = _n_trend(n)
        diag = np.full(p, JITTER)
        diag[2 + n:] = 1e12 if math.isinf(trend_ridge) else trend_ridge + JITTER
        return np.diag(diag)

    def _penalty(self, n: int, trend_ridge: float, kernel_ridge: float, Kcc: np.ndarray
                 ) -> np.ndarray:
        p_t, m = _n_trend(n), len(Kcc)
        P = np.zeros((p_t + m, p_t + m))
        P[:p_t, :p_t] = self._trend_penalty(n, trend_ridge)
        P[p_t:, p_t:] = kernel_ridge * (Kcc + JITTER * np.eye(m)) + JITTER * np.eye(m)
        return P

    def _final_fit(self, best: tuple, F: np.ndarray, Z: np.ndarray, u: np.ndarray,
                   C: np.ndarray, n: int, demo: np.ndarray, free: np.ndarray) -> None:
        """Fit the hyperparameters ``best`` on all samples and set the learnt attributes."""
        (self.trend_form_, self.trend_ridge_, self.length_scale_, self.kernel_ridge_,
         self.offset_ridge_) = best
        self.index_matrix_, self.index_goal_, self.index_scale_ = (
            np.zeros((0, n)), np.zeros(0), 0.0)
        if self.trend_form_ == "single_index":
            if self._fit_single_index(Z, u, n, demo, free):
                return
            # A profile that falls somewhere has no single minimum: the quadratic instead,
            # and the CV's pick is then the candidate fitted (its score is the model's).
            best = self._quadratic_pick
            (self.trend_form_, self.trend_ridge_, self.length_scale_, self.kernel_ridge_,
             self.offset_ridge_) = best
            if self.cv_best_ is not None:
                self.cv_best_ = best
        p_t = _n_trend(n)
        if math.isinf(self.kernel_ridge_):
            A, P = F, self._trend_penalty(n, self.trend_ridge_)
            self.centres_ = np.zeros((0, n))
        else:
            A = np.hstack([F, _gaussian(Z, C, self.length_scale_)])
            P = self._penalty(n, self.trend_ridge_, self.kernel_ridge_,
                              _gaussian(C, C, self.length_scale_))
            self.centres_ = C
        grams = _FoldGrams(A, u, demo, np.zeros(demo.max() + 1, dtype=np.int64), n,
                           free=free)
        G, r, m = grams.profiled_all(self.offset_ridge_)
        w = _convex_solve(G / m + P, r / m, n)
        if w is None or not np.all(np.isfinite(w)):
            raise ValueError("TrendKernelRegression: the penalised least squares failed")
        self.trend_ = w[:p_t]
        self.alpha_ = w[p_t:]
        self._unpack()

    def _fit_single_index(self, Z: np.ndarray, u: np.ndarray, n: int, demo: np.ndarray,
                          free: np.ndarray) -> bool:
        """The single-index trend on ``_index``; False if its profile does not rise."""
        L, z0, s = self._index
        A, q_max = _index_design(Z, L, z0, s)
        grams = _FoldGrams(A, u, demo, np.zeros(demo.max() + 1, dtype=np.int64), n,
                           free=free)
        G, r, m = grams.profiled_all(self.offset_ridge_)
        w = _nonneg_solve(G / m + JITTER * np.eye(len(G)), r / m, 1)
        if w is None or not np.all(np.isfinite(w)) or not single_index.increasing(
                w[1:], s, q_max):
            return False
        self.trend_, self.alpha_, self.centres_ = w, np.zeros(0), np.zeros((0, n))
        self.index_matrix_, self.index_goal_, self.index_scale_ = L, z0, s
        self._unpack()
        return True

    def _unpack(self) -> None:
        n = self.n_features_in_
        t = self.trend_
        if self.trend_form_ == "single_index":
            self._S, self._b, self._p = np.zeros((n, n)), np.zeros(n), 0.0
            self._c = float(t[0])
            return
        self._S = _symmetric(t[2 + n:], n)
        self._c, self._b, self._p = float(t[0]), t[1:1 + n], float(t[1 + n])

    # -- prediction -------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not hasattr(self, "trend_"):
            raise NotFittedError("this TrendKernelRegression is not fitted yet: call fit()")

    def _standardise(self, X: np.ndarray) -> np.ndarray:
        self._check_fitted()
        X = check_query(X, self.n_features_in_)
        return (X - self.mean_) / self.scale_

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Model output ``f(x)``, shape (m,), for states ``X`` (m, n)."""
        Z = self._standardise(X)
        if self.trend_form_ == "single_index":
            u = _index_design(Z, self.index_matrix_, self.index_goal_,
                              self.index_scale_)[0] @ self.trend_
            return self.y_mean_ + self.y_scale_ * u
        u = (self._c + Z @ self._b + 0.5 * self._p * np.einsum("ij,ij->i", Z, Z)
             + np.einsum("ij,jk,ik->i", Z, self._S, Z))
        if len(self.alpha_):
            for s in range(0, len(Z), CHUNK):
                u[s:s + CHUNK] += _gaussian(Z[s:s + CHUNK], self.centres_,
                                            self.length_scale_) @ self.alpha_
        return self.y_mean_ + self.y_scale_ * u

    def gradient(self, X: np.ndarray) -> np.ndarray:
        """Exact ``grad_x f(x)``, shape (m, n), in output units per state unit."""
        Z = self._standardise(X)
        if self.trend_form_ == "single_index":
            g = single_index.profile_gradient(Z, self.index_matrix_, self.index_goal_,
                                              self.index_scale_, self.trend_[1:])
            return g * (self.y_scale_ / self.scale_)
        g = self._b + self._p * Z + 2.0 * Z @ self._S
        if len(self.alpha_):
            ell2 = self.length_scale_**2
            for s in range(0, len(Z), CHUNK):
                Zc = Z[s:s + CHUNK]
                Kw = _gaussian(Zc, self.centres_, self.length_scale_) * self.alpha_
                g[s:s + CHUNK] += (Kw @ self.centres_ - Kw.sum(axis=1)[:, None] * Zc) / ell2
        return g * (self.y_scale_ / self.scale_)

    # -- persistence ------------------------------------------------------------------
    def get_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Numeric arrays and a JSON-able header that rebuild this model exactly.

        The header's ``params`` are the constructor arguments in plain Python types: NumPy
        scalars (``n_centres=np.int64(300)``) as ints and floats, a Generator
        ``random_state`` as ``None`` (``get_params`` keeps the values as given). Anything
        else JSON cannot hold raises a ValueError naming the parameter.
        """
        self._check_fitted()
        params = self.get_params()
        if isinstance(params["random_state"], np.random.Generator):
            params["random_state"] = None
        for name in _HYPER:
            if params[name] != "cv":
                params[name] = _json_float(float(params[name]))
        params = to_json(params, "TrendKernelRegression params")
        meta = {
            "version": _STATE_VERSION,
            "params": params,
            "trend_form": self.trend_form_,
            "index_scale": self.index_scale_,
            "trend_ridge": _json_float(self.trend_ridge_),
            "length_scale": float(self.length_scale_),
            "kernel_ridge": _json_float(self.kernel_ridge_),
            "offset_ridge": _json_float(self.offset_ridge_),
            "scale": self.scale_,
            "y_mean": self.y_mean_,
            "y_scale": self.y_scale_,
            "n_features_in": int(self.n_features_in_),
        }
        arrays = {"mean": self.mean_, "trend": self.trend_, "centres": self.centres_,
                  "alpha": self.alpha_, "index_matrix": self.index_matrix_,
                  "index_goal": self.index_goal_}
        return arrays, meta

    @classmethod
    def from_state(cls, arrays: dict[str, np.ndarray], meta: dict[str, Any]
                   ) -> TrendKernelRegression:
        """Rebuild a fitted model from :meth:`get_state` output (ValueError if malformed)."""
        try:
            if int(meta["version"]) > _STATE_VERSION:
                raise ValueError(f"format version {meta['version']} is newer than supported")
            params = dict(meta["params"])
            for name in _HYPER:
                if params.get(name, "cv") != "cv":
                    params[name] = float(params[name])
            model = cls(**params)
            n = int(meta["n_features_in"])
            model.n_features_in_ = n
            # Version 1 knew the quadratic trend only.
            model.trend_form_ = str(meta.get("trend_form", "quadratic"))
            if model.trend_form_ not in TREND_FORMS:
                raise ValueError(f"unknown trend_form {model.trend_form_!r}")
            single = model.trend_form_ == "single_index"
            model.trend_ridge_ = float(meta["trend_ridge"])
            model.length_scale_ = float(meta["length_scale"])
            model.kernel_ridge_ = float(meta["kernel_ridge"])
            model.offset_ridge_ = float(meta["offset_ridge"])
            model.scale_ = float(meta["scale"])
            model.y_mean_ = float(meta["y_mean"])
            model.y_scale_ = float(meta["y_scale"])
            model.mean_ = np.asarray(arrays["mean"], dtype=float).reshape(n)
            trend = np.asarray(arrays["trend"], dtype=float).ravel()
            if single and int(meta["version"]) < 3:
                # Version 2's profile had no steepening columns: their weights are zero.
                trend = np.concatenate([trend, np.zeros(len(single_index.KNEES))])
            model.trend_ = trend.reshape(_n_index_weights() if single else _n_trend(n))
            model.index_matrix_ = np.asarray(arrays["index_matrix"] if single else
                                             np.zeros((0, n)), dtype=float).reshape(-1, n)
            model.index_goal_ = np.asarray(arrays["index_goal"] if single else np.zeros(0),
                                           dtype=float).reshape(n if single else 0)
            model.index_scale_ = float(meta["index_scale"]) if single else 0.0
            if single and (model.index_matrix_.shape != (n, n) or not model.index_scale_ > 0):
                raise ValueError("single-index trend needs an (n, n) index_matrix and "
                                 "index_scale > 0")
            model.centres_ = np.asarray(arrays["centres"], dtype=float).reshape(-1, n)
            model.alpha_ = np.asarray(arrays["alpha"], dtype=float).reshape(len(model.centres_))
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"regressor state: bad or missing field ({err})") from None
        model.cv_scores_ = {}
        model.cv_standard_errors_ = {}
        model.cv_dof_ = {}
        model.cv_best_ = None
        model._unpack()
        return model


def _simplest_within(scores: dict, keys: list, margin: float, simpler) -> tuple:
    """The simplest of ``keys`` (the largest by ``simpler``) whose CV score is within
    ``margin`` of the best, or within :data:`CV_RESOLUTION` of it (round-off), whichever
    is wider: differences within the folds' noise do not buy a more flexible model."""
    return max(_within(scores, keys, margin), key=lambda k: (simpler(k), -scores[k]))


def _within(scores: dict, keys: list, margin: float) -> list:
    """The ``keys`` whose CV score is within ``margin``, or :data:`CV_RESOLUTION` (whichever
    is wider), of the best among them."""
    bound = min(scores[k] for k in keys) + max(margin, CV_RESOLUTION)
    return [k for k in keys if scores[k] <= bound]


def _simpler_residual(key: tuple) -> tuple:
    """Ordering of residuals of equal complexity, simplest largest: none, then a larger
    kernel penalty, then a longer length scale."""
    _, _, ell, kernel_ridge, _ = key
    return (not math.isfinite(kernel_ridge), kernel_ridge, 0.0 if math.isnan(ell) else ell)


def _simpler_trend(key: tuple) -> tuple:
    """Ordering of trend and offset penalties, simplest largest: the larger trend penalty
    (closer to an isotropic bowl), then the smaller offset penalty (offsets that owe
    nothing to the alignment's errors). Used for ties at an exact fit only."""
    return (key[1], -key[4])


def _grid(value: str | float, grid) -> list[float]:
    return list(grid) if value == "cv" else [float(value)]


def _json_float(value: float) -> float | str:
    return "inf" if math.isinf(value) else "nan" if math.isnan(value) else float(value)


def _quadratic_index(grams: _FoldGrams, n: int, penalty: np.ndarray, fold: int | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Cholesky factor ``L`` (n, n) of the Hessian of the quadratic trend fitted on all of
    ``grams``' samples (those outside ``fold`` if given) with free offsets, and its minimum
    ``z0`` (n,): the single-index trend's start (the identity and the origin if the solve
    fails)."""
    G, r, m = grams.profiled_all(0.0) if fold is None else grams.without(fold, 0.0)
    w = _convex_solve(G / m + penalty, r / m, n)
    if w is None or not np.all(np.isfinite(w)):
        return np.eye(n), np.zeros(n)
    lam, V = np.linalg.eigh(_trend_hessian(w, n))
    lam = np.maximum(lam, CURVATURE_FLOOR * lam[-1]) if lam[-1] > 0 else np.ones(n)
    z0 = -V @ ((V.T @ w[1:1 + n]) / lam)
    return np.linalg.cholesky((V * lam) @ V.T), z0


def _profile_scale(Z: np.ndarray, L: np.ndarray, z0: np.ndarray) -> float:
    """The profile basis' scale ``s``: the median ``sqrt(q)`` of ``Z`` (m, n) under the
    index ``(L, z0)``, or 1."""
    return math.sqrt(float(np.median(single_index.index_form(Z, L, z0)[1]))) or 1.0


def _n_index_weights() -> int:
    """Coefficients of the single-index trend: the constant and the profile's weights."""
    return 2 + 2 * len(single_index.KNEES)


def _index_design(Z: np.ndarray, L: np.ndarray, z0: np.ndarray, s: float
                  ) -> tuple[np.ndarray, float]:
    """The single-index trend's design ``[1, B(q(z))]`` (m, :func:`_n_index_weights`) and
    the largest ``q`` of the samples."""
    _, q = single_index.index_form(Z, L, z0)
    B, _ = single_index.profile_basis(q, s)
    return np.hstack([np.ones((len(Z), 1)), B]), float(q.max(initial=0.0))


def _median_distance(C: np.ndarray) -> float:
    """Median distance between distinct centres (standardised units), > 0."""
    sq = np.einsum("ij,ij->i", C, C)
    d2 = sq[:, None] - 2.0 * C @ C.T + sq[None, :]
    iu = np.triu_indices(len(C), 1)
    d = np.sqrt(np.maximum(d2[iu], 0.0))
    d = d[d > 0]
    return float(np.median(d)) if len(d) else 1.0
