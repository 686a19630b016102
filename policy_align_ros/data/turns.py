"""Continuous joints' recorded angles on one turn.

A driver reports a continuous joint's angle modulo one turn: a demonstration that passes
``pi`` jumps by ``2 pi`` between two samples, and two demonstrations on either side of it
lie a turn apart although the arm was in the same posture. Learnt as they are, the jump is
a motion of hundreds of rad/s and the two sides two places. :func:`unwrap_turns` makes each
demonstration's angle continuous in time (``numpy.unwrap``) and moves each demonstration by
whole turns to within half a turn of the angles' circular mean over all demonstrations.
The executor brings its measurements to the same turn
(:mod:`policy_align_ros.control.turns`). Where the joints' kinds are unknown (no robot),
or a joint the robot does not call continuous jumps, :func:`check_jumps` refuses the data;
so it does a step faster than :data:`JUMP_SPEED_FACTOR` times the joint's velocity limit
(a reset or a glitch in the recording: the robot cannot have moved so).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["JUMP_SPEED_FACTOR", "check_jumps", "unwrap_turns"]

#: A step faster than this many times its joint's velocity limit (over the demonstration's
#: median sample period at least, so that jittered stamps do not make one) is a jump the
#: robot did not make. Wide: a URDF's limits are sometimes lower than what the joint does.
JUMP_SPEED_FACTOR = 10.0


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
        X[:, columns] += math.tau * np.round((reference - X[:, columns].mean(axis=0)) / math.tau)
        out.append(Trajectory(X, t.times, t.velocities, name=t.name))
    return out


def check_jumps(trajs: Sequence[Trajectory], names: Sequence[str], joints: Sequence[str],
                robot: str | None, velocity_limit: np.ndarray | None = None) -> None:
    """Refuse demonstrations in which a joint moves by more than half a turn between two
    samples: no joint does that; a continuous joint reported modulo a turn, and not
    unwrapped, does. With the joints' velocity limits, refuse a step faster than
    :data:`JUMP_SPEED_FACTOR` times its joint's limit too.

    Parameters
    ----------
    trajs : sequence of Trajectory
        Joint-position demonstrations (rad, or m for prismatic joints).
    names : sequence of str
        The demonstrations' names, as the error gives them.
    joints : sequence of str
        The joints of the positions' columns.
    robot : str or None
        The robot the joints' kinds came from (None: unknown).
    velocity_limit : numpy.ndarray, shape (n,), optional
        The joints' velocity limits (rad/s or m/s; those not finite and positive are not
        checked).

    Raises
    ------
    ValueError
        Naming the joint, the demonstration, the jump and the fix.
    """
    all_steps = [np.abs(np.diff(traj.positions, axis=0)) for traj in trajs]
    for steps, name in zip(all_steps, names, strict=True):
        if not steps.size or steps.max() <= math.pi:
            continue
        i, j = np.unravel_index(int(np.argmax(steps)), steps.shape)
        fix = ("give the robot (--robot, --robot-config; the learner's robot or "
               "robot_config) so that its continuous joints are unwrapped" if not robot else
               f"it is not a continuous joint of {robot}: a glitch in the recording? leave "
               "the demonstration out")
        raise ValueError(f"joint {joints[j]}: moves by {steps[i, j]:.3g} between two samples "
                         f"of demonstration {name} (more than half a turn): a continuous "
                         f"joint reported modulo a turn? {fix}")
    if velocity_limit is not None:
        limit = np.asarray(velocity_limit, dtype=float)
        for traj, steps, name in zip(trajs, all_steps, names, strict=True):
            _check_speed(traj, steps, name, joints, robot, limit)


def _check_speed(traj: Trajectory, steps: np.ndarray, name: str, joints: Sequence[str],
                 robot: str | None, limit: np.ndarray) -> None:
    """Refuse a step of ``traj`` (``steps``, its absolute position steps) faster than
    :data:`JUMP_SPEED_FACTOR` times ``limit``.

    Each joint's change is timed from its previous change: a driver that publishes
    faster than its encoders are read repeats a position and then steps, which is no
    jump."""
    if not steps.size:
        return
    t = np.concatenate([[0.0], np.cumsum(traj.dt)])
    floor = float(np.median(traj.dt))
    worst = (0.0, 0, 0, 0.0)  # (times the limit, step, joint, time taken)
    for j in np.flatnonzero(np.isfinite(limit) & (limit > 0.0)):
        moved = np.flatnonzero(steps[:, j] > 0.0)
        if not moved.size:
            continue
        since = t[np.concatenate([[0], moved[:-1] + 1])]  # the previous change's sample
        taken = np.maximum(t[moved + 1] - since, floor)
        ratio = steps[moved, j] / taken / limit[j]
        k = int(np.argmax(ratio))
        if ratio[k] > worst[0]:
            worst = (float(ratio[k]), int(moved[k]), int(j), float(taken[k]))
    over, i, j, taken = worst
    if over <= JUMP_SPEED_FACTOR:
        return
    raise ValueError(
        f"joint {joints[j]}: moves by {steps[i, j]:.3g} in {1e3 * taken:.3g} ms at "
        f"{t[i]:.3f} s into demonstration {name}, {over:.0f} "
        f"times its velocity limit {limit[j]:g} in {robot}: a reset or a glitch in the "
        "recording? leave the demonstration out")
