"""The cross-validated choice of the trend-kernel model's hyperparameters.

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
scale), so the search costs a few small Cholesky solves per candidate
(``docs/design/cv_selection.md``). The data are thinned evenly in arc
length along each demonstration first (a robot at rest adds samples but no information),
to at most ``max_fit_points`` samples.
"""

from __future__ import annotations

import math

import numpy as np

from policy_align_ros.learning.regressors.trend_kernel import single_index
from policy_align_ros.learning.regressors.trend_kernel.features import (
    _gaussian,
    _index_design,
    _kernel,
    _n_index_weights,
    _n_trend,
    _profile_scale,
    _trend_hessian,
)
from policy_align_ros.learning.regressors.trend_kernel.grams import (
    _CVData,
    _fold_summary,
    _FoldGrams,
)
from policy_align_ros.learning.regressors.trend_kernel.solvers import (
    CURVATURE_FLOOR,
    JITTER,
    _convex_solve,
    _penalty,
    _trend_penalty,
    effective_dof,
)

__all__ = [
    "CV_RESOLUTION",
    "DOF_RESOLUTION",
    "KERNEL_RIDGE_GRID",
    "LENGTH_FACTORS",
    "OFFSET_RIDGE_GRID",
    "TREND_RIDGE_GRID",
    "CVSearch",
]

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
#: CV scores (shape error over the spread) closer than this are not told apart: the
#: potential is then known to 1e-5 of its spread either way, and differences come from
#: round-off (an exact quadratic scored 1e-21 with the trend alone, 1e-18 with a residual).
CV_RESOLUTION = 1e-10
#: Effective degrees of freedom closer than this are the same complexity (see
#: :meth:`CVSearch.fewest_dof_within`).
DOF_RESOLUTION = 0.5
#: Samples (a random subset of the thinned data) on which the single-index trend's index is
#: fitted, and the residual evaluations allowed, for the final fit and every fold's alike
#: (the folds score the procedure the final fit runs).
INDEX_FIT_POINTS = 2000
INDEX_NFEV = 20


