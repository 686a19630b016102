"""Each demonstration's time unit, estimated against the fitted potential.

A teacher moves each demonstration at a speed of their own. Under any projection
constraint ``xdot = N pi``, a demonstration moved ``c`` times faster than the policy
drops its potential estimate ``|xdot|^2 dt`` by ``c`` times the potential's drop: along
one demonstration the estimate is the potential times ``c``, plus an offset. The paper
takes ``c = 1`` for every demonstration. Here, once a global model ``f`` has been fitted
to the aligned potentials, each demonstration's factor ``s ~ 1 / c`` is the least-squares
slope of ``f`` on its own estimates (one offset per piece); the estimates are multiplied
by it and the model is fitted again. Demonstrations that are gradient flows of one
potential on one clock get factors of 1, and the paper's estimate is kept
(:data:`TIMING_RESOLUTION`). Design note: ``docs/design/timing.md``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["TIME_UNITS", "TIMING_RESOLUTION", "heldout_ratio", "timed_is_better",
           "timing_scales"]

#: PolicyAlign's ``time_units``: a factor per demonstration, or the paper's shared clock.
TIME_UNITS = ("per_demonstration", "shared")

#: Factors within this of 1 leave the paper's estimate as it is: the demonstrations'
#: timing agrees with one potential to within what the fitted model resolves.
TIMING_RESOLUTION = 0.01


def timing_scales(fitted: list[np.ndarray], values: list[np.ndarray], owner: np.ndarray,
                  n_parents: int) -> np.ndarray:
    """Per demonstration, the factor its potential estimates are multiplied by.

    Demonstration ``k``'s factor minimises ``sum_p sum_i (f_pi - s y_pi - b_p)^2`` over
    its pieces ``p`` (one offset ``b_p`` each). The factors are normalised to a geometric
    mean of 1 over the demonstrations whose factor is determined, so that the potential
    keeps the demonstrations' typical speed. A demonstration whose estimates do not vary, or whose
    slope is not positive (its potential disagrees with the model, which the held-out
    checks report), keeps 1.

    Parameters
    ----------
    fitted, values : list of ndarray, shape (N_p,)
        Per piece, the global model's potential and the aligned potential estimates at
        the same samples (potential units).
    owner : ndarray of int, shape (P,)
        The demonstration each piece belongs to.
    n_parents : int
        Number of demonstrations.

    Returns
    -------
    ndarray, shape (n_parents,)
        Positive factors; 1 for demonstrations without pieces.
    """
    owner = np.asarray(owner, dtype=np.int64)
    if len(fitted) != len(values) or len(values) != len(owner):
        raise ValueError(f"fitted, values and owner: {len(fitted)}, {len(values)} and "
                         f"{len(owner)} pieces; they must be equal")
    cross, spread = np.zeros(n_parents), np.zeros(n_parents)
    for f, y, k in zip(fitted, values, owner, strict=True):
        f, y = np.asarray(f, float), np.asarray(y, float)
        if f.shape != y.shape:
            raise ValueError(f"piece of demonstration {k}: {f.shape} fitted values for "
                             f"{y.shape} estimates")
        if len(y) < 2:
            continue
        dy = y - y.mean()
        cross[k] += dy @ (f - f.mean())
        spread[k] += dy @ dy
    scales = np.ones(n_parents)
    determined = (spread > 0) & (cross > 0)
    if not determined.any():
        return scales
    scales[determined] = cross[determined] / spread[determined]
    # A demonstration twice as fast and one twice as slow cancel: the geometric mean.
    scales[determined] /= np.exp(np.mean(np.log(scales[determined])))
    return scales


def heldout_ratio(checks: dict) -> float:
    """A fit's held-out error along the observed motion over a zero policy's, from its
    checks (:func:`~policy_align_ros.learning.folds.fit_checks`); infinite without one."""
    heldout = checks.get("heldout_vs_zero")
    return math.inf if heldout is None else float(heldout["ratio"])


def timed_is_better(timed: dict, shared: dict) -> bool:
    """Whether the fit on per-demonstration clocks is kept over the shared clock's.

    It is when it strands fewer demonstrated starts or, with as many stranded, when its
    held-out error ratio is lower on the same CV folds by more than two standard errors
    of the paired per-fold differences (the rule the tracking lag is kept by).

    Parameters
    ----------
    timed, shared : dict
        The two fits' checks (:func:`~policy_align_ros.learning.folds.fit_checks`):
        ``goal["n_starts_elsewhere"]`` and ``heldout_vs_zero["fold_ratios"]``.

    Returns
    -------
    bool
        False too when fewer than two folds can be paired.
    """
    stranded = [int(c["goal"].get("n_starts_elsewhere") or 0) for c in (timed, shared)]
    if stranded[0] != stranded[1]:
        return stranded[0] < stranded[1]
    held = [c.get("heldout_vs_zero") or {} for c in (timed, shared)]
    a, b = (np.asarray(h.get("fold_ratios", []), dtype=float) for h in held)
    if len(a) != len(b) or len(a) < 2:
        return False
    d = a - b
    return bool(d.mean() + 2.0 * d.std(ddof=1) / math.sqrt(len(d)) < 0.0)
