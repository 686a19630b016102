"""Demonstrated trajectories and their validation.

Notation (paper, section III): a trajectory ``k`` is a sequence of states
``x_k1 ... x_kN`` in ``R^n`` sampled at times ``t_1 < ... < t_N`` (seconds). When no
times are given, the paper's convention ``dt = 1`` is used, so velocities and the learnt
policy are in state units per step.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np

__all__ = ["Trajectory", "as_trajectories", "sample_period"]


class Trajectory:
    """One demonstration: states, optional sample times and optional velocities.

    Parameters
    ----------
    positions : array_like, shape (N, n)
        States ``x_i`` (for example joint positions in rad or hand positions in m).
    times : array_like, shape (N,), optional
        Strictly increasing sample times in seconds. ``None`` means ``dt = 1``.
    velocities : array_like, shape (N, n), optional
        Measured ``xdot_i`` in state units per second (per step without times). Used by the
        trapezoid potential estimate; the Euler estimate needs positions only.
    name : str, optional
        Label used in error messages (defaults to the index in a fit).

    Raises
    ------
    ValueError
        On a wrong shape, fewer than 2 samples, NaN/inf, or times that do not increase
        strictly. The message names the trajectory and the problem.
    """

    def __init__(
        self,
        positions: np.ndarray,
        times: np.ndarray | None = None,
        velocities: np.ndarray | None = None,
        *,
        name: str | None = None,
    ) -> None:
        label = "trajectory" if name is None else f"trajectory {name}"
        q = np.asarray(positions, dtype=float)
        if q.ndim != 2:
            raise ValueError(f"{label}: positions must have shape (N, n), got {q.shape}")
        if q.shape[0] < 2:
            raise ValueError(f"{label}: needs at least 2 samples, got {q.shape[0]}")
        if q.shape[1] < 1:
            raise ValueError(f"{label}: positions have zero columns")
        if not np.all(np.isfinite(q)):
            bad = int(np.argwhere(~np.isfinite(q))[0, 0])
            raise ValueError(f"{label}: positions contain NaN or inf (first at sample {bad})")
        t = None
        if times is not None:
            t = np.asarray(times, dtype=float)
            if t.shape != (q.shape[0],):
                raise ValueError(
                    f"{label}: times must have shape ({q.shape[0]},), got {t.shape}"
                )
            if not np.all(np.isfinite(t)):
                raise ValueError(f"{label}: times contain NaN or inf")
            steps = np.diff(t)
            if np.any(steps <= 0):
                bad = int(np.argmax(steps <= 0))
                raise ValueError(
                    f"{label}: times must increase strictly (t[{bad + 1}] <= t[{bad}])"
                )
        v = None
        if velocities is not None:
            v = np.asarray(velocities, dtype=float)
            if v.shape != q.shape:
                raise ValueError(
                    f"{label}: velocities must have the shape of positions {q.shape}, "
                    f"got {v.shape}"
                )
            if not np.all(np.isfinite(v)):
                raise ValueError(f"{label}: velocities contain NaN or inf")
        self.positions = q
        self.times = t
        self.velocities = v
        self.name = name

    @property
    def n_samples(self) -> int:
        """Number of samples ``N``."""
        return self.positions.shape[0]

    @property
    def n_dims(self) -> int:
        """State dimension ``n``."""
        return self.positions.shape[1]

    @property
    def dt(self) -> np.ndarray:
        """Time steps ``t_{i+1} - t_i``, shape (N-1,); ones without times."""
        if self.times is None:
            return np.ones(self.n_samples - 1)
        return np.diff(self.times)

    @property
    def duration(self) -> float:
        """``t_{N-1} - t_0`` (s); ``N - 1`` steps without times."""
        if self.times is None:
            return float(self.n_samples - 1)
        return float(self.times[-1] - self.times[0])

    def velocity_estimate(self) -> np.ndarray:
        """``xdot_i`` (N, n): the recorded velocities when there are any, else central
        differences of the positions over the times (one-sided at the ends; per step
        without times)."""
        if self.velocities is not None:
            return self.velocities
        steps = np.arange(self.n_samples) if self.times is None else self.times
        return np.gradient(self.positions, steps, axis=0)

    def __len__(self) -> int:
        return self.n_samples

    def __repr__(self) -> str:
        timing = "dt=1" if self.times is None else f"T={self.duration:.3g}s"
        return f"Trajectory(N={self.n_samples}, n={self.n_dims}, {timing})"


def as_trajectories(data: Sequence[Trajectory | np.ndarray]) -> list[Trajectory]:
    """Validate a collection of demonstrations and convert plain arrays.

    Parameters
    ----------
    data : sequence of Trajectory or array_like of shape (N_k, n)
        The demonstrations. Plain arrays are taken as positions with ``dt = 1``.

    Returns
    -------
    list of Trajectory
        One per input, all of the same state dimension ``n``. A Trajectory given without
        a name comes back as a shallow copy named by its index (``"3"``), so that later
        errors name it; the caller's object is not modified. Named ones are returned as
        given.

    Raises
    ------
    ValueError
        If the collection is empty, an item is invalid, or the dimensions disagree. The
        message names the trajectory index.
    """
    if isinstance(data, (np.ndarray, Trajectory)):
        raise ValueError(
            "expected a sequence of trajectories (a list of Trajectory or (N, n) arrays), "
            "got a single " + type(data).__name__
        )
    items = list(data)
    if not items:
        raise ValueError("no trajectories given")
    out: list[Trajectory] = []
    for k, item in enumerate(items):
        if isinstance(item, Trajectory):
            traj = item
            if traj.name is None:
                # A copy sharing the arrays: the caller's object keeps its own (no) name.
                traj = copy.copy(item)
                traj.name = str(k)
        else:
            try:
                traj = Trajectory(item, name=str(k))
            except ValueError as err:
                raise ValueError(f"trajectory {k}: {_strip_label(err)}") from None
        out.append(traj)
    n = out[0].n_dims
    for k, traj in enumerate(out):
        if traj.n_dims != n:
            raise ValueError(
                f"trajectory {k}: has dimension {traj.n_dims}, but trajectory 0 has {n}"
            )
    timed = [traj.times is not None for traj in out]
    if any(timed) and not all(timed):
        k = timed.index(not timed[0])
        raise ValueError(
            f"trajectory {k}: mixes timed and untimed trajectories (trajectory 0 "
            f"{'has' if timed[0] else 'has no'} times); give times for all or none"
        )
    return out


def sample_period(trajs: Sequence[Trajectory]) -> float:
    """The median time step over all samples of ``trajs`` (s; 1 without times)."""
    return float(np.median(np.concatenate([t.dt for t in trajs])))


def _strip_label(err: ValueError) -> str:
    text = str(err)
    return text.split(": ", 1)[1] if ": " in text else text
