"""Features of the trend-kernel model: the quadratic trend's, the Gaussian kernel's and the
single-index trend's design, in standardised units (see :mod:`.model`)."""

from __future__ import annotations

import functools
import math

import numpy as np

from policy_align_ros.learning.regressors.trend_kernel import single_index

__all__ = ["quadratic_features"]


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
    """``exp(-||z_i - c_j||^2 / (2 ell^2))`` (m, m_c), in one buffer: the search evaluates
    it for every length scale and fold model, and temporaries of its size cost more than
    the arithmetic (the operations and their order are those of the textbook formula)."""
    Z, C = np.asarray(Z, dtype=float), np.asarray(C, dtype=float)  # in place needs doubles
    out = 2.0 * Z @ C.T
    np.negative(out, out=out)
    out += np.einsum("ij,ij->i", Z, Z)[:, None]
    out += np.einsum("ij,ij->i", C, C)[None, :]
    np.maximum(out, 0.0, out=out)
    out *= -0.5
    out /= ell**2
    return np.exp(out, out=out)


def _kernel(Z: np.ndarray, C: np.ndarray, ell: float, pinned: bool,
            gaussian: np.ndarray | None = None) -> np.ndarray:
    """Kernel features (m, m_c) of the residual; ``pinned``: flat at the origin.
    ``gaussian``: :func:`_gaussian` of the same arguments, if known (used as the buffer).

    A pinned feature is ``k_j(z) - e(z) (z' c_j) k_j(0) / ell^2`` with the envelope
    ``e(z) = exp(-||z||^2 / (2 ell^2))``: its gradient at ``z = 0`` (the demonstrated goal
    in the goal-centred standardisation) is zero, so no residual moves the trend's
    stationary point, and away from the goal it is the Gaussian's.
    """
    Z, C = np.asarray(Z, dtype=float), np.asarray(C, dtype=float)  # in place needs doubles
    K = _gaussian(Z, C, ell) if gaussian is None else gaussian
    if not pinned:
        return K
    envelope = np.exp(-0.5 * np.einsum("ij,ij->i", Z, Z) / ell**2)
    at_goal = np.exp(-0.5 * np.einsum("ij,ij->i", C, C) / ell**2)
    pin = Z @ C.T  # (m, m_c), in place as in _gaussian
    np.multiply(envelope[:, None], pin, out=pin)
    pin *= (at_goal / ell**2)[None, :]
    K -= pin
    return K


def _kernel_gradient(Z: np.ndarray, C: np.ndarray, ell: float, alpha: np.ndarray,
                     pinned: bool, gaussian: np.ndarray | None = None) -> np.ndarray:
    """Gradient (m, n) of ``_kernel(Z, C, ell, pinned) @ alpha`` with respect to ``Z``;
    ``gaussian`` as in :func:`_kernel`."""
    ell2 = ell**2
    Kw = _gaussian(Z, C, ell) if gaussian is None else gaussian
    Kw *= alpha
    g = (Kw @ C - Kw.sum(axis=1)[:, None] * Z) / ell2
    if pinned:
        envelope = np.exp(-0.5 * np.einsum("ij,ij->i", Z, Z) / ell2)
        beta = alpha * np.exp(-0.5 * np.einsum("ij,ij->i", C, C) / ell2) / ell2
        s = beta @ C  # sum_j beta_j c_j: the pinned terms are -e(z) z's
        g -= envelope[:, None] * (s[None, :] - Z * ((Z @ s) / ell2)[:, None])
    return g


def _kernel_value_gradient(Z: np.ndarray, C: np.ndarray, ell: float, alpha: np.ndarray,
                           pinned: bool) -> tuple[np.ndarray, np.ndarray]:
    """``_kernel(Z, C, ell, pinned) @ alpha`` (m,) and :func:`_kernel_gradient` (m, n) from
    one Gaussian block: a descent needs both at every step, and the block is most of
    either's cost. The two functions run on it, so the results are the same to the last
    bit."""
    Z, C = np.asarray(Z, dtype=float), np.asarray(C, dtype=float)
    block = _gaussian(Z, C, ell)
    # Both work in the block's buffer: the value first, on a copy where it is changed.
    value = _kernel(Z, C, ell, pinned, block.copy() if pinned else block) @ alpha
    return value, _kernel_gradient(Z, C, ell, alpha, pinned, block)


