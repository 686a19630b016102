"""The single-index trend: a potential that is a function of one quadratic form.

Notation
--------
States ``z`` (n,) are standardised (see :mod:`.model`). The trend is::

    u(z) = beta_0 + sum_j beta_j B_j(q(z)),    q(z) = ||L' (z - z0)||^2

with ``L`` (n, n) lower triangular, the goal ``z0`` (n,) and the *profile* basis::

    B(q) = [q / s^2,  h_j(q),  h_j(q)^2 / s^2],   h_j(q) = sqrt(q + c_j^2) - c_j

``c_j = s * KNEES[j]``, ``s`` a typical ``sqrt(q)`` of the data. The first column is the
quadratic bowl. The hyperbolas ``h_j`` are quadratic for ``q << c_j^2`` and a cone
beyond: they bend the profile from a bowl near the goal to a bounded slope far from it (a
velocity-limited demonstrator). Their squares (``q - 2 c_j h_j``, with derivative
``(1 - c_j / sqrt(q + c_j^2)) / s^2``) grow like ``q^2`` below ``c_j^2`` and like the
bowl beyond: a profile that steepens away from the goal. Every column rises in ``q``, so with the
profile weights ``beta_j >= 0`` the profile rises by construction and ``z0`` is the
trend's only minimum. (Signed weights on the first two kinds could steepen a profile too,
but then it often fell near ``q = 0``, a ridge around the goal.)

A quadratic trend cannot bend that way; a kernel residual can only within its length
scale of the data. The index ``(L, z0)`` enters nonlinearly and is fitted by variable
projection (Golub and Pereyra): ``beta`` (non-negative least squares) and one free offset
per demonstration are solved for inside the residual, and the Jacobian is Kaufman's on
the active columns, ``-P_perp (dB / dtheta) beta``; the steps are Levenberg-Marquardt's
on the normal equations. Started from a quadratic trend's Hessian and minimum it
converges in about ten evaluations
(``tools/single_index_check.py``, ``docs/design/single_index.md``).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.optimize

from policy_align_ros.learning.regressors.trend_kernel.lapack import cho_factor, cho_solve

__all__ = ["KNEES", "centred", "fit_index", "increasing", "index_form", "levenberg_marquardt",
           "profile_basis", "profile_gradient", "profile_weights"]

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
    B, dB : ndarray (m, 1 + 2 len(KNEES))
        Columns: the bowl, the hyperbolas, the steepening columns (module docstring).
    """
    c = s * np.asarray(KNEES)
    root = np.sqrt(q[:, None] + c**2)
    hyper = q[:, None] / (root + c)  # sqrt(q + c^2) - c without cancellation at small q
    return (np.column_stack([q / s**2, hyper, hyper**2 / s**2]),
            np.column_stack([np.full(len(q), 1.0 / s**2), 0.5 / root, hyper / (root * s**2)]))


def centred(M: np.ndarray, demo: np.ndarray) -> np.ndarray:
    """Columns of ``M`` (m, p) minus their mean over each demonstration, ``demo`` (m,) in
    ``0..K-1``: the residual of a free per-demonstration offset."""
    nk = np.bincount(demo).astype(float)
    sums = np.stack([np.bincount(demo, weights=col, minlength=len(nk)) for col in M.T], 1)
    return M - (sums / np.maximum(nk, 1.0)[:, None])[demo]


def profile_weights(B: np.ndarray, u: np.ndarray, demo: np.ndarray) -> np.ndarray:
    """Non-negative profile weights ``beta`` (p,) fitting ``u`` (m,) with the basis ``B``
    (m, p) and one free offset per demonstration (``demo`` (m,) in ``0..K-1``)."""
    return scipy.optimize.nnls(centred(B, demo), centred(u[:, None], demo)[:, 0],
                               maxiter=50 * B.shape[1])[0]


