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

Choosing the hyperparameters
----------------------------
``trend_ridge``, ``length_scale`` and ``kernel_ridge`` (an infinite ``kernel_ridge`` drops
the residual, an infinite ``trend_ridge`` keeps the isotropic bowl only) are chosen by
K-fold cross-validation in which every fold holds out *whole demonstrations* and scores
their aligned values ``y`` (not only their increments): the aligned values carry the
potential *across* demonstrations, which is what a policy needs at new start states. All
fold errors come from per-fold Gram matrices (one pass over the data per length scale),
so the search costs a few small Cholesky solves per candidate. The data are thinned
evenly in arc length along each demonstration first (a robot at rest adds samples but no
information), to at most ``max_fit_points`` samples.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import scipy.linalg

from policy_align_ros.learning.regressors._common import (
    NotFittedError,
    assign_folds,
    check_Xy,
    check_query,
    thin_by_arc_length,
)

__all__ = ["TrendKernelRegression", "quadratic_features"]

#: Candidate trend penalties (on standardised data); ``inf`` is the isotropic bowl.
TREND_RIDGE_GRID = (1e-6, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, math.inf)
#: Candidate kernel penalties; ``inf`` drops the kernel residual.
KERNEL_RIDGE_GRID = (1e-6, 1e-4, 1e-2, math.inf)
#: Candidate length scales, as factors of the median distance between centres.
LENGTH_FACTORS = (0.08, 0.16, 0.32, 0.64)
#: Added to the penalty of every coefficient: keeps the solves well posed.
JITTER = 1e-9
#: Rows per block when evaluating kernels (bounds memory on large queries).
CHUNK = 8192
_STATE_VERSION = 1


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
    """Per-fold Gram matrices of a design, for values and for increments along demos.

    ``A`` (m, p) is the design at the samples (samples of one demonstration consecutive),
    ``u`` (m,) the targets; ``pairs`` (P, 2) index consecutive samples of a demonstration,
    whose differences give the increment design ``A[j] - A[i]`` and targets
    ``u[j] - u[i]``. Fold ``f`` is held out by subtracting its Grams from the totals, so
    every score below costs one (p, p) solve per fold.
    """

    def __init__(self, A: np.ndarray, u: np.ndarray, folds: np.ndarray, n_folds: int,
                 pairs: np.ndarray):
        D = A[pairs[:, 1]] - A[pairs[:, 0]]
        du = u[pairs[:, 1]] - u[pairs[:, 0]]
        pair_folds = folds[pairs[:, 0]]
        self.G, self.r, self.uu = _grams(A, u, folds, n_folds)
        self.GD, self.rD, self.dd = _grams(D, du, pair_folds, n_folds)
        self.count = np.bincount(folds, minlength=n_folds).astype(float)
        self.count_D = np.bincount(pair_folds, minlength=n_folds).astype(float)
        self.G_all, self.r_all = self.G.sum(axis=0), self.r.sum(axis=0)
        self.u_var = self.uu.sum() / self.count.sum()
        self.du_var = max(self.dd.sum() / max(self.count_D.sum(), 1.0), 1e-300)

    def score(self, penalty: np.ndarray) -> tuple[float, float]:
        """Held-out (values, increments) mean squared errors, each over its variance."""
        err = err_d = 0.0
        for f in range(len(self.count)):
            m_train = self.count.sum() - self.count[f]
            w = _solve((self.G_all - self.G[f]) / m_train + penalty,
                       (self.r_all - self.r[f]) / m_train)
            if w is None:
                return math.inf, math.inf
            err += self.uu[f] - 2.0 * w @ self.r[f] + w @ self.G[f] @ w
            err_d += self.dd[f] - 2.0 * w @ self.rD[f] + w @ self.GD[f] @ w
        return (float(err / self.count.sum() / self.u_var),
                float(err_d / max(self.count_D.sum(), 1.0) / self.du_var))


