"""The paper's naive baseline (section IV-C): regress the observed velocities directly.

Notation and units: a state ``x`` in ``R^n`` (state units); its velocity ``xdot`` in state
units per second, or per step when trajectories have no times (the paper's ``dt = 1``).
The naive policy ``pi_hat(x)`` is a multi-output regression of ``xdot`` on ``x`` with the
same regressor family as PolicyAlign (:class:`LocalLinearRegression`), trained on the
tuples ``(x_i, xdot_i)``. It therefore learns the *constrained* motion ``N pi`` averaged
over the constraints seen, not the unconstrained policy ``pi``; the comparison in the
paper's Table II shows the difference.

Velocities come from a trajectory's ``velocities`` when given; otherwise from forward
differences ``(x_{i+1} - x_i) / dt_i`` assigned to ``x_i``, the last sample dropped.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from policy_align_ros.learning.regressors import LocalLinearRegression, NotFittedError
from policy_align_ros.learning.trajectory import Trajectory, as_trajectories

__all__ = ["NaivePolicy", "velocity_samples"]

_STATE_VERSION = 1


def velocity_samples(
    trajectories: Sequence[Trajectory],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Training tuples ``(x_i, xdot_i)`` and the trajectory id of each.

    Parameters
    ----------
    trajectories : sequence of Trajectory
        Validated demonstrations of one dimension ``n``.

    Returns
    -------
    X : ndarray, shape (m, n)
        States (state units).
    V : ndarray, shape (m, n)
        Velocities (state units per second, or per step without times).
    groups : ndarray of int, shape (m,)
        Index of the trajectory of each sample.
    """
    xs, vs, gs = [], [], []
    for k, traj in enumerate(trajectories):
        if traj.velocities is not None:
            x, v = traj.positions, traj.velocities
        else:
            x = traj.positions[:-1]
            v = np.diff(traj.positions, axis=0) / traj.dt[:, None]
        xs.append(x)
        vs.append(v)
        gs.append(np.full(len(x), k))
    return np.vstack(xs), np.vstack(vs), np.concatenate(gs)


class NaivePolicy:
    """Naive policy: ``xdot`` regressed directly on ``x`` (paper section IV-C).

    Parameters
    ----------
    bandwidth, bandwidth_grid, n_folds, ridge, max_centers, smoothing, random_state
        Passed to :class:`LocalLinearRegression` (multi-output); the width is chosen by
        cross-validation over whole held-out trajectories by default.

    Attributes
    ----------
    regressor_ : LocalLinearRegression
        The fitted multi-output regressor.
    n_features_in_ : int
        State dimension ``n``.
    """

    def __init__(
        self,
        *,
        bandwidth: str | float = "cv",
        bandwidth_grid: Sequence[float] | None = None,
        n_folds: int = 5,
        ridge: float | None = None,
        max_centers: int | None = None,
        smoothing: float | None = None,
        random_state: int | np.random.Generator | None = None,
    ) -> None:
        self.bandwidth = bandwidth
        self.bandwidth_grid = bandwidth_grid
        self.n_folds = n_folds
        self.ridge = ridge
        self.max_centers = max_centers
        self.smoothing = smoothing
        self.random_state = random_state

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Constructor parameters, as given."""
        return {
            "bandwidth": self.bandwidth,
            "bandwidth_grid": self.bandwidth_grid,
            "n_folds": self.n_folds,
            "ridge": self.ridge,
            "max_centers": self.max_centers,
            "smoothing": self.smoothing,
            "random_state": self.random_state,
        }

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"NaivePolicy({args})"

    def _regressor(self) -> LocalLinearRegression:
        # None keeps the regressor's own default, so the two stay in step. Velocities are
        # values, not a potential up to an offset: CV scores plain squared errors.
        params = {k: v for k, v in self.get_params().items() if v is not None}
        return LocalLinearRegression(cv_criterion="mse", **params)

    def fit(self, trajectories: Sequence[Trajectory | np.ndarray]) -> NaivePolicy:
        """Fit on demonstrations.

        Parameters
        ----------
        trajectories : sequence of Trajectory or array_like of shape (N_k, n)
            Plain arrays are positions with ``dt = 1``.

        Returns
        -------
        self

        Raises
        ------
        ValueError
            On invalid trajectories (naming the index) or fewer than 2 velocity samples.
        """
        trajs = as_trajectories(trajectories)
        X, V, groups = velocity_samples(trajs)
        if len(X) < 2:
            raise ValueError(f"need at least 2 velocity samples, got {len(X)}")
        self.regressor_ = self._regressor().fit(X, V, groups=groups)
        self.n_features_in_ = X.shape[1]
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "regressor_"):
            raise NotFittedError("this NaivePolicy is not fitted yet: call fit() or from_state()")

    def policy(self, X: np.ndarray) -> np.ndarray:
        """Predicted velocity ``pi_hat(x)``.

        Parameters
        ----------
        X : array_like, shape (m, n)
            States (state units).

        Returns
        -------
        ndarray, shape (m, n)
            State units per second (per step without times).
        """
        self._check_fitted()
        return self.regressor_.predict(X)

    def get_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Numeric arrays and a JSON-serialisable header that rebuild this model exactly.

        Returns
        -------
        arrays : dict of str to ndarray
            The regressor's arrays.
        meta : dict
            Format version, kind and the regressor's header.
        """
        self._check_fitted()
        arrays, reg_meta = self.regressor_.get_state()
        params = self.get_params()
        if isinstance(params["random_state"], np.random.Generator):
            params["random_state"] = None
        if params["bandwidth_grid"] is not None:
            params["bandwidth_grid"] = [float(v) for v in params["bandwidth_grid"]]
        meta = {"version": _STATE_VERSION, "kind": "naive", "params": params}
        return arrays, {**meta, "regressor": reg_meta}

    @classmethod
    def from_state(cls, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> NaivePolicy:
        """Rebuild a fitted model from :meth:`get_state` output.

        Raises
        ------
        ValueError
            On a header of another kind, a newer version, or a bad regressor state.
        """
        if not isinstance(meta, dict) or meta.get("kind") != "naive":
            raise ValueError("naive policy state: header is not of kind 'naive'")
        version = meta.get("version")
        if not isinstance(version, int) or version > _STATE_VERSION:
            raise ValueError(
                f"naive policy state: unsupported format version {version!r} "
                f"(supported: {_STATE_VERSION})"
            )
        if not isinstance(meta.get("regressor"), dict):
            raise ValueError("naive policy state: missing regressor header")
        reg = LocalLinearRegression.from_state(arrays, meta["regressor"])
        if reg.y_ndim_ != 2 or reg.n_outputs_ != reg.n_features_in_:
            raise ValueError("naive policy state: regressor does not map R^n to R^n")
        try:
            model = cls(**meta["params"])
        except (KeyError, TypeError) as err:
            raise ValueError(f"naive policy state: bad parameters ({err})") from None
        model.regressor_ = reg
        model.n_features_in_ = reg.n_features_in_
        return model
