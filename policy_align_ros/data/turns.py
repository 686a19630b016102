"""Continuous joints' recorded angles on one turn.

A driver reports a continuous joint's angle modulo one turn: a demonstration that passes
``pi`` jumps by ``2 pi`` between two samples, and two demonstrations on either side of it
lie a turn apart although the arm was in the same posture. Learnt as they are, the jump is
a motion of hundreds of rad/s and the two sides two places. :func:`unwrap_turns` makes each
demonstration's angle continuous in time (``numpy.unwrap``) and moves each demonstration by
whole turns to within half a turn of the angles' circular mean over all demonstrations.
The executor brings its measurements to the same turn
(:mod:`policy_align_ros.control.turns`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["unwrap_turns"]

_TURN = 2.0 * np.pi


def unwrap_turns(trajs: Sequence[Trajectory], continuous: np.ndarray) -> list[Trajectory]:
    """The demonstrations with their continuous joints' angles on one turn.

    Parameters
    ----------
    trajs : sequence of Trajectory
        Joint-position demonstrations (rad for the continuous joints).
    continuous : array_like of bool, shape (n,)
        Which coordinates are continuous joints' angles.

    Returns
    -------
    list of Trajectory
        The same demonstrations (times, velocities and names kept), each continuous
        coordinate unwrapped in time and moved by whole turns to within half a turn of the
        circular mean of every sample's angle; ``trajs`` as they are without a continuous
        coordinate.
    """
    columns = np.flatnonzero(np.asarray(continuous, dtype=bool))
    if not len(columns):
        return list(trajs)
    angles = np.concatenate([t.positions[:, columns] for t in trajs])
    reference = np.arctan2(np.sin(angles).mean(axis=0), np.cos(angles).mean(axis=0))
    out = []
    for t in trajs:
        X = t.positions.copy()
        X[:, columns] = np.unwrap(X[:, columns], axis=0)
        X[:, columns] += _TURN * np.round((reference - X[:, columns].mean(axis=0)) / _TURN)
        out.append(Trajectory(X, t.times, t.velocities, name=t.name))
    return out
