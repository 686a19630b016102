"""The learnt goal, and whether re-timing one demonstration moves it.

A demonstration re-timed by a monotone warp of its time axis has the same geometry: the
potential a teacher follows is the same, so the learnt minimum should not move.
:func:`retiming_shift` measures by how much it does, relative to the data's extent.

Usage: ``python -m policy_align_ros.experiments.retiming --cases human_timing_2,bumps_2
[--seed 0] [--datasets 3]`` prints one Markdown table of the shifts (demonstration 0
re-timed by :func:`smoothstep_warp`); beside them, for scale, the shift when that
demonstration is left out instead, and the kernel residual each fit's cross-validation
chose (:func:`cv_residual`).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence

import numpy as np
from scipy.optimize import minimize

from policy_align_ros.learning import PolicyAlign, Trajectory
from policy_align_ros.learning.goal import data_extent

__all__ = ["cv_residual", "data_extent", "learnt_minimum", "retime", "retiming_shift",
           "smoothstep_warp"]

#: ``warp(s (N,)) -> (N,)``: a monotone map of ``[0, 1]`` onto itself (normalised time).
Warp = Callable[[np.ndarray], np.ndarray]


def learnt_minimum(model, start: np.ndarray) -> np.ndarray:
    """Descend the learnt potential from ``start`` to its local minimum.

    Parameters
    ----------
    model : fitted estimator with ``potential(X (m, n)) -> (m,)`` and
        ``policy(X) -> (m, n) = -grad potential``
    start : numpy.ndarray, shape (n,)
        For example the expert's end point, state units.

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    res = minimize(lambda x: float(model.potential(x[None])[0]),
                   np.asarray(start, dtype=float),
                   jac=lambda x: -np.asarray(model.policy(x[None])[0], dtype=float),
                   method="L-BFGS-B", options={"gtol": 1e-9, "ftol": 1e-13, "maxiter": 1000})
    return res.x


def smoothstep_warp(s: np.ndarray) -> np.ndarray:
    """``3 s^2 - 2 s^3``: slow at both ends, fast in the middle (monotone on [0, 1])."""
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def retime(traj: Trajectory, warp: Warp) -> Trajectory:
    """``traj``'s path travelled on a warped clock, recorded at the same stamps.

    The sample stamped at normalised time ``u`` shows the state the demonstration had at
    normalised time ``warp(u)`` (linear interpolation between its samples): the same
    path, start, end, duration and sample rate, with the speed along the path multiplied
    by ``warp'(u)``. Recorded velocities follow by the chain rule,
    ``v(warp(u)) warp'(u)``. (Moving the stamps instead, ``t0 + T warp(u)``, inverts the
    speed change and, for a warp with ``warp' = 0`` at an end, makes the first step
    infinitely fast, which no recorder produces.)

    Parameters
    ----------
    traj : Trajectory
        With stamps (``times`` not None).
    warp : callable
        Strictly increasing on the samples' normalised times, ``warp(0) = 0``,
        ``warp(1) = 1``.

    Returns
    -------
    Trajectory
    """
    if traj.times is None:
        raise ValueError(f"traj {traj.name!r}: has no stamps to re-time")
    t = traj.times
    span = float(t[-1] - t[0])
    u = (t - t[0]) / span
    s = np.asarray(warp(u), dtype=float)
    if s.shape != u.shape or np.any(np.diff(s) <= 0) or abs(s[0]) > 1e-12 \
            or abs(s[-1] - 1.0) > 1e-12:
        raise ValueError("warp: must map the samples' normalised times [0, 1] onto [0, 1], "
                         "strictly increasing")
    X = np.stack([np.interp(s, u, x) for x in traj.positions.T], axis=1)
    v = traj.velocities
    if v is not None:
        slope = np.gradient(s, u)
        v = np.stack([np.interp(s, u, c) for c in v.T], axis=1) * slope[:, None]
    return Trajectory(X, t.copy(), v, name=traj.name)


