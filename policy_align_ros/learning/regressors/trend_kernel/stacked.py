"""The gradients of several fitted trend-kernel models in one evaluation.

A fit's checks run the policy of every CV fold model from the starts it was fitted
without (:func:`~policy_align_ros.learning.folds.heldout_reach`): a few points per model,
hundreds of Euler steps. One ``gradient`` call per model and step costs far more in call
overhead than in arithmetic, so :func:`stacked_gradient` evaluates every model's gradient
at its own points at once, as one masked kernel block over all the models' centres. The
maths is :meth:`~.model.TrendKernelRegression.gradient`'s; the sums run in another order,
so the values agree to round-off (``test/learning/regressors/test_trend_kernel.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from policy_align_ros.learning.regressors.trend_kernel.model import TrendKernelRegression

__all__ = ["stacked_gradient"]


def stacked_gradient(models: Sequence) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
    """``g(X, owner)``: the gradient (m, n) of ``models[owner[i]]`` at ``X[i]`` (m, n),
    state units in and out, for fitted quadratic-trend
    :class:`~.model.TrendKernelRegression` models of one state dimension and pinning;
    None for anything else (the caller then asks each model)."""
    if not models or not all(isinstance(m, TrendKernelRegression)
                             and getattr(m, "trend_form_", None) == "quadratic"
                             for m in models):
        return None
    n = models[0].n_features_in_
    pinned = {m.goal_ is not None for m in models}
    if len(pinned) > 1 or any(m.n_features_in_ != n for m in models):
        return None
    pinned = pinned.pop()
    mean = np.stack([m.mean_ for m in models])                       # (K, n)
    scale = np.array([m.scale_ for m in models])                     # (K,)
    b = np.stack([m._b for m in models])                             # (K, n)
    p = np.array([m._p for m in models])                             # (K,)
    S = np.stack([m._S for m in models])                             # (K, n, n)
    out_scale = np.array([m.y_scale_ / m.scale_ for m in models])    # (K,)
    C = np.concatenate([m.centres_ for m in models])                 # (M, n)
    alpha = np.concatenate([m.alpha_ for m in models])               # (M,)
    block = np.repeat(np.arange(len(models)), [len(m.alpha_) for m in models])
    ell2 = np.array([m.length_scale_ ** 2 for m in models])          # (K,)
    c2 = np.einsum("ij,ij->i", C, C)
    # Per centre, the pinned term's weight (alpha_j k_j(0) / l^2, as _kernel_gradient).
    beta = alpha * np.exp(-0.5 * c2 / ell2[block]) / ell2[block] if pinned else None

    def gradient(X: np.ndarray, owner: np.ndarray) -> np.ndarray:
        Z = (X - mean[owner]) / scale[owner, None]
        g = b[owner] + p[owner, None] * Z + 2.0 * np.einsum("mj,mjk->mk", Z, S[owner])
        if len(alpha):
            l2 = ell2[owner]
            sq = np.einsum("ij,ij->i", Z, Z)[:, None] - 2.0 * Z @ C.T + c2[None, :]
            mine = block[None, :] == owner[:, None]
            Kw = np.where(mine, np.exp(-0.5 * np.maximum(sq, 0.0) / l2[:, None]), 0.0) * alpha
            g += (Kw @ C - Kw.sum(axis=1)[:, None] * Z) / l2[:, None]
            if pinned:
                envelope = np.exp(-0.5 * np.einsum("ij,ij->i", Z, Z) / l2)
                s = np.where(mine, beta[None, :], 0.0) @ C
                g -= envelope[:, None] * (s - Z * (np.einsum("ij,ij->i", Z, s) / l2)[:, None])
        return g * out_scale[owner, None]

    return gradient
