"""The trend-kernel model's small dense solves, straight from LAPACK.

A fit's cross-validation factors and solves tens of thousands of systems of a few dozen
to a few hundred unknowns. At those sizes the input checks and batch dispatch of
``scipy.linalg.cho_factor``, ``cho_solve``, ``cholesky`` and ``solve_triangular`` cost
about as much as the LAPACK routine itself. These functions call the same routines
(``dpotrf``, ``dpotrs``, ``dtrtrs``) with the same arguments as those wrappers do for
finite float64 arrays, so the results are the same to the last bit
(``docs/design/scaling.md``). Inputs must be finite float64 matrices: the
callers build them, and no check is repeated here.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from scipy.linalg.lapack import dpotrf, dpotrs, dtrtrs

__all__ = ["cho_factor", "cho_solve", "cholesky", "solve_triangular"]


def _factor(M: np.ndarray, lower: bool, clean: bool) -> np.ndarray:
    c, info = dpotrf(M, lower=lower, clean=clean)
    if info > 0:
        raise np.linalg.LinAlgError(
            f"{info}-th leading minor of the array is not positive definite")
    if info < 0:
        raise ValueError(f"LAPACK dpotrf: illegal value in argument {-info}")
    return c


def cho_factor(M: np.ndarray) -> tuple[np.ndarray, bool]:
    """``scipy.linalg.cho_factor(M, check_finite=False)``: the upper Cholesky factor of the
    symmetric positive-definite ``M`` (p, p), its other triangle left as it was, and
    ``False`` (not lower). Raises ``LinAlgError`` if ``M`` is not positive definite."""
    if M.size == 0:
        return scipy.linalg.cho_factor(M, check_finite=False)
    return _factor(M, False, False), False


def cholesky(M: np.ndarray, lower: bool) -> np.ndarray:
    """``scipy.linalg.cholesky(M, lower, check_finite=False)``: ``L`` (p, p) with
    ``L L' = M`` (lower) or ``R`` with ``R' R = M``, the other triangle zero. Raises
    ``LinAlgError`` if ``M`` is not positive definite."""
    if M.size == 0:
        return scipy.linalg.cholesky(M, lower=lower, check_finite=False)
    return _factor(M, lower, True)


def cho_solve(factor: tuple[np.ndarray, bool], b: np.ndarray) -> np.ndarray:
    """``scipy.linalg.cho_solve(factor, b, check_finite=False)``: ``M^-1 b`` for ``b`` (p,)
    or (p, k), ``factor`` from :func:`cho_factor`."""
    c, lower = factor
    if b.size == 0:
        return scipy.linalg.cho_solve(factor, b, check_finite=False)
    x, info = dpotrs(c, b, lower=lower)
    if info != 0:
        raise ValueError(f"LAPACK dpotrs: illegal value in argument {-info}")
    return x


def solve_triangular(L: np.ndarray, b: np.ndarray, lower: bool, trans: int = 0
                     ) -> np.ndarray:
    """``scipy.linalg.solve_triangular(L, b, trans, lower, check_finite=False)`` for
    ``trans`` 0 (``L x = b``) or 1 (``L' x = b``). Raises ``LinAlgError`` on a zero
    pivot."""
    if b.size == 0:
        return scipy.linalg.solve_triangular(L, b, trans=trans, lower=lower,
                                             check_finite=False)
    if L.flags.f_contiguous:
        x, info = dtrtrs(L, b, lower=lower, trans=trans)
    else:  # the transposed system: dtrtrs expects Fortran order, as scipy does it
        x, info = dtrtrs(L.T, b, lower=not lower, trans=not trans)
    if info > 0:
        raise np.linalg.LinAlgError(f"singular matrix: zero pivot at diagonal {info - 1}")
    if info < 0:
        raise ValueError(f"LAPACK dtrtrs: illegal value in argument {-info}")
    return x
