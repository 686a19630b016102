"""The single-index trend: a potential that is a function of one quadratic form.

Notation
--------
States ``z`` (n,) are standardised (see :mod:`.trend_kernel`). The trend is::

    u(z) = beta_0 + sum_j beta_j B_j(q(z)),    q(z) = ||L' (z - z0)||^2

with ``L`` (n, n) lower triangular, the goal ``z0`` (n,) and the *profile* basis
``B(q) = [q / s^2, sqrt(q + c_j^2) - c_j]``, ``c_j = s * KNEES[j]``, ``s`` a typical
``sqrt(q)`` of the data. The first column is the quadratic bowl; the others are
hyperbolas, quadratic for ``q << c_j^2`` and a cone beyond, so the profile bends from a
bowl near the goal to a bounded slope far from it (a velocity-limited demonstrator) or,
with negative weights, grows faster than a bowl.

A quadratic trend cannot bend that way; a kernel residual can only within its length
scale of the data. The index ``(L, z0)`` enters nonlinearly and is fitted by variable
projection (Golub and Pereyra): ``beta`` and one free offset per demonstration come from
linear least squares inside the residual, and the Jacobian is Kaufman's,
``-P_perp (dB / dtheta) beta``. Started from a quadratic trend's Hessian and minimum it
converges in about ten evaluations (``tools/single_index_check.py``,
``docs/notes/trend_kernel.md``).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import scipy.optimize

__all__ = ["KNEES", "fit_index", "increasing", "index_form", "profile_basis",
           "profile_gradient"]

#: Knees ``c_j / s`` of the hyperbolas: from a fraction of the data's typical radius to
#: a few times it.
KNEES = (1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0, 2.0, 4.0)


def profile_basis(q: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """The profile basis at ``q`` and its derivative in ``q``.

    Parameters
    ----------
    q : ndarray (m,)
        Values of the quadratic form, >= 0 (standardised units squared).
    s : float
        Typical ``sqrt(q)`` of the data, > 0.

    Returns
    -------
    B, dB : ndarray (m, 1 + len(KNEES))
    """
    c = s * np.asarray(KNEES)
    root = np.sqrt(q[:, None] + c**2)
    return (np.column_stack([q / s**2, root - c]),
            np.column_stack([np.full(len(q), 1.0 / s**2), 0.5 / root]))


def index_form(Z: np.ndarray, L: np.ndarray, z0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``D = (Z - z0) L`` (m, n) and ``q = ||D||^2`` row-wise (m,)."""
    D = (Z - z0) @ L
    return D, np.einsum("ij,ij->i", D, D)


def profile_gradient(Z: np.ndarray, L: np.ndarray, z0: np.ndarray, s: float,
                     beta: np.ndarray) -> np.ndarray:
    """``grad_z u`` (m, n) of the trend with profile weights ``beta`` (1 + len(KNEES),),
    the constant excluded: ``g'(q) 2 L D'``."""
    D, q = index_form(Z, L, z0)
    _, dB = profile_basis(q, s)
    return (dB @ beta)[:, None] * 2.0 * D @ L.T


def increasing(beta: np.ndarray, s: float, q_max: float) -> bool:
    """Whether the profile ``g(q) = sum_j beta_j B_j(q)`` rises on ``[0, 100 q_max]``.

    Then ``z0`` is the trend's only minimum and its gradient points away from it
    everywhere the data reach and well beyond; a profile that falls somewhere would send
    the policy uphill toward a ridge.
    """
    q = np.concatenate([[0.0], np.geomspace(1e-6 * s**2, 100.0 * max(q_max, s**2), 200)])
    _, dB = profile_basis(q, s)
    return bool(np.all(dB @ beta > 0.0))


def fit_index(Z: np.ndarray, u: np.ndarray, demo: np.ndarray, L: np.ndarray,
              z0: np.ndarray, s: float, max_nfev: int) -> tuple[np.ndarray, np.ndarray]:
    """Fit the index ``(L, z0)`` by variable projection, one free offset per demonstration.

    Parameters
    ----------
    Z : ndarray (m, n)
        Standardised states.
    u : ndarray (m,)
        Standardised potentials.
    demo : ndarray (m,) of int
        Demonstration of every sample (any ids).
    L, z0 : ndarray (n, n), (n,)
        Start: ``L`` lower triangular (a Cholesky factor of a positive definite Hessian),
        ``z0`` its minimum.
    s : float
        Scale of the profile basis (kept fixed).
    max_nfev : int
        Residual evaluations allowed.

    Returns
    -------
    L, z0 : ndarray (n, n), (n,)
        The fitted index (the start if the fit failed to improve it).
    """
    m, n = Z.shape
    il = np.tril_indices(n)
    _, k = np.unique(demo, return_inverse=True)
    offsets = np.zeros((m, int(k.max()) + 1))
    offsets[np.arange(m), k] = 1.0

    def unpack(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        L_ = np.zeros((n, n))
        L_[il] = theta[:len(il[0])]
        return L_, theta[len(il[0]):]

    def design(theta: np.ndarray):
        L_, z_ = unpack(theta)
        E = Z - z_
        D = E @ L_
        B, dB = profile_basis(np.einsum("ij,ij->i", D, D), s)
        Q, R = np.linalg.qr(np.hstack([offsets, B]))
        return L_, E, D, dB, Q, R

    def residual(theta: np.ndarray) -> np.ndarray:
        *_, Q, _ = design(theta)
        return u - Q @ (Q.T @ u)

    def jacobian(theta: np.ndarray) -> np.ndarray:
        L_, E, D, dB, Q, R = design(theta)
        coef = scipy.linalg.lstsq(R, Q.T @ u, check_finite=False)[0]
        slope = dB @ coef[offsets.shape[1]:]
        # dq / dL_ij = 2 E_i D_j (i >= j), dq / dz0 = -2 L D
        dq = np.hstack([2.0 * E[:, il[0]] * D[:, il[1]], -2.0 * D @ L_.T])
        M = slope[:, None] * dq
        return -(M - Q @ (Q.T @ M))

    theta0 = np.concatenate([L[il], z0])
    try:
        result = scipy.optimize.least_squares(residual, theta0, jac=jacobian,
                                              max_nfev=max_nfev, x_scale="jac")
    except (np.linalg.LinAlgError, ValueError):
        return L, z0
    if not np.all(np.isfinite(result.x)) or not math.isfinite(result.cost):
        return L, z0
    return unpack(result.x)