class CVSearch:
    """The CV scores of one fit's candidates and its picks.

    A candidate is the key ``(trend_form, trend_ridge, length_scale, kernel_ridge,
    offset_ridge)``; :class:`.model.TrendKernelRegression` exposes ``scores``,
    ``standard_errors`` and ``dof`` as ``cv_scores_``, ``cv_standard_errors_`` and
    ``cv_dof_``.

    Attributes
    ----------
    scores, standard_errors, dof : dict
        Held-out shape error, its standard error over the folds, and the effective degrees
        of freedom of the candidates the residual's choice compared.
    quadratic_pick : tuple
        The quadratic family's pick (the mid-grid candidate until the search sets it): the
        fallback of a single-index trend whose profile fails to rise.
    index : tuple (L, z0, s) or None
        The single-index trend's index fitted on all data, once :meth:`fit_index` ran.
    """

    def __init__(self, quadratic_pick: tuple) -> None:
        self.scores: dict[tuple, float] = {}
        self.standard_errors: dict[tuple, float] = {}
        self.dof: dict[tuple, float] = {}
        self.quadratic_pick = quadratic_pick
        self.index: tuple[np.ndarray, np.ndarray, float] | None = None

    def run(self, cv: _CVData, forms: list[str], lengths: list[float], t_grid: list[float],
            k_grid: list[float], o_grid: list[float], rng: np.random.Generator) -> tuple:
        """Score the candidates of every trend form into ``scores``; return the pick.

        The single-index trend is fitted and scored when the quadratic's pick does not
        fit the held-out shapes to :data:`CV_RESOLUTION`, and kept if it scores lower."""
        quadratic = None
        if "quadratic" in forms:
            quadratic = self.quadratic_pick = self.quadratic_search(cv, lengths, t_grid,
                                                                      k_grid, o_grid)
            if "single_index" not in forms or self.scores[quadratic] <= CV_RESOLUTION:
                return quadratic
        # The index starts from the quadratic trend alone with free offsets, at its best
        # trend penalty (the fit that ranks shapes, not levels).
        keys = [("quadratic", t, math.nan, math.inf, 0.0) for t in t_grid]
        if all(key in self.scores for key in keys):
            t_init = min(keys, key=self.scores.get)[1]
        else:
            scores = cv.trend.scores([_trend_penalty(cv.n, t) for t in t_grid], 0.0)
            t_init = t_grid[int(np.argmin([score for score, _ in scores]))]
        bound = math.inf if quadratic is None else self.scores[quadratic] - CV_RESOLUTION
        index = self.index_search(cv, t_init, o_grid, rng, bound)
        if quadratic is None and not math.isfinite(self.scores[index]):
            # No fold's profile rose (two minima, say): the quadratic as the CV picks it,
            # not at mid-grid penalties.
            quadratic = self.quadratic_pick = self.quadratic_search(cv, lengths, t_grid,
                                                                      k_grid, o_grid)
        if quadratic is None or (self.scores[index]
                                 < self.scores[quadratic] - CV_RESOLUTION):
            return index
        return quadratic

    def fit_index(self, grams: _FoldGrams, Z: np.ndarray, u: np.ndarray, demo: np.ndarray,
                  t_init: float, rng: np.random.Generator) -> np.ndarray:
        """Fit the single-index trend's index on a random subset of the samples, from the
        quadratic trend with free offsets and penalty ``t_init`` (sums in ``grams``);
        store it in ``index`` and return the subset's indices."""
        n = Z.shape[1]
        L0, z0 = _quadratic_index(grams, n, _trend_penalty(n, t_init))
        sub = np.sort(rng.choice(len(u), size=min(INDEX_FIT_POINTS, len(u)), replace=False))
        s = _profile_scale(Z[sub], L0, z0)
        L, z = single_index.fit_index(Z[sub], u[sub], demo[sub], L0, z0, s, INDEX_NFEV)
        self.index = (L, z, s)
        return sub

    def index_search(self, cv: _CVData, t_init: float, o_grid: list[float],
                     rng: np.random.Generator, bound: float = math.inf) -> tuple:
        """Score the single-index trend per offset penalty; return its best key.

        The folds stop once those scored already sum to ``bound`` (the score it has to
        beat) for every offset penalty: the rest can only add error. The scores recorded
        are then those lower bounds, with standard error NaN.

        Its index is fitted on all data (the final fit's), then again without every fold's
        demonstrations, started from the quadratic trend fitted without them: a held-out
        demonstration never shapes the index it is scored with, nor its start or scale."""
        n = cv.n
        sub = self.fit_index(cv.trend, cv.Z, cv.u, cv.demo, t_init, rng)
        start_penalty = _trend_penalty(n, t_init)
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
        self.record(keys, summary)
        return _simplest_within(self.scores, keys, 0.0, lambda key: -key[4])

    def quadratic_search(self, cv: _CVData, lengths: list[float], t_grid: list[float],
                         k_grid: list[float], o_grid: list[float]) -> tuple:
        """Score the quadratic trend's candidates in three stages; return its pick."""
        n = cv.n
        # 1. The trend alone scores its penalties and the offsets' ...
        for o in o_grid:
            self.record([("quadratic", t, math.nan, math.inf, o) for t in t_grid],
                         cv.trend.scores([_trend_penalty(n, t) for t in t_grid], o,
                                         floor=cv.floor))
        # 2. ... then the residual its length scale and penalty, jointly with the trend: at
        # the first stage's pick, and with free offsets at their best trend penalty. Where
        # a quadratic does not fit, the trend alone can rank the offset penalties wrongly.
        scores = self.scores
        stage_one = _simplest_within(scores, list(scores), 0.0, _simpler_trend)
        paths = {stage_one[4]: stage_one[1]}  # offset penalty -> trend penalty
        if 0.0 in o_grid and 0.0 not in paths:
            paths[0.0] = _simplest_within(scores, [key for key in scores if key[4] == 0.0],
                                          0.0, _simpler_trend)[1]
        finite_k = [k for k in k_grid if math.isfinite(k)]
        if scores[stage_one] <= CV_RESOLUTION and math.inf in k_grid:
            # The trend alone fits the held-out shapes to round-off: a residual can only tie
            # with it, and ties go to the simpler model.
            finite_k = []
        for ell in lengths if finite_k else ():
            grams, Kcc = cv.kernel_sums(ell)
            for o, t in paths.items():
                self.record([("quadratic", t, ell, k, o) for k in finite_k],
                             grams.scores([_penalty(n, t, k, Kcc) for k in finite_k], o,
                                          shared=_n_trend(n), floor=cv.floor))
        # The better path, and on it the model with the fewest effective degrees of freedom
        # within one standard error of its best score (no residual only if the kernel
        # penalty is left to the CV).
        keys = [key for key in scores if paths.get(key[4]) == key[1]
                and (math.inf in k_grid or math.isfinite(key[3]))]
        path = _simplest_within(scores, keys, 0.0, _simpler_trend)
        keys = [key for key in keys if key[4] == path[4]]
        error = self.standard_errors[min(keys, key=scores.get)]
        best = self.fewest_dof_within(cv, keys, error if math.isfinite(error) else 0.0)
        # 3. With a residual, the trend's and the offsets' penalties again: the trend alone
        # cannot tell them apart where a quadratic does not fit.
        if math.isfinite(best[3]) and (len(t_grid) > 1 or len(o_grid) > 1):
            ell, k = best[2], best[3]
            # Summed again rather than kept from stage 2: every length scale's sums held at
            # once would multiply the peak memory.
            grams, Kcc = cv.kernel_sums(ell)
            for o in o_grid:
                self.record([("quadratic", t, ell, k, o) for t in t_grid],
                             grams.scores([_penalty(n, t, k, Kcc) for t in t_grid], o,
                                          shared=-len(cv.C), floor=cv.floor))
            best = _simplest_within(scores, [key for key in scores if key[2:4] == (ell, k)],
                                    0.0, _simpler_trend)
        return best

    def fewest_dof_within(self, cv: _CVData, keys: list[tuple], margin: float) -> tuple:
        """Of ``keys`` (one trend and offset penalty; residuals, and the trend alone), the
        one with the fewest effective degrees of freedom (:func:`effective_dof`, fitted on
        all samples) among those scored within ``margin``, or :data:`CV_RESOLUTION`, of the
        best; recorded in ``dof``. Counts within :data:`DOF_RESOLUTION` of the fewest
        are ties, settled toward no residual, then the larger kernel penalty, then the
        longer length scale: a residual of long length scale and large penalty adds
        nothing to a trend of many degrees of freedom, yet round-off can rank it below
        the trend alone.

        A length scale and a penalty trade against each other, so neither orders the
        residuals by itself (``docs/design/cv_selection.md``).
        """
        scores = self.scores
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
                    A, Kcc = np.hstack([cv.F, _kernel(cv.Z, cv.C, ell, cv.pinned)]), _gaussian(
                        cv.C, cv.C, ell)
                designs[where] = (_FoldGrams(A, cv.u, cv.demo, one_fold, n,
                                             free=cv.trend.free), Kcc)
            grams, Kcc = designs[where]
            P = _trend_penalty(n, t) if Kcc is None else _penalty(n, t, k, Kcc)
            G, _, m = grams.profiled_all(o)
            self.dof[key] = effective_dof(G / m, P)
        fewest = min(self.dof[key] for key in within)
        simplest = [key for key in within if self.dof[key] <= fewest + DOF_RESOLUTION]
        return max(simplest, key=lambda key: (_simpler_residual(key), -scores[key]))

    def record(self, keys: list[tuple], scores: list[tuple[float, float]]) -> None:
        """Store the CV score and standard error of every candidate ``keys[i]``."""
        for key, (score, error) in zip(keys, scores, strict=True):
            self.scores[key], self.standard_errors[key] = score, error


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
