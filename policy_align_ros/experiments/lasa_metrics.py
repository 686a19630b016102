"""The LASA benchmark's measures: workspace size, rollouts, velocity error, DTW, convergence.

Units follow the data set: positions in mm, velocities in mm/s, times in s. A policy is
any callable ``policy(X) -> V`` mapping states ``(m, 2)`` to velocities ``(m, 2)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["euler_ends", "workspace_size", "euler_rollout", "velocity_error", "across_error",
           "dtw_mean_cost", "converged", "CONVERGED_FRACTION"]

#: A rollout has converged when it ends closer to the goal than this fraction of W.
CONVERGED_FRACTION = 0.01

Policy = Callable[[np.ndarray], np.ndarray]


def workspace_size(positions: Sequence[np.ndarray]) -> float:
    """W: the largest side of the bounding box of a shape's demonstrations.

    Parameters
    ----------
    positions : sequence of ndarray, each shape (N_k, d)
        The demonstrations' positions (mm).

    Returns
    -------
    float
        The largest side (mm).
    """
    if len(positions) == 0:
        raise ValueError("positions: need at least one demonstration")
    stacked = np.concatenate([np.asarray(p, dtype=float) for p in positions])
    return float(np.max(stacked.max(axis=0) - stacked.min(axis=0)))


def _check_steps(dt: float, steps: int) -> None:
    """ValueError unless ``dt`` is a finite number > 0 and ``steps`` >= 0."""
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a finite number > 0, got {dt}")
    if steps < 0:
        raise ValueError(f"steps: must be >= 0, got {steps}")


def euler_rollout(policy: Policy, x0: np.ndarray, dt: float, steps: int) -> np.ndarray:
    """Explicit Euler ``x <- x + dt policy(x)`` from ``x0``.

    Parameters
    ----------
    policy : callable
        ``policy(X)`` with ``X`` (1, d) returns (1, d) velocities (mm/s).
    x0 : ndarray, shape (d,)
        Start (mm).
    dt : float
        Step (s), > 0.
    steps : int
        Number of steps, >= 0.

    Returns
    -------
    ndarray, shape (steps + 1, d)
        The path, ``x0`` first (mm). Once a state is not finite the rest of the path is
        NaN (a diverged field).
    """
    _check_steps(dt, steps)
    x = np.asarray(x0, dtype=float).reshape(1, -1).copy()
    path = np.full((steps + 1, x.shape[1]), np.nan)
    path[0] = x[0]
    for i in range(steps):
        x = x + dt * np.asarray(policy(x), dtype=float).reshape(1, -1)
        if not np.all(np.isfinite(x)):
            break
        path[i + 1] = x[0]
    return path


def euler_ends(policy: Policy, X0: np.ndarray, dt: float, steps: int) -> np.ndarray:
    """Where :func:`euler_rollout`'s runs from every row of ``X0`` (m, d) end, all run at
    once (``policy`` takes and returns (m, d)): (m, d), NaN for a run whose state stopped
    being finite (a diverged field)."""
    _check_steps(dt, steps)
    X = np.array(X0, dtype=float, ndmin=2)
    alive = np.ones(len(X), dtype=bool)
    with np.errstate(all="ignore"):
        for _ in range(steps):
            if not alive.any():
                break
            X[alive] += dt * np.asarray(policy(X[alive]), dtype=float)
            alive &= np.all(np.isfinite(X), axis=1)
    X[~alive] = np.nan
    return X


def velocity_error(predicted: np.ndarray, velocities: np.ndarray) -> float:
    """nV: ``RMS |f(x_i) - v_i| / RMS |v_i|``.

    Parameters
    ----------
    predicted : ndarray, shape (N, d)
        The policy at the demonstration's samples (mm/s).
    velocities : ndarray, shape (N, d)
        The recorded velocities there (mm/s).

    Returns
    -------
    float
        0 for a perfect field, 1 for the zero policy.
    """
    predicted, velocities, scale = _checked(predicted, velocities)
    return float(np.sqrt(np.mean(np.sum((predicted - velocities) ** 2, axis=1))) / scale)


def _checked(predicted, velocities) -> tuple[np.ndarray, np.ndarray, float]:
    """Both as float arrays of one (N, d) shape, and ``RMS |v_i|`` (> 0)."""
    predicted, velocities = np.asarray(predicted, float), np.asarray(velocities, float)
    if predicted.shape != velocities.shape or predicted.ndim != 2:
        raise ValueError(f"predicted {predicted.shape} and velocities {velocities.shape}: "
                         "must be equal (N, d) arrays")
    scale = float(np.sqrt(np.mean(np.sum(velocities**2, axis=1))))
    if scale == 0.0:
        raise ValueError("velocities: all zero, nV is undefined")
    return predicted, velocities, scale


def across_error(predicted: np.ndarray, velocities: np.ndarray) -> float:
    """The part of nV across the demonstrated motion: ``RMS |(I - u_i u_i') f(x_i)| /
    RMS |v_i|``, ``u_i = v_i / |v_i|`` (samples at rest count with ``|f(x_i)|``).

    A gradient field that follows the demonstrations' paths scores 0 whatever its speed
    along them; a field bent across the paths scores its bend.

    Parameters
    ----------
    predicted, velocities : ndarray, shape (N, d)
        As :func:`velocity_error` (mm/s).

    Returns
    -------
    float
    """
    predicted, velocities, scale = _checked(predicted, velocities)
    speed = np.linalg.norm(velocities, axis=1)
    unit = np.divide(velocities, speed[:, None], out=np.zeros_like(velocities),
                     where=speed[:, None] > 0)
    across = predicted - np.sum(predicted * unit, axis=1)[:, None] * unit
    return float(np.sqrt(np.mean(np.sum(across**2, axis=1))) / scale)


def _dtw_cumulative(cost: np.ndarray) -> np.ndarray:
    """Cumulative DTW cost ``D[i, j] = c[i, j] + min(D[i-1, j-1], D[i-1, j], D[i, j-1])``.

    Row by row: with ``t[j] = c[i, j] + min(D[i-1, j-1], D[i-1, j])`` the in-row
    recursion ``D[i, j] = min(t[j], c[i, j] + D[i, j-1])`` unrolls to
    ``C[j] + min_{k <= j} (t[k] - C[k])`` with ``C`` the row's cumulative cost, a running
    minimum numpy computes at once.
    """
    n, m = cost.shape
    D = np.empty((n, m))
    D[0] = np.cumsum(cost[0])
    for i in range(1, n):
        prev = D[i - 1]
        diag = np.concatenate(([np.inf], prev[:-1]))
        t = cost[i] + np.minimum(diag, prev)
        C = np.cumsum(cost[i])
        D[i] = C + np.minimum.accumulate(t - C)
    return D


def dtw_mean_cost(a: np.ndarray, b: np.ndarray) -> float:
    """Mean Euclidean cost along the optimal dynamic-time-warping path between two paths.

    Parameters
    ----------
    a : ndarray, shape (n, d)
        First path (mm).
    b : ndarray, shape (m, d)
        Second path (mm); NaN rows (a diverged rollout) make the result infinite.

    Returns
    -------
    float
        Total cost of the optimal path (steps (1,1), (1,0), (0,1), from the first pair to
        the last) over its number of pairs (mm).
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1] or not len(a) or not len(b):
        raise ValueError(f"a {a.shape} and b {b.shape}: must be non-empty (n, d) and (m, d)")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return float("inf")
    cost = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    D = _dtw_cumulative(cost)
    i, j, length = len(a) - 1, len(b) - 1, 1
    while i > 0 or j > 0:
        # Step back to the predecessor the recursion took; ties prefer the diagonal.
        options = []
        if i > 0 and j > 0:
            options.append((D[i - 1, j - 1], i - 1, j - 1))
        if i > 0:
            options.append((D[i - 1, j], i - 1, j))
        if j > 0:
            options.append((D[i, j - 1], i, j - 1))
        _, i, j = min(options, key=lambda o: o[0])
        length += 1
    return float(D[-1, -1] / length)


def converged(final: np.ndarray, goal: np.ndarray, width: float) -> bool:
    """The convergence rule: ``|x(3T) - goal| < CONVERGED_FRACTION * W``.

    Parameters
    ----------
    final : ndarray, shape (d,)
        The rollout's last state (mm); not finite counts as not converged.
    goal : ndarray, shape (d,)
        The goal (mm).
    width : float
        W (mm), > 0.
    """
    if not width > 0:
        raise ValueError(f"width: must be > 0, got {width}")
    distance = float(np.linalg.norm(np.asarray(final, float) - np.asarray(goal, float)))
    return bool(np.isfinite(distance) and distance < CONVERGED_FRACTION * width)
