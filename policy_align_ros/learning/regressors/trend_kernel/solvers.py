"""Penalised least-squares solves of the trend-kernel model: the convex (positive-definite
trend) solve, the solves sharing a factored block, the non-negative solve of the
single-index profile, the penalties and the effective degrees of freedom."""

from __future__ import annotations

import math
import warnings

import numpy as np
import scipy.linalg
import scipy.linalg.blas
import scipy.optimize

from policy_align_ros.learning.regressors.trend_kernel.features import (
    _n_trend,
    _trend_hessian,
    _upper,
)
from policy_align_ros.learning.regressors.trend_kernel.lapack import (
    cho_factor,
    cho_solve,
    cholesky,
    solve_triangular,
)

__all__ = ["CURVATURE_FLOOR", "JITTER", "effective_dof"]

#: Smallest eigenvalue of the trend's Hessian, relative to its largest (keeps a minimum).
CURVATURE_FLOOR = 0.01
#: Added to the penalty of every coefficient: keeps the solves well posed.
JITTER = 1e-9


def _gram(A: np.ndarray) -> np.ndarray:
    """``A' A`` (p, p) through the symmetric rank-k update (half the work of ``A.T @ A``)."""
    if A.shape[0] == 0:
        return np.zeros((A.shape[1], A.shape[1]))
    upper = scipy.linalg.blas.dsyrk(1.0, np.asarray(A, dtype=float), trans=1)
    # dsyrk leaves the strict lower triangle at zero, so upper + upper' is the Gram but
    # for its doubled diagonal; set back, not through np.triu (its mask costs as much).
    diagonal = upper.diagonal().copy()
    out = upper + upper.T
    np.fill_diagonal(out, diagonal)
    return out


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
        factor = cho_factor(M + P)
    except np.linalg.LinAlgError:
        return math.inf
    return float(np.trace(cho_solve(factor, M)))


def _convex_solve(M: np.ndarray, b: np.ndarray, n: int, w: np.ndarray | None = None,
                  floor: float = 0.0) -> np.ndarray | None:
    """Solve ``M w = b`` for the coefficients, keeping the trend's Hessian positive definite.

    The trend decides the policy far from the data: a saddle sends rollouts away along
    its negative-curvature directions. So when the solved trend's Hessian
    ``H = p I + 2 S`` has an eigenvalue below ``CURVATURE_FLOOR`` times its largest, those
    eigenvalues are raised to that bound, the quadratic part is fixed there, and the other
    coefficients (constant, linear part, kernel weights) are solved again given it.
    ``w``: the solution of ``M w = b`` if already known. ``floor``: a bound of the
    eigenvalues in the model's standardised units as well, whatever the largest (a goal
    anchor's bowl: ``TrendKernelRegression.fit(min_curvature=...)``).
    """
    if w is None:
        w = _solve(M, b)
    if w is None:
        return None
    if not _floor_trend(w, n, floor):
        return w
    return _convex_resolve(M, b, w, n)


def _convex_resolve(M: np.ndarray, b: np.ndarray, w: np.ndarray, n: int
                    ) -> np.ndarray | None:
    """The coefficients of ``M w = b`` other than the quadratic part of ``w`` (fixed), in
    place; None if the solve fails."""
    p_t = _n_trend(n)
    quad = slice(1 + n, p_t)
    rest = np.concatenate((np.arange(1 + n), np.arange(p_t, len(w))))
    w_rest = _solve(_without_block(M, 1 + n, p_t), b[rest] - M[rest, quad] @ w[quad])
    if w_rest is None:
        return None
    w[rest] = w_rest
    return w


def _floor_trend(w: np.ndarray, n: int, floor: float = 0.0) -> bool:
    """Raise the eigenvalues of the trend's Hessian below ``CURVATURE_FLOOR`` times its
    largest, or below ``floor``, to that bound, in place in ``w``; whether any was (see
    :func:`_convex_solve`)."""
    lam, V = np.linalg.eigh(_trend_hessian(w, n))
    return _raise_curvature(w, n, lam, V, floor)


def _floor_trends(ws: list[np.ndarray | None], n: int, floor: float = 0.0) -> list[bool]:
    """:func:`_floor_trend` of every solution of ``ws`` (None: False), with one batched
    eigendecomposition: most solutions of a search need none raised, and a call per
    solution cost more than the solves' factorisations of small systems. The same LAPACK
    routine runs on each matrix, so the result is the same to the last bit."""
    idx = [i for i, w in enumerate(ws) if w is not None]
    out = [False] * len(ws)
    if not idx:
        return out
    iu, ju, scale = _upper(n)
    W = np.stack([ws[i] for i in idx])
    coef = W[:, 2 + n:_n_trend(n)] / scale
    S = np.zeros((len(idx), n, n))
    S[:, iu, ju] = coef
    S[:, ju, iu] = coef
    H = W[:, 1 + n, None, None] * np.eye(n) + 2.0 * S
    lam, V = np.linalg.eigh(H)
    # The test of _raise_curvature for all at once: most need nothing raised.
    for j in np.flatnonzero(lam[:, 0] < _curvature_bound(lam[:, -1], floor)):
        out[idx[j]] = _raise_curvature(ws[idx[j]], n, lam[j], V[j], floor)
    return out