def retiming_shift(model_factory: Callable[[], PolicyAlign], trajs: Sequence[Trajectory],
                   k: int, warp: Warp, start: np.ndarray | None = None) -> float:
    """How far re-timing demonstration ``k`` moves the learnt minimum, over the extent.

    Parameters
    ----------
    model_factory : callable ``() -> estimator``
        A fresh unfitted model, for example ``PolicyAlign``.
    trajs : sequence of Trajectory
        The demonstrations.
    k : int
        The demonstration re-timed.
    warp : callable
        A monotone warp of normalised time (see :func:`retime`).
    start : numpy.ndarray (n,), optional
        Where both descents start (default: the mean of the demonstrations' end points).

    Returns
    -------
    float
        ``|m_warped - m| / data_extent(trajs)``, with ``m`` the learnt minimum.
    """
    base, warped = _retimed_fits(model_factory, trajs, k, warp, start)[2:]
    return float(np.linalg.norm(warped - base) / data_extent(trajs))


def _descent_start(trajs: Sequence[Trajectory], start: np.ndarray | None) -> np.ndarray:
    """``start``, or the mean of the demonstrations' end points (state units)."""
    return (np.mean([t.positions[-1] for t in trajs], axis=0) if start is None
            else np.asarray(start, dtype=float))


def _retimed_fits(model_factory: Callable[[], PolicyAlign], trajs: Sequence[Trajectory],
                  k: int, warp: Warp, start: np.ndarray | None = None
                  ) -> tuple[PolicyAlign, PolicyAlign, np.ndarray, np.ndarray]:
    """The fits :func:`retiming_shift` compares (as given, then with demonstration ``k``
    re-timed) and their learnt minima, descended from :func:`_descent_start`."""
    if not 0 <= k < len(trajs):
        raise ValueError(f"k: must index one of the {len(trajs)} demonstrations, got {k}")
    x0 = _descent_start(trajs, start)
    base_model = model_factory().fit(list(trajs))
    warped = list(trajs)
    warped[k] = retime(trajs[k], warp)
    warped_model = model_factory().fit(warped)
    return (base_model, warped_model, learnt_minimum(base_model, x0),
            learnt_minimum(warped_model, x0))


def cv_residual(model) -> float | None:
    """The length scale of the kernel residual a fit's cross-validation chose (standardised
    state units), None for the trend alone, NaN for a regressor without that choice."""
    best = getattr(getattr(model, "regressor_", None), "cv_best_", None)
    if best is None:
        return math.nan
    _, _, length, kernel_ridge, _ = best
    return float(length) if math.isfinite(kernel_ridge) else None


def _residual_text(length: float | None) -> str:
    return "none" if length is None else "-" if math.isnan(length) else f"l={length:.3g}"


def _shift_task(task: tuple[str, int]) -> dict:
    from policy_align_ros.experiments import suite

    name, seed = task
    rng = np.random.default_rng(seed)
    problem = suite.ALL_CASES[name].make(rng)
    demos = suite._demos(problem, problem.sample_starts(rng, problem.n_train), rng)
    trajs = [d.trajectory for d in demos]
    base, warped, base_min, warped_min = _retimed_fits(
        lambda: PolicyAlign(random_state=seed), trajs, 0, smoothstep_warp)
    # For scale: how far the minimum moves when the demonstration is left out instead.
    without = PolicyAlign(random_state=seed).fit(trajs[1:])
    without_min = learnt_minimum(without, _descent_start(trajs, None))
    extent = data_extent(trajs)
    return {"case": name, "seed": seed,
            "shift": float(np.linalg.norm(warped_min - base_min) / extent),
            "left_out": float(np.linalg.norm(without_min - base_min) / extent),
            "residual": cv_residual(base), "residual_retimed": cv_residual(warped)}


def main(argv: Sequence[str] | None = None) -> int:
    """Print the re-timing shifts of ``--cases`` over ``--datasets`` seeds."""
    from policy_align_ros.experiments import suite
    from policy_align_ros.experiments.pool import parallel_map

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="human_timing_2,bumps_2")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--datasets", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=1)
    args = parser.parse_args(argv)
    names = args.cases.split(",")
    unknown = [c for c in names if c not in suite.ALL_CASES]
    if unknown:
        raise ValueError(f"--cases: unknown case(s) {unknown}")
    tasks = [(c, args.seed + i) for c in names for i in range(args.datasets)]
    rows = parallel_map(_shift_task, tasks, args.jobs, "retiming")
    print("| case | seed | learnt-minimum shift / data extent | the same, demonstration 0 left "
          "out | CV's residual: as given / re-timed |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['seed']} | {100 * r['shift']:.2f} % | "
              f"{100 * r['left_out']:.2f} % | {_residual_text(r['residual'])} / "
              f"{_residual_text(r['residual_retimed'])} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
