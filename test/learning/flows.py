"""Exact flows of a quadratic potential, the learning tests' shared demonstrations."""

from __future__ import annotations

import numpy as np

from policy_align_ros.learning import Trajectory


def quadratic_flow(A: np.ndarray, centre: np.ndarray, start: np.ndarray, steps: int,
                   dt: float, walk: float = 0.0,
                   rng: np.random.Generator | None = None) -> Trajectory:
    """The Euler flow of ``xdot = -A (x - centre)`` from ``start``, ``steps`` samples ``dt``
    apart; with ``walk``, each step is also pushed about by white noise of that standard
    deviation drawn from ``rng``."""
    x, X = np.asarray(start, dtype=float).copy(), []
    for _ in range(steps):
        X.append(x.copy())
        x = x - dt * A @ (x - centre)
        if walk:
            x = x + walk * rng.normal(size=x.shape)
    return Trajectory(np.array(X), times=dt * np.arange(steps))
