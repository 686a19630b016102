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
connected trajectories), so only their shape is data
(``docs/design/alignment_and_outliers.md``, ``docs/design/trend_kernel.md``).

Choosing the hyperparameters
----------------------------
By 10-fold cross-validation over whole demonstrations, each scored by its shape
(:mod:`.cv`).

By default (``trend_form="cv"``) the CV also scores the single-index trend of
:mod:`.single_index` (a rising profile of one fitted quadratic form, for potentials that
flatten or steepen away from the goal), with its index re-fitted without each fold, and
keeps it if it scores lower.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from policy_align_ros.learning.base import BaseEstimator, check_is_fitted
from policy_align_ros.learning.fitting import (
    assign_folds,
    check_finite,
    check_query,
    check_Xy,
    single_blas_thread,
)
from policy_align_ros.learning.regressors.registry import register
from policy_align_ros.learning.regressors.trend_kernel import single_index
from policy_align_ros.learning.regressors.trend_kernel.cv import (
    KERNEL_RIDGE_GRID,
    LENGTH_FACTORS,
    OFFSET_RIDGE_GRID,
    TREND_RIDGE_GRID,
    CVSearch,
    _grid,
)
from policy_align_ros.learning.regressors.trend_kernel.features import (
    _gaussian,
    _index_design,
    _kernel,
    _kernel_directions,
    _kernel_gradient,
    _kernel_value_gradient,
    _median_distance,
    _n_trend,
    _symmetric,
    _trend_jacobian,
    quadratic_features,
)
from policy_align_ros.learning.regressors.trend_kernel.grams import (
    _CVData,
    _FoldGrams,
    along_motion,
    direction_bases,
    direction_rows,
    memo_sums,
)
from policy_align_ros.learning.regressors.trend_kernel.solvers import (
    JITTER,
    _convex_solve,
    _nonneg_solve,
    _penalty,
    _trend_penalty,
)
from policy_align_ros.learning.regressors.trend_kernel.state import (
    TREND_FORMS,
    model_from_state,
    model_state,
)
from policy_align_ros.learning.thinning import thin_trajectories

__all__ = ["CENTRES_PER_DEMONSTRATION", "DIRECTION_WEIGHTS", "MAX_CENTRES", "TREND_FORMS",
           "TrendKernelRegression"]

#: Rows per block when evaluating kernels (bounds memory on large queries).
CHUNK = 8192
#: The direction weights ``direction_weight="auto"`` stands for, largest first: PolicyAlign
#: fits them in turn and keeps the first whose policy takes every demonstration's start to
#: the goal (:func:`~policy_align_ros.learning.anchor.choose_direction_weight`); a fit
#: outside PolicyAlign takes the last. Chosen on the LASA tuning shapes: a decade apart,
#: topped by 3000, from where a larger weight no longer lowers the error
#: (``docs/design/goal_anchor.md``).
DIRECTION_WEIGHTS = (3000.0, 1000.0, 100.0, 10.0)
#: The weight of the rows along the motion (a fit given ``drops``) over the direction
#: weight: chosen on the LASA tuning shapes among 1, 3 and 10 (``docs/design/goal_anchor.md``).
ALONG_WEIGHT = 3.0
#: ``n_centres="auto"``: kernel centres per demonstration, and at most this many in all.
CENTRES_PER_DEMONSTRATION = 25
MAX_CENTRES = 300


