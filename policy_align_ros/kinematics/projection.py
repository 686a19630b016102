"""Nullspace projection of constraint matrices.

Notation (paper, eqs. 2-3): a constraint ``A(x, t) xdot = 0`` with ``A`` of shape (k, n)
turns a policy ``pi`` into the observed motion ``xdot = N pi`` with
``N = I - pinv(A) A`` (n, n). ``k = 0`` (no active constraint) gives ``N = I``. Units
follow the state (rad, m); ``N`` itself is dimensionless.
"""

from __future__ import annotations

import numpy as np

__all__ = ["nullspace_projector", "nullspace_projectors", "projector_from_svd", "DEFAULT_RCOND"]

#: Relative singular-value cut-off below which a constraint direction counts as lost
#: (rank loss at singular configurations); relative to the largest singular value.
DEFAULT_RCOND = 1e-10


def nullspace_projector(A: np.ndarray, n: int | None = None, rcond: float = DEFAULT_RCOND
                        ) -> np.ndarray:
    """Orthogonal projector onto the nullspace of ``A``.

    Parameters
    ----------
    A : array_like, shape (k, n)
        Constraint matrix; ``k`` may be 0.
    n : int, optional
        State dimension, needed only when ``A`` is given as an empty array without a
        column count (for example ``[]``).
    rcond : float
        Singular values below ``rcond * s_max`` are treated as zero, so rank-deficient or
        singular constraints never blow up.

    Returns
    -------
    numpy.ndarray, shape (n, n)
        ``N = I - pinv(A) A``, symmetric and idempotent.

    Raises
    ------
    ValueError
        If ``A`` is not 2-D, is not finite, or ``n`` disagrees with its columns.
    """
    mat = np.asarray(A, dtype=float)
    if mat.size == 0 and mat.ndim < 2:
        if n is None:
            raise ValueError("A: empty constraint matrix needs the state dimension n")
        mat = np.zeros((0, n))
    if mat.ndim != 2:
        raise ValueError(f"A: must have shape (k, n), got {mat.shape}")
    if n is not None and mat.shape[1] != n:
        raise ValueError(f"A: has {mat.shape[1]} columns, expected n={n}")
    if not np.all(np.isfinite(mat)):
        raise ValueError("A: contains NaN or inf")
    dim = mat.shape[1]
    if mat.shape[0] == 0:
        return np.eye(dim)
    _, s, vt = np.linalg.svd(mat, full_matrices=False)
    return projector_from_svd(s, vt, rcond)


def projector_from_svd(s: np.ndarray, vt: np.ndarray, rcond: float = DEFAULT_RCOND
                       ) -> np.ndarray:
    """``N = I - pinv(A) A`` (n, n) from the thin SVD of ``A`` (k, n).

    For callers that need the singular values ``s`` (min(k, n),) as well (the executor's
    near-singularity check), so one SVD serves both. ``vt`` has shape (min(k, n), n).
    """
    dim = vt.shape[1]
    if s.size == 0 or s[0] == 0.0:
        return np.eye(dim)
    # Row space basis: N = I - V_r V_r^T is exactly I - pinv(A) A.
    basis = vt[s > rcond * s[0]]
    return np.eye(dim) - basis.T @ basis


def nullspace_projectors(As: np.ndarray, rcond: float = DEFAULT_RCOND) -> np.ndarray:
    """Vectorised :func:`nullspace_projector` for many constraints of equal shape.

    Parameters
    ----------
    As : array_like, shape (m, k, n)
        ``m`` constraint matrices; ``k`` may be 0.
    rcond : float
        Relative singular-value cut-off, as in :func:`nullspace_projector`.

    Returns
    -------
    numpy.ndarray, shape (m, n, n)
    """
    mats = np.asarray(As, dtype=float)
    if mats.ndim != 3:
        raise ValueError(f"As: must have shape (m, k, n), got {mats.shape}")
    if not np.all(np.isfinite(mats)):
        raise ValueError("As: contains NaN or inf")
    m, k, dim = mats.shape
    eye = np.broadcast_to(np.eye(dim), (m, dim, dim)).copy()
    if k == 0 or m == 0:
        return eye
    _, s, vt = np.linalg.svd(mats, full_matrices=False)
    smax = s[:, :1]
    keep = (s > rcond * smax) & (smax > 0.0)
    basis = vt * keep[:, :, None]
    return eye - np.einsum("mki,mkj->mij", basis, basis)