def _grams(A: np.ndarray, u: np.ndarray, folds: np.ndarray, n_folds: int):
    G = np.stack([A[folds == f].T @ A[folds == f] for f in range(n_folds)])
    r = np.stack([A[folds == f].T @ u[folds == f] for f in range(n_folds)])
    uu = np.array([u[folds == f] @ u[folds == f] for f in range(n_folds)])
    return G, r, uu


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
    trend_ridge : "cv" or float
        Penalty on the anisotropic part ``S`` of the quadratic trend (standardised units;
        ``inf``: an isotropic bowl only), or ``"cv"`` to choose from ``TREND_RIDGE_GRID``.
    length_scale : "cv" or float
        Kernel length scale in standardised units, or ``"cv"`` (``LENGTH_FACTORS`` times
        the median distance between centres).
    kernel_ridge : "cv" or float
        RKHS penalty of the residual (``inf``: no residual), or ``"cv"``.
    n_centres : int
        Kernel centres (a random subset of the thinned data).
    max_fit_points : int
        Samples kept after thinning in arc length along each demonstration.
    n_folds : int
        Cross-validation folds, each of whole demonstrations (``groups``).
    random_state : int, numpy.random.Generator or None
        Seeds the choice of centres and folds.

    Attributes
    ----------
    trend_ridge_, length_scale_, kernel_ridge_ : float
        Hyperparameters used.
    cv_scores_ : dict
        Held-out mean squared error (outputs scaled to unit variance) per evaluated
        ``(trend_ridge, length_scale, kernel_ridge)``.
    mean_, scale_ : ndarray (n,), float
        Standardisation of the states (state units).
    y_mean_, y_scale_ : float
        Standardisation of the outputs.
    trend_ : ndarray (2 + n + n (n + 1) / 2,)
        Trend coefficients (standardised units).
    centres_ : ndarray (m, n)
        Kernel centres, standardised; ``alpha_`` (m,) their weights.
    n_features_in_ : int
    """

    def __init__(
        self,
        *,
        trend_ridge: str | float = "cv",
        length_scale: str | float = "cv",
        kernel_ridge: str | float = "cv",
        n_centres: int = 300,
        max_fit_points: int = 6000,
        n_folds: int = 5,
        random_state: int | np.random.Generator | None = 0,
    ) -> None:
        self.trend_ridge = trend_ridge
        self.length_scale = length_scale
        self.kernel_ridge = kernel_ridge
        self.n_centres = n_centres
        self.max_fit_points = max_fit_points
        self.n_folds = n_folds
        self.random_state = random_state

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Constructor parameters, as given."""
        return {
            "trend_ridge": self.trend_ridge,
            "length_scale": self.length_scale,
            "kernel_ridge": self.kernel_ridge,
            "n_centres": self.n_centres,
            "max_fit_points": self.max_fit_points,
            "n_folds": self.n_folds,
            "random_state": self.random_state,
        }

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"TrendKernelRegression({args})"

    def _check_params(self) -> None:
        for name in ("trend_ridge", "length_scale", "kernel_ridge"):
            value = getattr(self, name)
            if value == "cv":
                continue
            if not isinstance(value, (int, float)) or not value > 0 or math.isnan(value):
                raise ValueError(f"{name} must be 'cv' or a positive float, got {value!r}")
        if self.length_scale != "cv" and math.isinf(self.length_scale):
            raise ValueError("length_scale must be finite")
        for name, low in (("n_centres", 1), ("max_fit_points", 10), ("n_folds", 2)):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"{name} must be an int >= {low}, got {value!r}")

    # -- fit --------------------------------------------------------------------------
    def fit(self, X: np.ndarray, y: np.ndarray, groups: np.ndarray | None = None
            ) -> TrendKernelRegression:
        """Fit on states ``X`` (m, n), outputs ``y`` (m,) and demonstration ids ``groups``.

        Samples of one demonstration must be consecutive and in time order (they are
        thinned in arc length). Without ``groups`` all samples form one demonstration and
        the hyperparameters that are ``"cv"`` fall back to mid-grid values.

        Returns
        -------
        self
        """
        self._check_params()
        X, y, groups = check_Xy(X, y, groups)
        rng = np.random.default_rng(self.random_state)
        idx = thin_by_arc_length(X, groups, self.max_fit_points)
        X, y, groups = X[idx], y[idx], groups[idx]
        m, n = X.shape
        self.n_features_in_ = n
        self.mean_ = X.mean(axis=0)
        self.scale_ = float(np.sqrt(np.mean(np.var(X, axis=0)))) or 1.0
        self.y_mean_ = float(y.mean())
        self.y_scale_ = float(y.std()) or 1.0
        Z = (X - self.mean_) / self.scale_
        u = (y - self.y_mean_) / self.y_scale_

        centre_idx = np.sort(rng.choice(m, size=min(self.n_centres, m), replace=False))
        C = Z[centre_idx]
        F = quadratic_features(Z)
        n_groups = len(np.unique(groups))
        n_folds = min(self.n_folds, n_groups)
        folds = assign_folds(groups, n_folds, rng) if n_folds >= 2 else None

        d_med = _median_distance(C)
        lengths = ([float(self.length_scale)] if self.length_scale != "cv"
                   else [f * d_med for f in LENGTH_FACTORS])
        t_grid = (TREND_RIDGE_GRID if self.trend_ridge == "cv" else (float(self.trend_ridge),))
        k_grid = (KERNEL_RIDGE_GRID if self.kernel_ridge == "cv"
                  else (float(self.kernel_ridge),))
        self.cv_scores_: dict[tuple[float, float, float], float] = {}

        if folds is None:
            t_best = t_grid[len(t_grid) // 2]
            k_best = k_grid[len(k_grid) // 2]
            ell_best = lengths[len(lengths) // 2]
        else:
            # 1. The trend alone picks its penalty ...
            same = np.flatnonzero(groups[1:] == groups[:-1])
            pairs = np.column_stack([same, same + 1])
            grams = _FoldGrams(F, u, folds, n_folds, pairs)
            for t in t_grid:
                self.cv_scores_[(t, math.nan, math.inf)] = grams.score(self._trend_penalty(n, t))
            t_best = min(t_grid, key=lambda t: _criterion(self.cv_scores_[(t, math.nan, math.inf)]))
            best = (t_best, math.nan, math.inf)
            # 2. ... then the residual its length scale and penalty, jointly with the trend.
            finite_k = [k for k in k_grid if math.isfinite(k)]
            if finite_k:
                for ell in lengths:
                    K = _gaussian(Z, C, ell)
                    grams = _FoldGrams(np.hstack([F, K]), u, folds, n_folds, pairs)
                    Kcc = _gaussian(C, C, ell)
                    for k in finite_k:
                        key = (t_best, ell, k)
                        self.cv_scores_[key] = grams.score(self._penalty(n, t_best, k, Kcc))
                        if _criterion(self.cv_scores_[key]) < _criterion(self.cv_scores_[best]):
                            best = key
            t_best, ell_best, k_best = best
            if math.isnan(ell_best):
                ell_best = lengths[len(lengths) // 2]
        self.trend_ridge_, self.length_scale_, self.kernel_ridge_ = t_best, ell_best, k_best
        self._final_fit(F, Z, u, C, n)
        return self

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

    def _final_fit(self, F: np.ndarray, Z: np.ndarray, u: np.ndarray, C: np.ndarray, n: int
                   ) -> None:
        m = len(u)
        p_t = _n_trend(n)
        if math.isinf(self.kernel_ridge_):
            w = _solve(F.T @ F / m + self._trend_penalty(n, self.trend_ridge_), F.T @ u / m)
            self.centres_ = np.zeros((0, n))
            self.alpha_ = np.zeros(0)
        else:
            A = np.hstack([F, _gaussian(Z, C, self.length_scale_)])
            P = self._penalty(n, self.trend_ridge_, self.kernel_ridge_,
                              _gaussian(C, C, self.length_scale_))
            w = _solve(A.T @ A / m + P, A.T @ u / m)
            self.centres_ = C
            self.alpha_ = w[p_t:] if w is not None else None
        if w is None or not np.all(np.isfinite(w)):
            raise ValueError("TrendKernelRegression: the penalised least squares failed")
        self.trend_ = w[:p_t]
        self._unpack()

    def _unpack(self) -> None:
        n = self.n_features_in_
        t = self.trend_
        iu, ju = np.triu_indices(n)
        S = np.zeros((n, n))
        coef = t[2 + n:]
        S[iu, ju] = np.where(iu == ju, coef, coef / math.sqrt(2.0))
        self._S = S + S.T - np.diag(np.diag(S))
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
        """Numeric arrays and a JSON-able header that rebuild this model exactly."""
        self._check_fitted()
        params = self.get_params()
        if isinstance(params["random_state"], np.random.Generator):
            params["random_state"] = None
        for name in ("trend_ridge", "length_scale", "kernel_ridge"):
            if params[name] != "cv":
                params[name] = _json_float(float(params[name]))
        meta = {
            "version": _STATE_VERSION,
            "params": params,
            "trend_ridge": _json_float(self.trend_ridge_),
            "length_scale": float(self.length_scale_),
            "kernel_ridge": _json_float(self.kernel_ridge_),
            "scale": self.scale_,
            "y_mean": self.y_mean_,
            "y_scale": self.y_scale_,
            "n_features_in": int(self.n_features_in_),
        }
        arrays = {"mean": self.mean_, "trend": self.trend_, "centres": self.centres_,
                  "alpha": self.alpha_}
        return arrays, meta

    @classmethod
    def from_state(cls, arrays: dict[str, np.ndarray], meta: dict[str, Any]
                   ) -> TrendKernelRegression:
        """Rebuild a fitted model from :meth:`get_state` output (ValueError if malformed)."""
        try:
            if int(meta["version"]) > _STATE_VERSION:
                raise ValueError(f"format version {meta['version']} is newer than supported")
            params = dict(meta["params"])
            for name in ("trend_ridge", "length_scale", "kernel_ridge"):
                if params[name] != "cv":
                    params[name] = float(params[name])
            model = cls(**params)
            n = int(meta["n_features_in"])
            model.n_features_in_ = n
            model.trend_ridge_ = float(meta["trend_ridge"])
            model.length_scale_ = float(meta["length_scale"])
            model.kernel_ridge_ = float(meta["kernel_ridge"])
            model.scale_ = float(meta["scale"])
            model.y_mean_ = float(meta["y_mean"])
            model.y_scale_ = float(meta["y_scale"])
            model.mean_ = np.asarray(arrays["mean"], dtype=float).reshape(n)
            model.trend_ = np.asarray(arrays["trend"], dtype=float).reshape(_n_trend(n))
            model.centres_ = np.asarray(arrays["centres"], dtype=float).reshape(-1, n)
            model.alpha_ = np.asarray(arrays["alpha"], dtype=float).reshape(len(model.centres_))
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"regressor state: bad or missing field ({err})") from None
        model.cv_scores_ = {}
        model._unpack()
        return model


def _criterion(scores: tuple[float, float]) -> float:
    import os
    mode = os.environ.get("PA_CRIT", "value")
    v, d = scores
    if mode == "value":
        return v
    if mode == "inc":
        return d
    return v + d


def _json_float(value: float) -> float | str:
    return "inf" if math.isinf(value) else float(value)


def _median_distance(C: np.ndarray) -> float:
    """Median distance between distinct centres (standardised units), > 0."""
    sq = np.einsum("ij,ij->i", C, C)
    d2 = sq[:, None] - 2.0 * C @ C.T + sq[None, :]
    iu = np.triu_indices(len(C), 1)
    d = np.sqrt(np.maximum(d2[iu], 0.0))
    d = d[d > 0]
    return float(np.median(d)) if len(d) else 1.0
