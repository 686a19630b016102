"""Tracking lag of the demonstrations: the potential when the velocity lags the policy.

A robot that tracks velocity commands through its dynamics, or a person whose speed builds
up from rest, does not move at the policy's velocity ``u = N pi(x)`` but lags it. To first
order the lag is ``u = v + tau dv/dt`` with a time constant ``tau`` (s). The paper's
potential step along a trajectory, ``d phi = grad phi . v dt``, is then (with ``v`` in the
null space of the same constraint as ``u``, so ``grad phi . v = -u . v``)

    ``d phi = -(|v|^2 + tau v . dv/dt) dt = -|v|^2 dt - tau d(|v|^2 / 2)``,

so the lagged estimate is the paper's minus ``tau`` times the kinetic term
``(|v|^2 - |v_1|^2) / 2`` (:func:`lagged_potentials`). Over a demonstration from rest to
rest the correction sums to zero: it moves the potential's drop to where the policy asked
for it, before the robot's speed caught up.

``tau`` is not known. :func:`choose_lag` picks it as every other choice of the fit is
picked: by the global model's cross-validation over held-out demonstrations; ``tau = 0``
(the paper's estimate) is kept unless a lag improves the held-out score by more than two
standard errors (``docs/design/tracking_lag.md``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["LAG_GRID", "choose_lag", "kinetic_term", "lagged_potentials", "refine_minimum"]

#: Time constants (s) scored by :func:`choose_lag` besides 0: velocity controllers lag by
#: tens of milliseconds (a compliant arm's slow loop by a few hundred), a person's speed
#: builds up over a few hundred. A lag is refined between the grid points around the best
#: score, so the last point only brackets: lags up to about half of it are found.
LAG_GRID = (0.02, 0.04, 0.08, 0.16, 0.32, 0.64)


def kinetic_term(traj: Trajectory) -> np.ndarray:
    """``(|v_i|^2 - |v_1|^2) / 2`` along a timed trajectory, (N,) in (state units / s)^2.

    ``v`` is the trajectory's recorded velocity when it has one, else the central
    difference of its positions over its times (one-sided at the ends).
    """
    v = traj.velocity_estimate()
    k = 0.5 * np.einsum("ij,ij->i", v, v)
    return k - k[0]


def lagged_potentials(phi: Sequence[np.ndarray], kinetic: Sequence[np.ndarray], tau: float
                      ) -> list[np.ndarray]:
    """The potentials ``phi_k - tau K_k`` of a tracking lag ``tau`` (s).

    Parameters
    ----------
    phi : sequence of ndarray, shape (N_k,)
        The paper's potential estimates along each trajectory.
    kinetic : sequence of ndarray, shape (N_k,)
        :func:`kinetic_term` of the same trajectories.
    tau : float
        Lag time constant (s), >= 0.
    """
    if tau == 0.0:
        return list(phi)
    return [p - tau * k for p, k in zip(phi, kinetic, strict=True)]


def refine_minimum(taus: Sequence[float], scores: Sequence[float]) -> float:
    """The vertex of the parabola through the best of ``scores`` and its neighbours
    (``taus`` increasing); the best grid point itself at an end of the grid or when the
    parabola does not open upwards.

    A parabola because the potentials are linear in ``tau`` and a fit with fixed
    hyperparameters is linear in its targets: its held-out squared error is quadratic in
    ``tau`` (up to the score's normalisation).
    """
    t = np.asarray(taus, dtype=float)
    s = np.asarray(scores, dtype=float)
    i = int(np.argmin(s))
    if i == 0 or i == len(t) - 1 or not np.all(np.isfinite(s[i - 1:i + 2])):
        return float(t[i])
    x, y = t[i - 1:i + 2], s[i - 1:i + 2]
    a, b, _ = np.polyfit(x, y, 2)
    if not a > 0.0:
        return float(t[i])
    return float(np.clip(-b / (2.0 * a), x[0], x[2]))


def choose_lag(score: Callable[[float], tuple[float | None, float]], period: float = 0.0,
               grid: Sequence[float] = LAG_GRID) -> tuple[float, dict[float, float]]:
    """The tracking lag whose potentials the global model's CV predicts best.

    Parameters
    ----------
    score : callable ``tau -> (score, standard_error)``
        The held-out score of the global model (hyperparameters fixed) on the potentials
        of lag ``tau`` (s), and its standard error over the folds; ``score`` None when
        the fit has none.
    period : float
        The demonstrations' sample period (s): a lag shorter than one period cannot be
        told from the integration rule's own error over a step, so no lag below it is
        scored.
    grid : sequence of float
        Lags (s, > 0, increasing) scored besides 0, in order until the score rises: a
        recording without lag costs one score.

    Returns
    -------
    tau : float
        0 unless the best lag (the grid refined by :func:`refine_minimum`; the grid's last
        lag itself is never chosen, it only brackets) scores lower than ``tau = 0`` by
        more than twice that score's standard error.
    scores : dict
        ``{tau: score}`` of every lag scored.
    """
    base, error = score(0.0)
    if base is None or not math.isfinite(base):
        return 0.0, {}
    scores = {0.0: base}
    for tau in sorted({max(float(t), period) for t in grid}):
        s = score(float(tau))[0]
        scores[float(tau)] = math.inf if s is None or not math.isfinite(s) else s
        if scores[float(tau)] > min(scores.values()):
            break  # past the best: the score rises on both sides of a lag it measures
    taus = sorted(scores)
    best = refine_minimum(taus, [scores[t] for t in taus])
    if best > 0.0:
        best = max(best, period)
    if best > 0.0 and best not in scores:
        s = score(best)[0]
        scores[best] = math.inf if s is None or not math.isfinite(s) else s
    # The grid's last lag only brackets a minimum below it: a score still falling there
    # measures no lag, so the best of the others stands (as before the grid reached it).
    top = max(float(t) for t in grid) if len(grid) else math.inf
    best = min((t for t in scores if t < max(top, period)), key=scores.get)
    # Two standard errors: a lag is a second model of the same data, kept only on clear
    # evidence (a switch's step that no rule integrates exactly can pass for a small lag).
    margin = 2.0 * error if math.isfinite(error) else 0.0
    if best == 0.0 or not scores[best] < base - margin:
        return 0.0, scores
    return best, scores