def _raise_curvature(w: np.ndarray, n: int, lam: np.ndarray, V: np.ndarray,
                     floor: float = 0.0) -> bool:
    """:func:`_floor_trend` given the eigenvalues ``lam`` (n,) and vectors ``V`` (n, n) of
    the trend's Hessian."""
    floor = _curvature_bound(lam[-1], floor)
    if lam[0] >= floor:
        return False
    S = 0.5 * ((V * np.maximum(lam, floor)) @ V.T - w[1 + n] * np.eye(n))
    iu, ju, scale = _upper(n)
    w[2 + n:_n_trend(n)] = scale * S[iu, ju]
    return True


def _curvature_bound(largest: float | np.ndarray, floor: float = 0.0) -> np.ndarray:
    """The least eigenvalue the trend's Hessian may keep: ``CURVATURE_FLOOR`` times its
    largest, ``largest`` (1 where that is not positive), and at least ``floor``; for one
    Hessian or, given an array of largest eigenvalues, for each."""
    return np.maximum(CURVATURE_FLOOR * np.where(largest > 0, largest, 1.0), floor)


def _without_block(M: np.ndarray, a: int, b: int) -> np.ndarray:
    """``M`` (p, p) without its rows and columns ``a:b``: four block copies, a tenth of the
    time of fancy indexing (this runs for most candidates of a search)."""
    k = len(M) - (b - a)
    out = np.empty((k, k))
    out[:a, :a], out[:a, a:] = M[:a, :a], M[:a, b:]
    out[a:, :a], out[a:, a:] = M[b:, :a], M[b:, b:]
    return out


def _solve_shared(M: np.ndarray, b: np.ndarray, penalties: list[np.ndarray], q: int,
                  factor: tuple | None = None) -> list[np.ndarray | None]:
    """Solve ``(M + P) w = b`` for every ``P`` in ``penalties``.

    When the penalties are block diagonal with the same leading ``q x q`` block (the
    trend's, while the kernel's penalty varies; ``q < 0``: the same trailing ``-q x -q``
    block, the kernel's, while the trend's varies), that block is factored once and every
    penalty costs one factorisation of the other block's Schur complement, a fraction of
    the work of factoring each full system. ``factor``: :func:`_shared_factor`'s, if known.
    """
    p = M.shape[0]
    if q == 0 or abs(q) >= p or len(penalties) < 2:
        return [_solve(M + P, b) for P in penalties]
    if factor is None:
        factor = _shared_factor(M, b, penalties[0], q)
    if factor is None:
        return [_solve(M + P, b) for P in penalties]
    s, o, L, W, z = factor
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
        w[s] = solve_triangular(L, z - W @ w_other, lower=True, trans=1)
        out.append(w)
    return out


def _shared_factor(M: np.ndarray, b: np.ndarray, P: np.ndarray, q: int) -> tuple | None:
    """The shared block of :func:`_solve_shared` factored: its slice ``s``, the other
    block's ``o``, the Cholesky factor ``L`` of ``(M + P)[s, s]``, ``W = L^-1 M[s, o]`` and
    ``z = L^-1 b[s]``; None if the block is not positive definite."""
    p = M.shape[0]
    # Slices, not a permuted copy: copying the large blocks costs more than the solves.
    s, o = (slice(0, q), slice(q, p)) if q > 0 else (slice(p + q, p), slice(0, p + q))
    try:
        L = cholesky(M[s, s] + P[s, s], lower=True)
    except np.linalg.LinAlgError:
        return None
    W = solve_triangular(L, M[s, o], lower=True)
    z = solve_triangular(L, b[s], lower=True)
    return s, o, L, W, z


