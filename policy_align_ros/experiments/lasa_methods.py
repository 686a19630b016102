"""The methods the LASA benchmark compares, each an adapter ``fit(trajs) -> policy``.

A policy maps states ``X`` (m, 2) in mm to velocities (m, 2) in mm/s. The methods:

- ``policy_align``: :class:`PolicyAlign` with its defaults (``--set NAME=VALUE`` changes
  PolicyAlign's or its TrendKernelRegression's parameters);
- ``naive``: :class:`NaivePolicy` ``(random_state=0)``, velocities regressed on positions;
- ``gmr``: Gaussian mixture regression, a ``gmr.GMM`` of 8 components (seed 0) fitted on
  the joint samples ``(x, xdot)`` (forward differences of the training trajectories) and
  conditioned on ``x``;
- ``grad_field``: the least-squares gradient field, ``xdot = -grad phi(x)`` with
  ``phi(x) = x'Ax/2 + b'x + sum_j w_j exp(-|x - c_j|^2 / (2 l^2))`` fitted to the
  velocities by ridge least squares (see :func:`fit_gradient_field` for its fixed rule).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from policy_align_ros.learning import NaivePolicy, PolicyAlign, Trajectory
from policy_align_ros.learning.baselines.naive import velocity_samples
from policy_align_ros.learning.regressors import TrendKernelRegression

__all__ = ["METHODS", "METHOD_LABELS", "fit_method", "fit_gradient_field", "GmrField",
           "parse_policy_settings", "GRAD_FIELD_CENTRES", "GRAD_FIELD_WIDTH",
           "GRAD_FIELD_RIDGE", "GMR_COMPONENTS"]

Policy = Callable[[np.ndarray], np.ndarray]

METHODS = ("policy_align", "naive", "gmr", "grad_field")
METHOD_LABELS = {"policy_align": "`PolicyAlign()`", "naive": "`NaivePolicy`",
                 "gmr": "GMM-GMR, 8 components", "grad_field": "LSQ gradient field"}
GMR_COMPONENTS = 8
#: Gradient field: at most this many RBF centres, evenly spaced along the training samples.
GRAD_FIELD_CENTRES = 50
#: Gradient field: RBF length scale as a fraction of the training data's W.
GRAD_FIELD_WIDTH = 0.1
#: Gradient field: ridge on the RBF weights relative to the mean diagonal of the Gram.
GRAD_FIELD_RIDGE = 1e-3


def parse_policy_settings(items: Sequence[str]) -> dict[str, Any]:
    """``["integration=euler", "offset_ridge=inf", ...]`` as PolicyAlign keyword arguments.

    A name of PolicyAlign's constructor sets that argument; a name of
    TrendKernelRegression's (as in ``bench suite --set``) sets the default regressor's.
    Values are numbers when they parse as one, else strings.
    """
    from policy_align_ros.experiments.suite import parse_settings

    own = set(PolicyAlign().get_params()) - {"regressor", "random_state", "verbose"}
    regressor_names = set(TrendKernelRegression().get_params()) - {"random_state"}
    kwargs: dict[str, Any] = {}
    regressor_items = []
    for item in items:
        name, sep, value = item.partition("=")
        if sep and name in own:
            try:
                kwargs[name] = float(value)
            except ValueError:
                kwargs[name] = value
            if name == "max_neighbours":
                kwargs[name] = int(kwargs[name])
        elif sep and name in regressor_names:
            regressor_items.append(item)
        else:
            raise ValueError(f"--set {item!r}: expected NAME=VALUE with NAME one of "
                             f"{sorted(own | regressor_names)}")
    regressor = parse_settings(regressor_items)
    if regressor:
        kwargs["regressor"] = regressor
    return kwargs


def _policy_align(trajs: list[Trajectory], settings: dict[str, Any]) -> Policy:
    kwargs = dict(settings)
    if "regressor" in kwargs:
        kwargs["regressor"] = TrendKernelRegression(random_state=0, **kwargs["regressor"])
    model = PolicyAlign(random_state=0, **kwargs).fit(trajs)
    return model.policy


def _naive(trajs: list[Trajectory], settings: dict[str, Any]) -> Policy:
    return NaivePolicy(random_state=0).fit(trajs).policy


class GmrField:
    """Gaussian mixture regression ``E[xdot | x]`` of a joint GMM over ``(x, xdot)``.

    The conditional of each component is precomputed once, so one call costs a few small
    matrix products (``gmr.GMM.predict`` re-conditions on every call, too slow for the
    thousands of Euler steps of a rollout); the result equals ``gmm.predict``.

    Parameters
    ----------
    priors : ndarray, shape (K,)
    means : ndarray, shape (K, 2 d)
        ``(x, xdot)`` means (mm, mm/s).
    covariances : ndarray, shape (K, 2 d, 2 d)
    """

    def __init__(self, priors: np.ndarray, means: np.ndarray, covariances: np.ndarray):
        d = means.shape[1] // 2
        self.log_priors = np.log(np.maximum(priors, 1e-300))
        self.mu_x, self.mu_v = means[:, :d], means[:, d:]
        sxx = covariances[:, :d, :d]
        svx = covariances[:, d:, :d]
        self.sxx_inv = np.linalg.inv(sxx)
        self.gain = svx @ self.sxx_inv                       # (K, d, d)
        self.log_norm = -0.5 * (np.linalg.slogdet(sxx)[1] + d * np.log(2 * np.pi))

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """Velocities (m, d) at states ``X`` (m, d)."""
        diff = np.asarray(X, float)[:, None, :] - self.mu_x[None]            # (m, K, d)
        maha = np.einsum("mki,kij,mkj->mk", diff, self.sxx_inv, diff)
        logw = self.log_priors + self.log_norm - 0.5 * maha
        w = np.exp(logw - logw.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        cond = self.mu_v[None] + np.einsum("kij,mkj->mki", self.gain, diff)  # (m, K, d)
        return np.einsum("mk,mki->mi", w, cond)


def _gmr(trajs: list[Trajectory], settings: dict[str, Any]) -> Policy:
    from gmr import GMM

    X, V, _ = velocity_samples(trajs)
    gmm = GMM(n_components=GMR_COMPONENTS, random_state=0).from_samples(np.hstack([X, V]))
    return GmrField(gmm.priors, gmm.means, gmm.covariances)


def _field_design(X: np.ndarray, centres: np.ndarray, length: float) -> np.ndarray:
    """Rows of ``-grad phi`` as a linear map of the parameters ``(a11, a12, a22, b1, b2,
    w_1..w_J)``: shape (2 m, 5 + J), x-components first then y-components."""
    x, y = X[:, 0], X[:, 1]
    zeros, ones = np.zeros_like(x), np.ones_like(x)
    diff = X[:, None, :] - centres[None]                                     # (m, J, 2)
    k = np.exp(-np.sum(diff**2, axis=2) / (2 * length**2))                   # (m, J)
    # -d/dx of w exp(-r^2/(2 l^2)) = w k (x - c) / l^2
    rbf_x, rbf_y = k * diff[:, :, 0] / length**2, k * diff[:, :, 1] / length**2
    quad_x = np.stack([-x, -y, zeros, -ones, zeros], axis=1)
    quad_y = np.stack([zeros, -x, -y, zeros, -ones], axis=1)
    return np.vstack([np.hstack([quad_x, rbf_x]), np.hstack([quad_y, rbf_y])])


def fit_gradient_field(X: np.ndarray, V: np.ndarray, *, n_centres: int = GRAD_FIELD_CENTRES,
                       width: float = GRAD_FIELD_WIDTH, ridge: float = GRAD_FIELD_RIDGE
                       ) -> Policy:
    """Least-squares gradient field fitted to velocities, by a fixed rule.

    Centres: ``n_centres`` training samples evenly spaced in the stacked sample order (all
    if fewer). Length scale ``l = width * W`` with ``W`` the largest side of the training
    samples' bounding box. Ridge ``ridge`` times the mean diagonal of the RBF columns'
    Gram, on the RBF weights only (the quadratic is free). The bench's rule
    (the defaults) is fixed a priori; no LASA score chose it.

    Parameters
    ----------
    X : ndarray, shape (m, 2)
        Positions (mm).
    V : ndarray, shape (m, 2)
        Velocities (mm/s).
    n_centres, width, ridge : int, float, float
        The rule's constants (defaults: ``GRAD_FIELD_CENTRES``, ``GRAD_FIELD_WIDTH``,
        ``GRAD_FIELD_RIDGE``).

    Returns
    -------
    callable
        ``policy(X) -> (m, 2)`` velocities (mm/s).
    """
    X, V = np.asarray(X, float), np.asarray(V, float)
    if X.ndim != 2 or X.shape[1] != 2 or V.shape != X.shape:
        raise ValueError(f"X {X.shape} and V {V.shape}: must be equal (m, 2) arrays")
    pick = np.unique(np.linspace(0, len(X) - 1, min(n_centres, len(X))).astype(int))
    centres = X[pick]
    length = width * max(float(np.max(X.max(axis=0) - X.min(axis=0))), 1e-12)
    G = _field_design(X, centres, length)
    y = np.concatenate([V[:, 0], V[:, 1]])
    gram = G.T @ G
    penalty = np.zeros(G.shape[1])
    penalty[5:] = ridge * np.mean(np.diag(gram)[5:])
    theta = np.linalg.solve(gram + np.diag(penalty) + 1e-12 * np.eye(len(penalty)), G.T @ y)

    def policy(Q: np.ndarray) -> np.ndarray:
        Q = np.asarray(Q, float)
        out = _field_design(Q, centres, length) @ theta
        return np.stack([out[:len(Q)], out[len(Q):]], axis=1)

    return policy


def _grad_field(trajs: list[Trajectory], settings: dict[str, Any]) -> Policy:
    X, V, _ = velocity_samples(trajs)
    return fit_gradient_field(X, V)


_FITTERS = {"policy_align": _policy_align, "naive": _naive, "gmr": _gmr,
            "grad_field": _grad_field}


def fit_method(name: str, trajs: list[Trajectory],
               settings: dict[str, Any] | None = None) -> Policy:
    """Fit method ``name`` (one of :data:`METHODS`) on ``trajs``; its policy.

    ``settings`` are PolicyAlign keyword arguments (:func:`parse_policy_settings`); the
    other methods ignore them.
    """
    if name not in _FITTERS:
        raise ValueError(f"method {name!r}: unknown; known: {list(METHODS)}")
    return _FITTERS[name](list(trajs), dict(settings or {}))
