"""Continuous joints' angles on the turn a model was learnt on.

A URDF ``continuous`` joint has no limits, and drivers report its angle modulo one turn
(often in ``[-pi, pi)``). A model learnt on joint positions knows the angles its
demonstrations passed through: a measurement one turn away from them is the same posture,
but to the policy it is a state nobody demonstrated (the extrapolation guard would stop the
robot there). The executor therefore moves each continuous joint's measured angle by whole
turns to within half a turn of the middle of the model's support along that joint
(:func:`turn_centres`, :func:`nearest_turn`), before the policy, the guard and the limits
see it. Kinematics do not care: Pinocchio configures a continuous joint by its cosine and
sine (:class:`~policy_align_ros.kinematics.robot.Robot`).

The learn pipeline does the same for the demonstrations
(:func:`~policy_align_ros.data.turns.unwrap_turns`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["TURN", "nearest_turn", "turn_centres", "wrap_continuous"]

#: One turn (rad).
TURN = 2.0 * math.pi


def turn_centres(support: np.ndarray, continuous: np.ndarray,
                 permutation: np.ndarray | None = None) -> np.ndarray | None:
    """The angle each continuous joint's measurements are brought near (rad).

    Parameters
    ----------
    support : ndarray, shape (m, n)
        The model's support states (``PolicyAlign.support_states_``), joint positions in
        model order (rad or m).
    continuous : array_like of bool, shape (n,)
        Which controller joints are continuous (``Robot.continuous``).
    permutation : array_like of int, shape (n,), optional
        ``q[permutation]`` is ``q`` in model order; identity when omitted.

    Returns
    -------
    ndarray, shape (n,) or None
        In controller order: the middle of the support's range along each continuous joint,
        NaN for the others; None when no joint is continuous.
    """
    continuous = np.asarray(continuous, dtype=bool)
    if not continuous.any():
        return None
    support = np.asarray(support, dtype=float)
    n = continuous.shape[0]
    if support.ndim != 2 or support.shape[1] != n or not len(support):
        raise ValueError(f"support: expected a non-empty (m, {n}) array, got shape "
                         f"{support.shape}")
    p = np.arange(n) if permutation is None else np.asarray(permutation, dtype=int)
    middle = np.empty(n)
    middle[p] = 0.5 * (support.min(axis=0) + support.max(axis=0))
    return np.where(continuous, middle, np.nan)


def nearest_turn(q: np.ndarray, centres: np.ndarray | None) -> np.ndarray:
    """``q`` (n,) with each joint whose centre is finite moved by whole turns to within half
    a turn of it (rad); ``q`` itself when ``centres`` is None."""
    if centres is None:
        return q
    turns = np.round((np.nan_to_num(centres, nan=0.0) - q) / TURN)
    return np.where(np.isfinite(centres), q + TURN * turns, q)


def wrap_continuous(q: np.ndarray, continuous: np.ndarray) -> np.ndarray:
    """Continuous joints' angles on ``[-pi, pi)``, as a real driver reports them.

    Parameters
    ----------
    q : array_like, shape (..., n)
        Joint positions (rad for the continuous joints).
    continuous : array_like of bool, shape (n,)
        Which joints are continuous (:attr:`policy_align_ros.kinematics.Robot.continuous`).

    Returns
    -------
    ndarray, shape (..., n)
        A copy of ``q`` with each continuous coordinate replaced by
        ``(q + pi) mod 2 pi - pi``; the other coordinates unchanged. Applied to a
        difference ``q - q_ref``, it gives the shortest angle from ``q_ref`` to ``q``.
    """
    out = np.array(q, dtype=float)
    mask = np.broadcast_to(np.asarray(continuous, dtype=bool), out.shape)
    wrapped = np.mod(out + np.pi, TURN) - np.pi
    # mod of a tiny negative number rounds up to a whole turn, which would give +pi.
    wrapped = np.where(wrapped >= np.pi, wrapped - TURN, wrapped)
    return np.where(mask, wrapped, out)