def _convex_solves(M: np.ndarray, b: np.ndarray, penalties: list[np.ndarray], q: int,
                   n: int, floor: float = 0.0) -> list[np.ndarray | None]:
    """:func:`_convex_solve` of ``(M + P) w = b`` for every ``P`` in ``penalties``, solved
    by :func:`_solve_shared` with its shared block ``q``.

    A trend that needs its curvature raised keeps the factorisations for the re-solve of
    the other coefficients. When the shared block is the kernel's (``q < 0``, the trend's
    penalty varies), only the trend's constant and linear part is eliminated again, at the
    cost of two triangular solves rather than a factorisation of the whole system; when it
    is the trend's, see :func:`_convex_solves_trend_shared`. ``floor`` as in
    :func:`_convex_solve`.
    """
    p = M.shape[0]
    if q == _n_trend(n) < p and len(penalties) >= 2:
        return _convex_solves_trend_shared(M, b, penalties, n, floor)
    factor = None
    if q < 0 and p + q == _n_trend(n) and len(penalties) >= 2:
        factor = _shared_factor(M, b, penalties[0], q)
    first = _solve_shared(M, b, penalties, q, factor)
    if factor is None:
        return [_convex_solve(M + P, b, n, w, floor)
                for P, w in zip(penalties, first, strict=True)]
    raised = _floor_trends(first, n, floor)
    return [_resolve_with_factor(M + P, b, w, n, factor) if up else w
            for P, w, up in zip(penalties, first, raised, strict=True)]


def _convex_solves_trend_shared(M: np.ndarray, b: np.ndarray, penalties: list[np.ndarray],
                                n: int, floor: float = 0.0) -> list[np.ndarray | None]:
    """:func:`_convex_solves` with the trend's block shared (the kernel's penalty varies).

    The solves are :func:`_solve_shared`'s; the factor of each penalty's Schur complement
    is kept, and a trend whose curvature is raised re-solves the other coefficients on it:
    eliminating the constant and linear part alone rather than the whole trend changes that
    Schur complement by a term of rank ``n (n + 1) / 2 + 1`` (the quadratic part's), which
    the Woodbury identity absorbs with a few triangular solves.
    """
    p, p_t = M.shape[0], _n_trend(n)
    factor = _shared_factor(M, b, penalties[0], p_t)
    if factor is None:
        return [_convex_solve(M + P, b, n, w, floor)
                for P, w in zip(penalties, _solve_shared(M, b, penalties, p_t), strict=True)]
    s, o, L, W, z = factor
    schur = M[o, o] - _gram(W)
    rhs = b[o] - W.T @ z
    out: list[np.ndarray | None] = []
    factors: list[tuple | None] = []  # None: solved, floored and final already
    for P in penalties:
        try:
            S = cho_factor(schur + P[o, o])
        except np.linalg.LinAlgError:
            w = _solve_shared(M, b, [P, P], p_t, factor)[0]  # the general fallbacks
            out.append(_convex_solve(M + P, b, n, w, floor))
            factors.append(None)
            continue
        w = np.empty(p)
        w[o] = cho_solve(S, rhs)
        w[s] = solve_triangular(L, z - W @ w[o], lower=True, trans=1)
        out.append(w)
        factors.append(S)
    raised = _floor_trends([w if S is not None else None
                            for w, S in zip(out, factors, strict=True)], n, floor)
    update = None
    for i in np.flatnonzero(raised):
        if update is None:
            update = _quadratic_update(M + penalties[0], n)
        out[i] = _resolve_woodbury(M + penalties[i], b, out[i], n, factors[i], update)
    return out


def _quadratic_update(K: np.ndarray, n: int) -> tuple | None:
    """For the trend block of ``K`` split into ``r`` (constant and linear) and ``q`` (the
    quadratic part): the factor of ``K_rr``, ``S_q = K_qq - K_qr K_rr^-1 K_rq`` and
    ``X = K_qo - K_qr K_rr^-1 K_ro`` (``o`` the kernel's columns); None if ``K_rr`` is not
    positive definite."""
    p_t = _n_trend(n)
    r, q, o = slice(0, 1 + n), slice(1 + n, p_t), slice(p_t, len(K))
    try:
        F = cho_factor(K[r, r])
    except np.linalg.LinAlgError:
        return None
    Y = cho_solve(F, np.hstack([K[r, q], K[r, o]]))
    m_q = p_t - 1 - n
    S_q = K[q, q] - K[q, r] @ Y[:, :m_q]
    X = K[q, o] - K[q, r] @ Y[:, m_q:]
    return F, S_q, X


