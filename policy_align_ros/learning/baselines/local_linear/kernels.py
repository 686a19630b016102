"""Receptive-field weights of the local-linear regression.

Notation and units: ``s`` a squared distance (state units^2) from a field centre, ``h`` a
field width (state units). The weight is a Gaussian with a smooth polynomial cut-off at
``R = CUTOFF h``, so that sums over neighbours are exact and sparse::

    g(s; h^2) = exp(-s / (2 h^2)) (1 - (s / R^2)^2)^2  for s < R^2, else 0
"""

from __future__ import annotations

import numpy as np

__all__ = ["CUTOFF", "FAR_WIDENING", "blend_width2", "kernel"]

#: Cut-off radius of a receptive field in units of its width ``h``.
CUTOFF = 3.0
#: Growth of the blending width with the distance from the nearest centre, far away.
FAR_WIDENING = 0.5


def kernel(s: np.ndarray, h2: float | np.ndarray, derivative: bool = True):
    """Receptive-field weight ``g(s; h^2)`` and its derivatives.

    Parameters
    ----------
    s : ndarray
        Squared distances (state units^2), ``s >= 0``.
    h2 : float or ndarray broadcastable to ``s``
        Squared width ``h^2`` (state units^2).
    derivative : bool
        Also return the derivatives.

    Returns
    -------
    g : ndarray, shape of ``s``
        Dimensionless, 0 for ``s >= CUTOFF^2 h^2``.
    dg_ds, dg_dh2 : ndarray, shape of ``s``
        In 1/state units^2; only when ``derivative``.
    """
    r2 = (CUTOFF * CUTOFF) * h2
    u = np.minimum(s / r2, 1.0)
    one_minus = 1.0 - u * u
    gauss = np.exp(-0.5 * s / h2)
    g = gauss * (one_minus * one_minus)
    if not derivative:
        return g
    dg_ds = -0.5 * g / h2 - 4.0 * gauss * u * one_minus / r2
    dg_dh2 = 0.5 * g * s / (h2 * h2) + 4.0 * gauss * u * u * one_minus / h2
    return g, dg_ds, dg_dh2


def blend_width2(t: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Squared blending width ``H^2(t)`` at squared distance ``t`` from the nearest centre.

    ``H^2 = h^2 + a^2 t^2 / (t + R^2)`` with ``a = FAR_WIDENING`` and ``R = CUTOFF h``:
    ``h^2`` near the data, growing like ``(a d_min)^2`` far from it. Without this, far
    away the blend would switch between diverging linear extrapolations over a width of
    ``h^2 / ||c_j - c_k||``, and its gradient would grow without bound with the distance.

    Parameters
    ----------
    t : ndarray
        Squared distances to the nearest centre (state units^2).
    h : float
        Field width (state units).

    Returns
    -------
    H2, dH2_dt : ndarray, shape of ``t``
    """
    r2 = (CUTOFF * h) ** 2
    a2 = FAR_WIDENING * FAR_WIDENING
    q = t + r2
    return h * h + a2 * t * t / q, a2 * t * (t + 2.0 * r2) / (q * q)
