"""Missed control periods: a simulator tick that integrated a command it had already used.

A *missed control period* is a tick whose position step equals the previous tick's
(non-zero): no new command came within the period. The report's ``sim`` block counts them
for the executor runs and the recorded demonstrations.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SAME_STEP_TOL", "repeated_steps", "stale_ticks"]

#: Two position steps closer than this (rad) are the same command integrated twice:
#: rounding leaves ~1e-16; a new command differs by dt * (change of the command).
SAME_STEP_TOL = 1e-12


def repeated_steps(Q: np.ndarray) -> np.ndarray:
    """Which steps of a sampled trajectory ``Q`` (T, n) repeat the previous step.

    Returns
    -------
    ndarray of bool, shape (T - 2,)
        Entry ``i`` is True when ``Q[i+2] - Q[i+1]`` equals ``Q[i+1] - Q[i]`` (within
        :data:`SAME_STEP_TOL`, and non-zero): the simulator integrated the same command
        again, so the commanding node missed that control period. (The joint velocity in
        the message cannot tell: ``(q + dt v - q) / dt`` rounds differently every tick.)
    """
    D = np.diff(np.asarray(Q, dtype=float), axis=0)
    if len(D) < 2:
        return np.zeros(0, dtype=bool)
    same = np.all(np.abs(D[1:] - D[:-1]) <= SAME_STEP_TOL, axis=1)
    return same & np.any(np.abs(D[1:]) > SAME_STEP_TOL, axis=1)


def stale_ticks(trajectories: list) -> tuple[int, int]:
    """``(ticks, stale)`` of recorded demonstrations: steps, and repeated ones among them."""
    ticks = stale = 0
    for traj in trajectories:
        same = repeated_steps(traj.positions)
        ticks += len(same)
        stale += int(same.sum())
    return ticks, stale