def _resolve_woodbury(K: np.ndarray, b: np.ndarray, w: np.ndarray, n: int, S: tuple,
                      update: tuple | None) -> np.ndarray | None:
    """The constant, linear and kernel coefficients of ``K w = b`` given the quadratic part
    of ``w`` (fixed by :func:`_floor_trend`): the kernel's from the Schur complement of the
    whole trend (factored in ``S``) updated by the quadratic part's term (``update``,
    :func:`_quadratic_update`), then the constant and linear part."""
    if update is None:
        return _convex_resolve(K, b, w, n)
    F, S_q, X = update
    p_t = _n_trend(n)
    r, q, o = slice(0, 1 + n), slice(1 + n, p_t), slice(p_t, len(K))
    c = b[r] - K[r, q] @ w[q]
    g = b[o] - K[o, q] @ w[q] - K[o, r] @ cho_solve(F, c)
    Sg = cho_solve(S, g)
    SX = cho_solve(S, X.T)
    core = _solve(S_q + X @ SX, X @ Sg)
    if core is None:
        return _convex_resolve(K, b, w, n)
    w[o] = Sg - SX @ core
    w[r] = cho_solve(F, c - K[r, o] @ w[o])
    return w


def _resolve_with_factor(K: np.ndarray, b: np.ndarray, w: np.ndarray, n: int, factor: tuple
                         ) -> np.ndarray | None:
    """The constant, linear and kernel coefficients of ``K w = b`` given the quadratic part
    of ``w`` (fixed by :func:`_floor_trend`), with the kernel block factored in ``factor``
    (:func:`_shared_factor` with ``q < 0``): block elimination of the constant and linear
    part, whose ``1 + n`` columns of ``W`` it reuses."""
    s, _, L, W, _ = factor
    p_t = _n_trend(n)
    r, quad = slice(0, 1 + n), slice(1 + n, p_t)
    c = b[r] - K[r, quad] @ w[quad]
    d = solve_triangular(L, b[s] - K[s, quad] @ w[quad], lower=True)
    Wr = W[:, r]
    x = _solve(K[r, r] - Wr.T @ Wr, c - Wr.T @ d)
    if x is None:
        return None
    w[r] = x
    w[s] = solve_triangular(L, d - Wr @ x, lower=True, trans=1)
    return w


def _nonneg_solve(M: np.ndarray, b: np.ndarray, free: int) -> np.ndarray | None:
    """Minimise ``w' M w - 2 b' w`` over ``w`` (p,) with ``w[free:] >= 0`` (the
    single-index profile's weights after its constant); None if ``M`` is not positive
    definite.

    The first ``free`` entries are eliminated in closed form; the rest is the NNLS problem
    ``min ||R w - R^-T c||`` on the Cholesky factor ``R`` of their Schur complement.
    """
    try:
        F = cho_factor(M[:free, :free])
        X = cho_solve(F, np.column_stack([M[:free, free:], b[:free]]))
        R = cholesky(M[free:, free:] - M[free:, :free] @ X[:, :-1], lower=False)
        c = b[free:] - M[free:, :free] @ X[:, -1]
        t = solve_triangular(R, c, lower=False, trans=1)
        beta = scipy.optimize.nnls(R, t, maxiter=50 * len(t))[0]
    except (np.linalg.LinAlgError, ValueError, RuntimeError):
        return None
    return np.concatenate([X[:, -1] - X[:, :-1] @ beta, beta])


def _solve(M: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """``M^-1 b`` for a symmetric ``M`` (p, p): by Cholesky, else (not positive definite
    to round-off) by a symmetric indefinite factorisation; None if that fails too."""
    try:
        return cho_solve(cho_factor(M), b)
    except np.linalg.LinAlgError:
        try:
            # An ill-conditioned candidate is judged by its CV score and the fit's checks,
            # not by a LinAlgWarning that a user of the fit could do nothing about.
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
                return scipy.linalg.solve(M, b, assume_a="sym", check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return None


def _trend_penalty(n: int, trend_ridge: float) -> np.ndarray:
    """Diagonal penalty (p_t, p_t) of the quadratic trend's coefficients: ``trend_ridge`` on
    the anisotropic part ``S`` (``inf``: 1e12, the isotropic bowl), :data:`JITTER` on the
    rest."""
    p = _n_trend(n)
    diag = np.full(p, JITTER)
    diag[2 + n:] = 1e12 if math.isinf(trend_ridge) else trend_ridge + JITTER
    return np.diag(diag)


def _penalty(n: int, trend_ridge: float, kernel_ridge: float, Kcc: np.ndarray
             ) -> np.ndarray:
    """Block-diagonal penalty (p_t + m_c, p_t + m_c) of the trend and of the kernel
    residual on the centres whose Gram is ``Kcc`` (m_c, m_c)."""
    p_t, m = _n_trend(n), len(Kcc)
    P = np.zeros((p_t + m, p_t + m))
    P[:p_t, :p_t] = _trend_penalty(n, trend_ridge)
    P[p_t:, p_t:] = kernel_ridge * (Kcc + JITTER * np.eye(m)) + JITTER * np.eye(m)
    return P