def _trend_jacobian(Z: np.ndarray, pinned: bool) -> np.ndarray:
    """Gradients (m, n, p_t) of the :func:`quadratic_features` at ``Z`` (m, n) with respect
    to ``z``; ``pinned``: the linear features are zero (the goal-centred trend)."""
    m, n = Z.shape
    iu, ju, scale = _upper(n)
    J = np.zeros((m, n, _n_trend(n)))
    if not pinned:
        J[:, np.arange(n), 1 + np.arange(n)] = 1.0
    J[:, :, 1 + n] = Z
    cols = 2 + n + np.arange(len(iu))
    J[:, iu, cols] += Z[:, ju] * scale
    J[:, ju, cols] += Z[:, iu] * scale
    return J


def _kernel_jacobian(Z: np.ndarray, C: np.ndarray, ell: float, pinned: bool) -> np.ndarray:
    """Gradients (m, n, m_c) of :func:`_kernel` features with respect to ``z``."""
    ell2 = ell**2
    K = _gaussian(Z, C, ell)
    J = K[:, None, :] * (C.T[None, :, :] - Z[:, :, None]) / ell2
    if pinned:
        envelope = np.exp(-0.5 * np.einsum("ij,ij->i", Z, Z) / ell2)
        at_goal = np.exp(-0.5 * np.einsum("ij,ij->i", C, C) / ell2) / ell2
        J -= (envelope[:, None, None] * at_goal[None, None, :]
              * (C.T[None, :, :] - Z[:, :, None] * (Z @ C.T)[:, None, :] / ell2))
    return J


def _kernel_directions(bases: np.ndarray, Z: np.ndarray, C: np.ndarray, ell: float,
                       pinned: bool) -> np.ndarray:
    """Direction rows (m, n - 1, m_c) of the :func:`_kernel` features: ``bases``
    (m, n - 1, n) applied to their gradients (:func:`_kernel_jacobian`), without forming
    the gradients.

    The gradient of feature ``j`` at ``z`` is ``a_j(z) c_j - b_j(z) z`` with scalars
    ``a_j = k_j / l^2 - e k_j(0) / l^2`` and ``b_j = k_j / l^2 - e k_j(0) (z' c_j) / l^4``
    (the terms with ``e`` for a pinned feature only), so a basis ``B`` maps it to
    ``a_j B c_j - b_j B z``: two products instead of one per coordinate.
    """
    ell2 = ell**2
    # In place as in _gaussian: each (m, m_c) temporary costs more than its arithmetic.
    a = _gaussian(Z, C, ell)
    a /= ell2
    b = a
    if pinned:
        envelope = np.exp(-0.5 * np.einsum("ij,ij->i", Z, Z) / ell2)
        at_goal = np.exp(-0.5 * np.einsum("ij,ij->i", C, C) / ell2) / ell2
        pinned_terms = envelope[:, None] * at_goal[None, :]
        b = Z @ C.T
        b *= pinned_terms
        b /= ell2
        np.subtract(a, b, out=b)
        a -= pinned_terms
    out = bases @ C.T  # (m, n - 1, m_c): the largest array here
    out *= a[:, None, :]
    Bz = np.einsum("mij,mj->mi", bases, Z)
    for i in range(out.shape[1]):  # one (m, m_c) temporary per row, not all at once
        out[:, i, :] -= Bz[:, i, None] * b
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


def _trend_hessian(w: np.ndarray, n: int) -> np.ndarray:
    """Hessian ``p I + 2 S`` (n, n) of the quadratic trend whose coefficients lead ``w``."""
    return w[1 + n] * np.eye(n) + 2.0 * _symmetric(w[2 + n:_n_trend(n)], n)


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
