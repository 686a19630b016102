"""Which demonstrations train a model: copies found, content hashes, the hold-out split,
and which joints never move.

ROS-free; numpy and scipy only. States are arrays ``(N_k, n)`` in state units (rad or m).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

if TYPE_CHECKING:
    from policy_align_ros.learning import Trajectory

__all__ = ["CONSTANT_JOINT_FRACTION", "constant_joints", "find_duplicates", "fingerprint",
           "holdout_split"]

#: A joint whose range over every demonstration is at most this fraction of the widest
#: joint's range is constant: a gripper that never moves, or a joint held by its brake.
#: Its encoder noise (a few 1e-4 rad) stays below it for any arm motion over 0.5 rad.
CONSTANT_JOINT_FRACTION = 1e-3


def holdout_split(n_demos: int, fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """Indices of the training and held-out demonstrations (both sorted).

    At least one demonstration is held out when there are 3 or more and ``fraction > 0``,
    and at least two are always kept for training.
    """
    n_out = int(round(fraction * n_demos)) if n_demos >= 3 else 0
    if fraction > 0 and n_demos >= 3:
        n_out = min(max(n_out, 1), n_demos - 2)
    order = np.random.default_rng(seed).permutation(n_demos)
    return sorted(order[n_out:].tolist()), sorted(order[:n_out].tolist())


def find_duplicates(positions: Sequence[np.ndarray], tol: float = 1e-3) -> dict[int, int]:
    """Demonstrations that are near-identical copies of an earlier one.

    Parameters
    ----------
    positions : sequence of ndarray (N_k, n)
        The demonstrations' states.
    tol : float
        Relative tolerance: ``j`` duplicates ``i < j`` when the mean distance from each
        sample of either to the nearest sample of the other is at most
        ``tol * sqrt(sum_d var(X[:, d]))`` over all samples ``X``, and their first and last
        samples are that close too (a cheap pre-filter).

    Returns
    -------
    dict int -> int
        Index of each duplicate -> index of the first demonstration it copies.
    """
    arrays = [np.asarray(p, dtype=float) for p in positions]
    if len(arrays) < 2:
        return {}
    spread = math.sqrt(float(np.sum(np.var(np.concatenate(arrays), axis=0))))
    threshold = tol * (spread if spread > 0 else 1.0)
    starts = np.array([a[0] for a in arrays])
    ends = np.array([a[-1] for a in arrays])
    trees: dict[int, cKDTree] = {}

    def tree(k: int) -> cKDTree:
        if k not in trees:
            trees[k] = cKDTree(arrays[k])
        return trees[k]

    dup: dict[int, int] = {}
    for i in range(len(arrays)):
        if i in dup:
            continue
        near = np.flatnonzero(
            (np.linalg.norm(starts - starts[i], axis=1) <= threshold)
            & (np.linalg.norm(ends - ends[i], axis=1) <= threshold))
        for j in near[near > i]:
            j = int(j)
            if j in dup:
                continue
            d_ij = float(np.mean(tree(j).query(arrays[i])[0]))
            d_ji = float(np.mean(tree(i).query(arrays[j])[0]))
            if max(d_ij, d_ji) <= threshold:
                dup[j] = i
    return dup


def fingerprint(traj: Trajectory) -> str:
    """Content hash of a demonstration (positions and times), 16 hex digits.

    Names repeat across datasets (every recorder writes ``demo_0000``), so a model's
    training demonstrations are recognised by content.
    """
    digest = hashlib.sha256(np.ascontiguousarray(traj.positions, dtype=np.float64).tobytes())
    if traj.times is not None:
        digest.update(np.ascontiguousarray(traj.times, dtype=np.float64).tobytes())
    return digest.hexdigest()[:16]


def constant_joints(positions: Sequence[np.ndarray],
                    fraction: float = CONSTANT_JOINT_FRACTION) -> list[int]:
    """Columns that never move in any demonstration.

    Parameters
    ----------
    positions : sequence of ndarray (N_k, n)
        The demonstrations' joint positions (rad or m).
    fraction : float
        A column whose range (max - min over all samples of all demonstrations) is at most
        ``fraction`` times the largest column's range is constant.

    Returns
    -------
    list of int
        Indices of the constant columns, ascending; empty when every column is constant
        (nothing moves: there is no state to keep) or none is.
    """
    stacked = np.concatenate([np.asarray(p, dtype=float) for p in positions])
    ranges = np.ptp(stacked, axis=0)
    widest = float(np.max(ranges)) if ranges.size else 0.0
    if widest <= 0.0:
        return []
    return [int(k) for k in np.flatnonzero(ranges <= fraction * widest)]
