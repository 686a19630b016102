"""The estimator :class:`LocalLinearRegression` and its model-file state."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from policy_align_ros.learning.base import BaseEstimator, check_is_fitted
from policy_align_ros.learning.baselines.local_linear.blend import blend
from policy_align_ros.learning.baselines.local_linear.centres import CentreIndex
from policy_align_ros.learning.baselines.local_linear.cv import auto_grid, cross_validate
from policy_align_ros.learning.baselines.local_linear.fields import default_ridge, fit_fields
from policy_align_ros.learning.fitting import check_query, single_blas_thread
from policy_align_ros.learning.thinning import thin_trajectories

__all__ = ["LocalLinearRegression"]


#: Below this many query points a prediction is too small for BLAS threads to matter,
#: and the executor's 1 kHz control step cannot afford even a cheap thread-limit switch.
SMALL_QUERY = 64
#: Largest number of points whose statistics make the final local models (thinned).
MAX_FIT_POINTS = 100_000
#: 2 added the optional arrays ``floors`` and ``softness`` (version 1: linear models);
#: 3 the optional per-field ``widths`` (without them a state has the global width).
_STATE_VERSION = 3
#: Constructor parameters of earlier versions, ignored when a saved state has them, so that
#: older model files still load with their fitted models as they are: ``increment_weight``
#: (derivative equations) and ``smoothing`` (slopes shrunk toward the neighbours' slope),
#: both off by default.
_REMOVED_PARAMS = ("increment_weight", "smoothing")


def _blas_context(n_queries: int) -> contextlib.AbstractContextManager:
    return contextlib.nullcontext() if n_queries < SMALL_QUERY else single_blas_thread()


class LocalLinearRegression(BaseEstimator):
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
    ridge : None or float
        Dimensionless penalty on the local slopes (relative to ``h^2``); it sets slopes to
        zero in directions without local data. ``None`` is ``1e-3 (n / 2)^2``, as the best
        penalty grows with the dimension.
    max_centers : int
        Cap on the number of receptive fields.
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
        "global". Needs ``bandwidth="cv"``; with a fixed width, "cv" means "global".
    random_state : int, numpy.random.Generator or None
        Seeds the subsamples, the folds and the first centre of the cover.

    Attributes
    ----------
    bandwidth_ : float
        Width used (state units).
    ridge_ : float
        Slope penalty used.
    cv_scores_ : dict of float to float, or None
        Mean held-out error (outputs scaled to unit variance) per evaluated width;
        None without cross-validation.
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
        ridge: float | None = None,
        max_centers: int = 3000,
        cv_criterion: str = "increments",
        extrapolation: str = "auto",
        widths: str = "cv",
        random_state: int | np.random.Generator | None = 0,
    ) -> None:
        self.bandwidth = bandwidth
        self.bandwidth_grid = bandwidth_grid
        self.n_folds = n_folds
        self.ridge = ridge
        self.max_centers = max_centers
        self.cv_criterion = cv_criterion
        self.extrapolation = extrapolation
        self.widths = widths
        self.random_state = random_state

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
        if rg is not None and not (
            isinstance(rg, (int, float, np.floating)) and math.isfinite(rg) and rg >= 0
        ):
            raise ValueError(f"ridge must be None or a float >= 0, got {rg!r}")
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

        ridge = default_ridge(X.shape[1]) if self.ridge is None else float(self.ridge)
        if self.bandwidth == "cv":
            if self.bandwidth_grid is None:
                grid = auto_grid(Xs)
            else:
                grid = np.sort(np.asarray(self.bandwidth_grid, dtype=float))
            h, scores, self.adaptive_ = cross_validate(
                Xs, Y, g, grid, ridge, rng, n_folds=self.n_folds,
                max_centers=int(self.max_centers),
                increments=self.cv_criterion == "increments", widths=self.widths,
            )
        else:
            h, scores = float(self.bandwidth), None
            self.adaptive_ = self.widths == "adaptive"
        # Consecutive samples of a trajectory are nearly duplicates at the scale of h:
        # beyond MAX_FIT_POINTS, thinning them changes the local statistics little.
        groups = np.zeros(m, dtype=int) if g is None else g
        keep = thin_trajectories(None, groups, MAX_FIT_POINTS, rule="stride", rng=rng)
        # A scalar output is taken for a potential, which is descended: floors stop the
        # descent where the data end (package docstring).
        floored_models = self.extrapolation == "floor" or (
            self.extrapolation == "auto" and Y.shape[1] == 1
        )
        centres, intercepts, slopes, floors, softness, widths = fit_fields(
            Xs[keep], Y[keep], h, ridge, int(self.max_centers), rng, floored_models,
            self.adaptive_,
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

    # -- prediction

    def _check_X(self, X: np.ndarray) -> np.ndarray:
        check_is_fitted(self, "centers_")
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
        check_is_fitted(self, "centers_")
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
