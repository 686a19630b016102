"""Prediction of the local-linear regression: the normalised blend of the local models and
its exact gradient, with floored local models where a potential's data end.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from policy_align_ros.learning.baselines.local_linear.centres import CentreIndex

__all__ = ["blend", "floored"]

#: fraction of the spread of its values on its data (see :func:`extrapolation_floors`).
FLOOR_SOFTNESS = 0.02


def floored(
    u: np.ndarray, floor: np.ndarray, softness: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Linear above a floor, smoothly levelling off below it, and its derivative.

    ``phi(u) = u`` for ``u >= a``, ``a - w (1 - exp((u - a) / w))`` below: continuous with
    its derivative at ``a``, decreasing by at most ``w`` past it, with a slope that decays
    over ``w``. ``a = -inf`` leaves ``u`` linear.

    Parameters
    ----------
    u : ndarray
        Local model increments ``B_j (x - c_j)`` (output units).
    floor, softness : ndarray, broadcastable to ``u``
        ``a`` and ``w > 0`` (output units).

    Returns
    -------
    phi, dphi_du : ndarray, shape of ``u``
    """
    z = np.minimum((u - floor) / softness, 0.0)
    e = np.exp(z)
    below = z < 0.0
    return np.where(below, floor + softness * (e - 1.0), u), e


def blend(
    X: np.ndarray,
    index: CentreIndex,
    intercepts: np.ndarray,
    slopes: np.ndarray,
    h: float,
    gradient: bool = False,
    floors: np.ndarray | None = None,
    softness: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Normalised blend of the local models and its exact gradient.

    Parameters
    ----------
    X : ndarray, shape (m, n)
        Query states (state units, same origin as the centres).
    index : CentreIndex
        The field centres, shape (C, n).
    intercepts : ndarray, shape (C, d)
        Local model values at their centres.
    slopes : ndarray, shape (C, d, n)
        Local model slopes.
    h : float or ndarray, shape (C,)
        Field width, common or per field (state units).
    gradient : bool
        Also return ``d f / d x``.
    floors, softness : ndarray, shape (C, d), optional
        Floors of the local models (:func:`floored`); None keeps them linear.

    Returns
    -------
    f : ndarray, shape (m, d)
        Prediction.
    grad : ndarray, shape (m, d, n), or None
        Exact gradient of ``f`` (output units per state unit) when requested.
    """
    m, n = X.shape
    d = intercepts.shape[1]
    # l_j(x) = a_j + B_j x, with the centre folded into the offset.
    offsets = intercepts - np.einsum("cdn,cn->cd", slopes, index.centres)
    floor = None if floors is None else (floors, softness)
    f = np.empty((m, d))
    grad = np.empty((m, d, n)) if gradient else None
    # With v_j = g(rel_j; H^2(t)), rel_j = ||x - c_j||^2 - t and t = ||x - c_*||^2:
    #   d rel_j/dx = 2 (c_* - c_j),   d H^2/dx = H^2'(t) 2 (x - c_*),
    #   grad f = [sum_j v_j B_j + sum_j (l_j - f) grad v_j] / sum_j v_j;
    # a floored model l_j = b_j + phi_j(u_j), u_j = B_j (x - c_j), replaces B_j by
    # phi_j'(u_j) B_j.
    for start, stop, nearest, dw2, weights in index.relative_blocks(X, h, gradient):
        block = (X[start:stop], index.centres, nearest, dw2, weights)
        fb, gb = (_dense_block if len(weights) == 3 else _sparse_block)(
            block, offsets, intercepts, slopes, floor, gradient
        )
        f[start:stop] = fb
        if gradient:
            grad[start:stop] = gb
    return f, grad


def _dense_block(block, offsets, intercepts, slopes, floor, gradient):
    """:func:`blend` on a block of points with dense weights ``(v, dv/drel, dv/dH^2)``.

    ``block`` is ``(Xb, centres, nearest, dH^2/dt, weights)``; ``floor`` is ``(floors,
    softness)`` or None. Returns ``f`` (b, d) and ``grad`` (b, d, n) or None.
    """
    Xb, centres, nearest, dw2, (v, dvs, dvh) = block
    d = intercepts.shape[1]
    cn = centres[nearest]
    f = np.empty((len(Xb), d))
    grad = np.empty((len(Xb), d, Xb.shape[1])) if gradient else None
    V = v.sum(axis=1)
    for k in range(d):
        L = offsets[None, :, k] + Xb @ slopes[:, k, :].T
        vd = v
        if floor is not None:
            b0 = intercepts[None, :, k]
            p, dp = floored(L - b0, floor[0][None, :, k], floor[1][None, :, k])
            L = b0 + p
            vd = v * dp
        fk = np.einsum("ij,ij->i", v, L) / V
        f[:, k] = fk
        if gradient:
            L -= fk[:, None]
            Es = dvs * L
            eh = np.einsum("ij,ij->i", dvh, L)
            g = vd @ slopes[:, k, :] + 2.0 * (Es.sum(axis=1)[:, None] * cn - Es @ centres)
            g += (2.0 * eh * dw2)[:, None] * (Xb - cn)
            grad[:, k] = g / V[:, None]
    return f, grad


def _sparse_block(block, offsets, intercepts, slopes, floor, gradient):
    """:func:`blend` on a block of points with sparse weights ``(rows, cols, v, ...)``.

    As :func:`_dense_block`.
    """
    Xb, centres, nearest, dw2, (rows, cols, v, dvs, dvh) = block
    b, d = len(Xb), intercepts.shape[1]
    C = len(centres)
    cn = centres[nearest]
    f = np.empty((b, d))
    grad = np.empty((b, d, Xb.shape[1])) if gradient else None
    V = np.bincount(rows, v, minlength=b)
    Vmat = sp.csr_matrix((v, (rows, cols)), shape=(b, C)) if gradient else None
    for k in range(d):
        L = offsets[cols, k] + np.einsum("ij,ij->i", slopes[cols, k], Xb[rows])
        if floor is not None:
            b0 = intercepts[cols, k]
            p, dp = floored(L - b0, floor[0][cols, k], floor[1][cols, k])
            L = b0 + p
            if gradient:
                Vmat = sp.csr_matrix((v * dp, (rows, cols)), shape=(b, C))
        fk = np.bincount(rows, v * L, minlength=b) / V
        f[:, k] = fk
        if gradient:
            L -= fk[rows]
            es = dvs * L
            Es = sp.csr_matrix((es, (rows, cols)), shape=(b, C))
            esum = np.bincount(rows, es, minlength=b)
            eh = np.bincount(rows, dvh * L, minlength=b)
            g = Vmat @ slopes[:, k, :] + 2.0 * (esum[:, None] * cn - Es @ centres)
            g += (2.0 * eh * dw2)[:, None] * (Xb - cn)
            grad[:, k] = g / V[:, None]
    return f, grad