@register
class TrendKernelRegression(BaseEstimator):
    """Quadratic trend plus Gaussian-kernel residual with an analytic gradient.

    Parameters
    ----------
    trend_form : "cv", "quadratic" or "single_index"
        The trend: the quadratic (with the residual), or the single-index trend of
        :mod:`.single_index` (a profile of one fitted quadratic form, no residual), or
        ``"cv"`` (default) to choose between them. The single-index trend is only tried
        when the quadratic does not already fit the held-out shapes to
        :data:`~.cv.CV_RESOLUTION`: it suits potentials that flatten or steepen away from
        the goal (velocity-limited or quartic attractors; ``docs/design/single_index.md``).
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
    n_centres : "auto" or int
        Kernel centres (a random subset of the thinned data). ``"auto"``:
        :data:`CENTRES_PER_DEMONSTRATION` per demonstration of ``groups``, at most
        :data:`MAX_CENTRES`. A demonstration adds one path's worth of detail whatever
        its sample rate, and the centres set the cost of every CV solve (cubic in their
        number): six LASA demonstrations fit as well with 150 as with 300, two and a half
        times faster (``docs/design/trend_kernel.md``).
    max_fit_points : int
        Samples kept after thinning in arc length along each demonstration.
    n_folds : int
        Cross-validation folds, each of whole demonstrations (``groups``); at most one
        per demonstration. Ten: with fewer, which demonstrations share a fold can decide
        the fit.
    direction_weight : "auto" or float
        Used only by a fit given a ``goal`` and the samples' ``motion``: how much a slope
        of the potential across a demonstration's motion over one step costs, against an
        error of the same size in its values. ``"auto"``: PolicyAlign chooses among
        :data:`DIRECTION_WEIGHTS` by whether the demonstrations' starts reach the goal; a
        fit outside PolicyAlign takes the smallest, 10.
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
    cv_folds_ : dict or None
        The CV fold of every demonstration id of ``groups`` (None without
        cross-validation, and on a loaded model).
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
    n_centres_ : int
        The centres drawn (``n_centres`` resolved, at most the samples), also for a trend
        without residual; absent on a loaded model.
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
        n_centres: str | int = "auto",
        max_fit_points: int = 6000,
        n_folds: int = 10,
        direction_weight: str | float = "auto",
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
        self.direction_weight = direction_weight
        self.random_state = random_state

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
        w = self.direction_weight
        if w != "auto" and (not isinstance(w, (int, float)) or not 0 <= w < math.inf):
            raise ValueError(f"direction_weight must be 'auto' or a finite float >= 0, got "
                             f"{w!r}")
        c = self.n_centres
        if c != "auto" and (not isinstance(c, (int, np.integer)) or c < 1):
            raise ValueError(f"n_centres must be 'auto' or an int >= 1, got {c!r}")
        for name, low in (("max_fit_points", 10), ("n_folds", 2)):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"{name} must be an int >= {low}, got {value!r}")

    def _direction_weight(self) -> float:
        """The direction weight a fit uses (``"auto"`` outside PolicyAlign: the last, the
        smallest, of :data:`DIRECTION_WEIGHTS`)."""
        w = self.direction_weight
        return DIRECTION_WEIGHTS[-1] if w == "auto" else float(w)

    # -- fit --------------------------------------------------------------------------
    def fit(self, X: np.ndarray, y: np.ndarray, groups: np.ndarray | None = None,
            free_groups: np.ndarray | None = None, goal: np.ndarray | None = None,
            motion: np.ndarray | None = None, scored: bool = True,
            final: bool = True, drops: np.ndarray | None = None,
            min_curvature: float | None = None) -> TrendKernelRegression:
        """Fit on states ``X`` (m, n), outputs ``y`` (m,) and demonstration ids ``groups``.

        Samples of one demonstration must be consecutive and in time order (they are
        thinned in arc length). Without ``groups`` all samples form one demonstration and
        the hyperparameters that are ``"cv"`` fall back to mid-grid values.
        ``free_groups`` (ids in ``groups``) are demonstrations whose offsets are always
        re-fitted freely: ``y`` carries their shape only. ``goal`` (n,), state units:
        where the demonstrations come to rest (:func:`~policy_align_ros.learning.goal.
        demonstrated_goal`); the model is then stationary there: the quadratic trend is
        centred on it and the residual is flat at it (:func:`~.features._kernel`), and the
        single-index trend is not a candidate. ``motion`` (m, n), state units: each
        sample's step along its demonstration; with a ``goal``, the fit then also
        penalises the model's gradient across the motion, ``direction_weight`` times
        (:func:`direction_bases`): the potential's values along bundled
        demonstrations leave its slope across them free, and a demonstration moves
        downhill. ``drops`` (m,), potential units: the change of ``y``'s estimate over
        each sample's step in ``motion``; the fit then also matches the model's slope
        along the motion to it, :data:`ALONG_WEIGHT` times the direction weight
        (:func:`along_motion`): the values say where a demonstration's potential lies,
        the drops how steeply it falls at each sample. ``min_curvature``, output units per
        squared state unit (1/s for potentials of velocities): with a ``goal``, the
        smallest eigenvalue the quadratic trend's Hessian may have, in every candidate of
        the CV and in the final fit (beside the bound relative to its largest,
        :data:`~.solvers.CURVATURE_FLOOR`); kept as ``min_curvature_`` (None without a
        goal), which refits of the model pass on. ``scored=False``:
        a fit of one candidate (every hyperparameter fixed, the quadratic trend) skips its
        CV score, which only a caller comparing scores reads (``cv_best_`` is then None);
        the model fitted is the same. ``final=False``: the reverse, the CV's scores and pick
        (``cv_scores_``, ``cv_standard_errors_``, ``cv_best_``) without the model fitted on
        all data, for a caller that compares scores only (the tracking lag's choice);
        ``predict`` then raises ``NotFittedError``. A single-index pick, whose final fit
        may fall back to the quadratic, is fitted anyway.

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
        self.goal_ = None if goal is None else check_finite("goal", goal, (X.shape[1],))
        if min_curvature is not None and not (math.isfinite(min_curvature)
                                              and min_curvature >= 0.0):
            raise ValueError(f"min_curvature must be a finite float >= 0, got {min_curvature}")
        self.min_curvature_ = (None if goal is None or min_curvature is None
                               else float(min_curvature))
        if motion is not None:
            motion = check_finite("motion", motion, X.shape)
        if drops is not None:
            if motion is None:
                raise ValueError("drops are the potential's changes over the steps in "
                                 "motion: give motion too")
            # Thinned and ordered with the steps, as their last column.
            motion = np.column_stack([motion, check_finite("drops", drops, y.shape)])
        # Hundreds of factorisations of a few hundred unknowns: OpenBLAS's threads cost
        # more than they bring there.
        with single_blas_thread():
            return self._fit(X, y, groups, free, motion, scored, final)

    def _fit(self, X: np.ndarray, y: np.ndarray, groups: np.ndarray, free_groups: np.ndarray,
             motion: np.ndarray | None = None, scored: bool = True,
             final: bool = True) -> TrendKernelRegression:
        rng = np.random.default_rng(self.random_state)
        idx = thin_trajectories(X, groups, self.max_fit_points)
        X, y, groups = X[idx], y[idx], groups[idx]
        use_motion = (motion is not None and self.goal_ is not None
                      and self._direction_weight() > 0)
        motion = motion[idx] if use_motion else None
        m, n = X.shape
        self.n_features_in_ = n
        # Goal-centred: the standardised origin is the goal, where the model is stationary.
        self.mean_ = X.mean(axis=0) if self.goal_ is None else self.goal_.copy()
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
        # The bowl's bound in the standardised units the solves work in.
        self._floor = (0.0 if not self.min_curvature_
                       else self.min_curvature_ * self.scale_**2 / self.y_scale_)

        demo_ids, demo = np.unique(groups, return_inverse=True)
        wanted = (min(MAX_CENTRES, CENTRES_PER_DEMONSTRATION * len(demo_ids))
                  if self.n_centres == "auto" else int(self.n_centres))
        self.n_centres_ = min(wanted, m)
        C = Z[np.sort(rng.choice(m, size=self.n_centres_, replace=False))]
        free = np.isin(demo_ids, free_groups)
        n_folds = min(self.n_folds, len(demo_ids))
        demo_fold = np.zeros(len(demo_ids), dtype=np.int64)
        if n_folds >= 2:
            demo_fold[demo] = assign_folds(groups, n_folds, rng)
            # Samples grouped by fold: every fold's sums come from a slice, not a copy.
            order = np.argsort(demo_fold[demo], kind="stable")
            Z, u, demo = Z[order], u[order], demo[order]
            motion = None if motion is None else motion[order]
        # Kept so that a caller can refit the chosen model on the same training folds.
        self.cv_folds_ = ({int(g): int(f) for g, f in zip(demo_ids, demo_fold, strict=True)}
                          if n_folds >= 2 else None)
        F = quadratic_features(Z)
        pinned = self.goal_ is not None
        if pinned:
            F[:, 1:1 + n] = 0.0  # no linear term: the bowl's centre is the goal
        bases = DF = targets = None
        if motion is not None:
            bases, targets = self._motion_rows(motion)
            DF = direction_rows(bases, _trend_jacobian(Z, pinned))
        lengths, t_grid, k_grid, o_grid, forms = self._grids(C, pinned)
        mid = (lengths[len(lengths) // 2], k_grid[len(k_grid) // 2])
        # Without CV, and as the fallback of a single-index trend whose profile fails to rise.
        search = CVSearch(("quadratic", t_grid[len(t_grid) // 2], *mid, o_grid[-1]))
        self.cv_scores_ = search.scores
        self.cv_standard_errors_ = search.standard_errors
        self.cv_dof_ = search.dof
        self.cv_best_ = None
        single = forms == ["quadratic"] and all(len(g) == 1 for g in (lengths, t_grid, k_grid,
                                                                        o_grid))
        if n_folds < 2 or (single and not scored):
            best = search.quadratic_pick
            if forms == ["single_index"]:
                best = ("single_index", math.nan, mid[0], math.inf, o_grid[-1])
                search.fit_index(_FoldGrams(F, u, demo, demo_fold, n, free=free), Z, u, demo,
                                 t_grid[len(t_grid) // 2], rng)
        else:
            cv = _CVData(F, Z, u, C, demo, demo_fold,
                         _FoldGrams(F, u, demo, demo_fold, n, free=free, D=DF, Dt=targets),
                         pinned, bases, DF, targets, self._floor)
            best = self.cv_best_ = search.run(cv, forms, lengths, t_grid, k_grid, o_grid, rng)
            if math.isnan(best[2]):
                best = (*best[:2], mid[0], *best[3:])
        self._quadratic_pick, self._index = search.quadratic_pick, search.index
        if final or best[0] != "quadratic" or self.cv_best_ is None:
            self._final_fit(best, F, Z, u, C, n, demo, free, bases, targets)
        return self

    def _grids(self, C: np.ndarray, pinned: bool) -> tuple[list, list, list, list, list]:
        """The candidate length scales, trend, kernel and offset penalties and trend forms
        of the search, for centres ``C`` (standardised) and a model pinned at a goal or
        not."""
        d_med = _median_distance(C)
        lengths = _grid(self.length_scale, [f * d_med for f in LENGTH_FACTORS])
        forms = list(TREND_FORMS) if self.trend_form == "cv" else [self.trend_form]
        if pinned:
            forms = ["quadratic"]  # the single-index trend fits a centre of its own
        return (lengths, _grid(self.trend_ridge, TREND_RIDGE_GRID),
                _grid(self.kernel_ridge, KERNEL_RIDGE_GRID),
                _grid(self.offset_ridge, OFFSET_RIDGE_GRID), forms)

    def _motion_rows(self, motion: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The samples' direction bases (m, r, n) and what they observe (m, r; None:
        zero) from ``motion`` (m, n), with the drops as a last column when given."""
        n = self.n_features_in_
        steps = motion[:, :n] / self.scale_
        bases = direction_bases(steps, self._direction_weight())
        if motion.shape[1] == n:
            return bases, None
        return along_motion(steps, motion[:, n] / self.y_scale_, bases,
                            ALONG_WEIGHT * self._direction_weight())

    def _final_fit(self, best: tuple, F: np.ndarray, Z: np.ndarray, u: np.ndarray,
                   C: np.ndarray, n: int, demo: np.ndarray, free: np.ndarray,
                   bases: np.ndarray | None = None, targets: np.ndarray | None = None
                   ) -> None:
        """Fit the hyperparameters ``best`` on all samples and set the learnt attributes;
        ``bases`` (m, r, n): the samples' direction bases, or None, and ``targets`` (m, r)
        what they observe (None: zero)."""
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
        kernel = not math.isinf(self.kernel_ridge_)
        ell, pinned = self.length_scale_, self.goal_ is not None
        if kernel:
            P = _penalty(n, self.trend_ridge_, self.kernel_ridge_, _gaussian(C, C, ell))
            self.centres_ = C
        else:
            P = _trend_penalty(n, self.trend_ridge_)
            self.centres_ = np.zeros((0, n))

        def build() -> _FoldGrams:
            A = np.hstack([F, _kernel(Z, C, ell, pinned)]) if kernel else F
            D = None
            if bases is not None:
                D = direction_rows(bases, _trend_jacobian(Z, True))
                if kernel:
                    D = np.concatenate([D, _kernel_directions(bases, Z, C, ell, True)],
                                       axis=2)
            return _FoldGrams(A, u, demo, np.zeros(demo.max() + 1, dtype=np.int64), n,
                              free=free, D=D, Dt=targets)

        # F follows from Z and the pinning; without a kernel the centres play no part.
        design = ("all", Z, C if kernel else None, ell if kernel else None, pinned, bases,
                  demo)
        grams = memo_sums(design, build, u, targets, free)
        G, r, m = grams.profiled_all(self.offset_ridge_)
        w = _convex_solve(G / m + P, r / m, n, floor=self._floor)
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
    def _standardise(self, X: np.ndarray) -> np.ndarray:
        check_is_fitted(self, "trend_")
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
                u[s:s + CHUNK] += _kernel(Z[s:s + CHUNK], self.centres_, self.length_scale_,
                                          self.goal_ is not None) @ self.alpha_
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
            for s in range(0, len(Z), CHUNK):
                g[s:s + CHUNK] += _kernel_gradient(Z[s:s + CHUNK], self.centres_,
                                                   self.length_scale_, self.alpha_,
                                                   self.goal_ is not None)
        return g * (self.y_scale_ / self.scale_)

    def value_and_gradient(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(predict(X), gradient(X))`` in one evaluation of the kernel block (a descent
        needs both at every step); equal to the two calls to the last bit."""
        if self.trend_form_ == "single_index" or not len(getattr(self, "alpha_", ())):
            return self.predict(X), self.gradient(X)
        Z = self._standardise(X)
        u = (self._c + Z @ self._b + 0.5 * self._p * np.einsum("ij,ij->i", Z, Z)
             + np.einsum("ij,jk,ik->i", Z, self._S, Z))
        g = self._b + self._p * Z + 2.0 * Z @ self._S
        for s in range(0, len(Z), CHUNK):
            value, grad = _kernel_value_gradient(Z[s:s + CHUNK], self.centres_,
                                                 self.length_scale_, self.alpha_,
                                                 self.goal_ is not None)
            u[s:s + CHUNK] += value
            g[s:s + CHUNK] += grad
        return self.y_mean_ + self.y_scale_ * u, g * (self.y_scale_ / self.scale_)

    # -- persistence ------------------------------------------------------------------
    def get_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Numeric arrays and a JSON-able header that rebuild this model exactly
        (:func:`~.state.model_state`)."""
        return model_state(self)

    @classmethod
    def from_state(cls, arrays: dict[str, np.ndarray], meta: dict[str, Any]
                   ) -> TrendKernelRegression:
        """Rebuild a fitted model from :meth:`get_state` output (ValueError if malformed;
        :func:`~.state.model_from_state`)."""
        return model_from_state(cls, arrays, meta)