def index_form(Z: np.ndarray, L: np.ndarray, z0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``D = (Z - z0) L`` (m, n) and ``q = ||D||^2`` row-wise (m,)."""
    D = (Z - z0) @ L
    return D, np.einsum("ij,ij->i", D, D)


def profile_gradient(Z: np.ndarray, L: np.ndarray, z0: np.ndarray, s: float,
                     beta: np.ndarray) -> np.ndarray:
    """``grad_z u`` (m, n) of the trend with profile weights ``beta`` (1 + 2 len(KNEES),),
    the constant excluded: ``g'(q) 2 L D'``."""
    D, q = index_form(Z, L, z0)
    _, dB = profile_basis(q, s)
    return (dB @ beta)[:, None] * 2.0 * D @ L.T


def increasing(beta: np.ndarray, s: float, q_max: float) -> bool:
    """Whether the profile ``g(q) = sum_j beta_j B_j(q)`` rises on
    ``[1e-6 s^2, 100 max(q_max, s^2)]``.

    The slope ``g'(q)`` must be positive at 200 points spaced geometrically over that
    range: from well inside the basis' scale ``s^2`` to a hundred times the largest of the
    data's ``q_max`` and ``s^2`` (so that data all near the minimum are still checked out
    to the basis' own scale). Then ``z0`` is the trend's only minimum and its gradient
    points away from it everywhere the data reach and well beyond. Non-negative weights
    rise unless they are all zero (a flat trend); the check guards the fit's output
    whatever produced it.
    """
    q = np.geomspace(1e-6 * s**2, 100.0 * max(q_max, s**2), 200)
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
    uc = centred(u[:, None], k)[:, 0]

    def unpack(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        L_ = np.zeros((n, n))
        L_[il] = theta[:len(il[0])]
        return L_, theta[len(il[0]):]

    cache: dict[bytes, tuple] = {}

    def design(theta: np.ndarray):
        # The Jacobian is asked for at the point whose residual was just evaluated: one
        # entry saves the second NNLS and QR there.
        key = theta.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = _design(theta)
        return cache[key]

    def _design(theta: np.ndarray):
        L_, z_ = unpack(theta)
        E = Z - z_
        D = E @ L_
        B, dB = profile_basis(np.einsum("ij,ij->i", D, D), s)
        Bc = centred(B, k)
        beta = scipy.optimize.nnls(Bc, uc, maxiter=50 * B.shape[1])[0]
        # At the NNLS solution the zero weights stay at their bound for small steps: the
        # projection is onto the active columns.
        active = beta > 0.0
        Q = np.linalg.qr(Bc[:, active])[0] if active.any() else np.zeros((m, 0))
        return L_, E, D, dB, Bc, beta, Q

    def residual(theta: np.ndarray) -> np.ndarray:
        _, _, _, _, Bc, beta, _ = design(theta)
        return uc - Bc @ beta

    def jacobian(theta: np.ndarray) -> np.ndarray:
        L_, E, D, dB, _, beta, Q = design(theta)
        slope = dB @ beta
        # dq / dL_ij = 2 E_i D_j (i >= j), dq / dz0 = -2 L D
        dq = np.hstack([2.0 * E[:, il[0]] * D[:, il[1]], -2.0 * D @ L_.T])
        M = centred(slope[:, None] * dq, k)
        return -(M - Q @ (Q.T @ M))

    try:
        theta = levenberg_marquardt(residual, jacobian, np.concatenate([L[il], z0]),
                                    max_nfev)
    except (np.linalg.LinAlgError, ValueError, RuntimeError):  # RuntimeError: NNLS
        return L, z0
    if not np.all(np.isfinite(theta)):
        return L, z0
    return unpack(theta)


def levenberg_marquardt(residual, jacobian, theta: np.ndarray, max_nfev: int,
                        rtol: float = 1e-10) -> np.ndarray:
    """Minimise ``||residual(theta)||^2`` by Levenberg-Marquardt steps with Marquardt's
    scaling, solved on the normal equations.

    Parameters
    ----------
    residual, jacobian : callable
        ``theta`` (p,) -> residual (m,) and its Jacobian (m, p). The Jacobian is only
        asked for at the last point whose residual was evaluated.
    theta : ndarray (p,)
        Start.
    max_nfev : int
        Residual evaluations allowed (the start's included).
    rtol : float
        Stop when an accepted step lowers the cost by less than this fraction.

    Returns
    -------
    ndarray (p,)
        The point of lowest cost found.

    Notes
    -----
    ``J' J`` costs ``m p^2`` and a Cholesky factor ``p^3 / 3`` per step, where
    ``scipy.optimize.least_squares`` does an SVD of ``J``, several times the work for
    the index's tall Jacobians (``docs/design/single_index.md``).
    """
    r = residual(theta)
    cost = float(r @ r)
    J = jacobian(theta)
    damping = 1e-3
    for _ in range(max_nfev - 1):
        A, g = J.T @ J, J.T @ r
        diag = np.maximum(np.diag(A), 1e-12 * max(float(np.max(np.diag(A))), 1e-300))
        try:
            factor = cho_factor(A + damping * np.diag(diag))
        except np.linalg.LinAlgError:
            damping *= 10.0
            continue
        trial = theta - cho_solve(factor, g)
        r_trial = residual(trial)
        cost_trial = float(r_trial @ r_trial)
        if not (math.isfinite(cost_trial) and cost_trial < cost):
            damping *= 4.0
            continue
        converged = cost - cost_trial < rtol * cost
        theta, r, cost = trial, r_trial, cost_trial
        if converged:
            break
        J = jacobian(theta)
        damping = max(damping / 3.0, 1e-12)
    return theta
