"""Exact flows of a quadratic potential, the learning tests' shared demonstrations, and
the potentials their goal and descent tests know the minima of."""

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


def bowl(A: np.ndarray, c: np.ndarray):
    """The potential ``0.5 (x - c)' A (x - c)`` and its gradient, as callables of states
    (m, n)."""
    def potential(X):
        D = X - c
        return 0.5 * np.einsum("ij,jk,ik->i", D, A, D)

    def gradient(X):
        return (X - c) @ A

    return potential, gradient


def two_wells():
    """A shallow bowl with two Gaussian wells at (-1, 0) and (1, 0): its potential and
    gradient, with a minimum in each well."""
    wells = np.array([[-1.0, 0.0], [1.0, 0.0]])

    def potential(X):
        d2 = np.sum((X[:, None, :] - wells[None]) ** 2, axis=2)
        return 0.05 * np.sum(X**2, axis=1) - np.exp(-d2 / 0.2).sum(axis=1)

    def gradient(X):
        D = X[:, None, :] - wells[None]
        e = np.exp(-np.sum(D**2, axis=2) / 0.2)
        return 0.1 * X + np.einsum("mk,mkn->mn", e, D) / 0.1

    return potential, gradient
