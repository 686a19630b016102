"""The paper's naive baseline (section IV-C): regress the observed velocities directly.

Notation and units: a state ``x`` in ``R^n`` (state units); its velocity ``xdot`` in state
units per second, or per step when trajectories have no times (the paper's ``dt = 1``).
The naive policy ``pi_hat(x)`` is a multi-output regression of ``xdot`` on ``x`` (by
default :class:`LocalLinearRegression`, the LWPR family the paper uses), trained on the
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

from policy_align_ros.learning.base import BaseEstimator, check_is_fitted
from policy_align_ros.learning.baselines.local_linear import LocalLinearRegression
from policy_align_ros.learning.trajectory import Trajectory, as_trajectories

__all__ = ["NaivePolicy", "velocity_samples"]

#: 2: the parameters are the regressor and ``random_state`` (1: the regressor's own seven),
#: and the header names the regressor's class.
_STATE_VERSION = 2


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


class NaivePolicy(BaseEstimator):
    """Naive policy: ``xdot`` regressed directly on ``x`` (paper section IV-C).

    Parameters
    ----------
    regressor : estimator or None
        Multi-output regressor of the velocities on the states (``fit(X, V, groups=...)``,
        ``predict``, ``get_state``/``from_state``, registered under its class name); it
        is fitted on a copy. None: ``LocalLinearRegression(cv_criterion="mse",
        random_state=random_state)``, its width chosen by cross-validation over whole
        held-out trajectories; velocities are values, not a potential known up to an
        offset, so CV scores plain squared errors.
    random_state : int, numpy.random.Generator or None
        Seed of the default regressor.

    Attributes
    ----------
    regressor_ : estimator
        The fitted multi-output regressor.
    n_features_in_ : int
        State dimension ``n``.
    """

    def __init__(self, *, regressor: Any = None,
                 random_state: int | np.random.Generator | None = 0) -> None:
        self.regressor = regressor
        self.random_state = random_state

    def _regressor(self) -> Any:
        if self.regressor is None:
            return LocalLinearRegression(cv_criterion="mse", random_state=self.random_state)
        return type(self.regressor)(**self.regressor.get_params(deep=False))

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
        check_is_fitted(self, "regressor_")
        return self.regressor_.predict(X)

    def get_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Numeric arrays and a JSON-serialisable header that rebuild this model exactly.

        Returns
        -------
        arrays : dict of str to ndarray
            The regressor's arrays.
        meta : dict
            Format version, kind, parameters, the regressor's class and header. A given
            regressor's parameters are those in its header.
        """
        check_is_fitted(self, "regressor_")
        arrays, reg_meta = self.regressor_.get_state()
        random_state = self.random_state
        if isinstance(random_state, np.random.Generator):
            random_state = None  # a file cannot hold its state
        params = {"regressor": None if self.regressor is None else "given",
                  "random_state": random_state}
        meta = {"version": _STATE_VERSION, "kind": "naive", "params": params,
                "regressor_class": type(self.regressor_).__name__}
        return arrays, {**meta, "regressor": reg_meta}

    @classmethod
    def from_state(cls, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> NaivePolicy:
        """Rebuild a fitted model from :meth:`get_state` output (also of format version 1).

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
        # Imported here: the registry imports this package to register its regressor.
        from policy_align_ros.learning.regressors import regressor_class

        reg_cls = regressor_class(meta.get("regressor_class", "LocalLinearRegression"))
        reg = reg_cls.from_state(arrays, meta["regressor"])
        if getattr(reg, "y_ndim_", 2) != 2 or reg.n_outputs_ != reg.n_features_in_:
            raise ValueError("naive policy state: regressor does not map R^n to R^n")
        try:
            params = dict(meta["params"])
            random_state = params.get("random_state")
            model = cls(random_state=random_state)
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"naive policy state: bad parameters ({err})") from None
        if not _is_default(reg, params, version, random_state):
            model.regressor = type(reg)(**reg.get_params(deep=False))
        model.regressor_ = reg
        model.n_features_in_ = reg.n_features_in_
        return model


def _is_default(reg: Any, params: dict[str, Any], version: int, random_state: Any) -> bool:
    """Whether a loaded model's regressor is the default one (``regressor=None``).

    Version 1 headers hold the regressor's parameters instead: the regressor is the
    default when they match the default's.
    """
    if version >= 2:
        return params.get("regressor") is None
    default = LocalLinearRegression(cv_criterion="mse", random_state=random_state)
    return type(reg) is LocalLinearRegression and reg.get_params() == default.get_params()
