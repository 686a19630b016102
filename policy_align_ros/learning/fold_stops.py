"""Where the CV folds' models stop a run, against where the model stops it: a run's own
check of the learnt potential, for a start and a constraint the fit never saw.

Under a constraint the demonstrations never showed, a run of the learnt policy settles
where the learnt potential is lowest on the constraint. There the potential may be an
extrapolation across the demonstrated paths, and nothing in the fit's held-out errors
says so. Each CV fold's model was fitted without some demonstrations; where they stop the
same run elsewhere than the model does, the stop depends on which demonstrations were
kept, and the model's own stop is uncertain by as much.

:func:`stop_spread` runs the model and every fold model (``PolicyAlign.fold_regressors_``)
from one start, under the caller's projection, until each run has stopped
(:data:`SETTLED_SPEED`) or :data:`MAX_CHECK_DURATIONS` have passed, and gives the largest
distance of a fold's stop from the model's over the run's travel. Above
:data:`STOP_SPREAD_LIMIT` the stop is uncertain. ``docs/design/fold_stops.md`` gives the
measurement behind the limit.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["MAX_CHECK_DURATIONS", "SETTLED_SPEED", "STEPS_PER_DURATION", "STOP_SPREAD_LIMIT",
           "StopSpread", "check_horizon", "settle", "settled_speed", "spread_of",
           "stop_spread", "typical_speed"]

#: The folds' stops spread over more than this share of the run's travel: uncertain. Read
#: on tuning seeds (docs/design/fold_stops.md).
STOP_SPREAD_LIMIT = 0.05
#: A checked run has stopped once its speed is at most this share of the demonstrations'
#: typical speed (:func:`settled_speed`): the stops compared are stops, not places that
#: slow runs have reached.
SETTLED_SPEED = 0.01
#: Euler steps per typical duration of the demonstrations (their extent over their
#: typical speed, :func:`check_horizon`).
STEPS_PER_DURATION = 100
#: A checked run that has not stopped after this many typical durations ends there.
MAX_CHECK_DURATIONS = 12

Field = Callable[[np.ndarray], np.ndarray]
Projection = Callable[[np.ndarray, int, np.ndarray], np.ndarray]


@dataclasses.dataclass(frozen=True)
class StopSpread:
    """What :func:`stop_spread` found for one run.

    Attributes
    ----------
    stop : ndarray (n,)
        Where the model's run ends.
    fold_stops : ndarray (K, n)
        Where each fold model's run ends.
    travel : float
        The run's travel: the distance from its start to ``stop``, at least the
        ``floor`` given (state units).
    spread : float
        The largest distance of a fold's stop from ``stop`` over ``travel``; NaN
        without fold models.
    """

    stop: np.ndarray
    fold_stops: np.ndarray
    travel: float
    spread: float

    @property
    def uncertain(self) -> bool:
        """Whether the folds' stops spread over more than :data:`STOP_SPREAD_LIMIT` of
        the travel (False without fold models: nothing to tell)."""
        return bool(self.spread > STOP_SPREAD_LIMIT)


def _goal_report(model) -> dict:
    return (getattr(model, "fit_summary_", None) or {}).get("goal") or {}


def typical_speed(model) -> float | None:
    """The demonstrations' typical speed (state units/s) in ``model``'s goal report
    (``fit_summary_["goal"]``); None without one (a model file written before the goal
    report) or for an untimed model (its policy is per sample, not per second)."""
    speed = _goal_report(model).get("typical_speed")
    if not getattr(model, "timed_", False) or not isinstance(speed, (int, float)):
        return None
    return float(speed)


def check_horizon(model) -> tuple[float, int] | None:
    """The step (s) and the most steps of a checked run of ``model``: its data's typical
    duration (extent over typical speed, ``fit_summary_["goal"]``) in
    :data:`STEPS_PER_DURATION` steps, for at most :data:`MAX_CHECK_DURATIONS` durations.
    None when the summary lacks either (a model file written before the goal report) or
    the model is untimed (its policy is per sample, not per second)."""
    extent, speed = _goal_report(model).get("extent"), typical_speed(model)
    if not (speed is not None and isinstance(extent, (int, float)) and extent > 0.0
            and speed > 0.0 and np.isfinite(extent / speed)):
        return None
    return extent / speed / STEPS_PER_DURATION, MAX_CHECK_DURATIONS * STEPS_PER_DURATION


def settled_speed(model) -> float:
    """The speed (state units/s) below which a checked run of ``model`` has stopped:
    :data:`SETTLED_SPEED` times its demonstrations' typical speed (0 without one, or for
    an untimed model, whose policy is per sample: the runs last their steps)."""
    speed = typical_speed(model)
    return 0.0 if speed is None else SETTLED_SPEED * speed


def settle(policy: Field, x0: np.ndarray, dt: float, steps: int,
           project: Projection | None = None, settled: float = 0.0) -> np.ndarray:
    """Explicit Euler of ``policy`` from ``x0`` (n,): the state after ``steps`` steps of
    ``dt`` (s), or once the command's norm is at most ``settled`` (state units/s; 0: all
    the steps).

    ``policy(X (1, n)) -> (1, n)`` is in state units per s; ``project(x (n,), i, v (n,))
    -> (n,)`` projects the command at step ``i`` onto the constraint (None: free).
    """
    x = np.array(x0, dtype=float)
    for i in range(steps):
        v = policy(x[None])[0]
        if project is not None:
            v = project(x, i, v)
        if settled > 0.0 and np.linalg.norm(v) <= settled:
            break
        x = x + dt * v
    return x


def stop_spread(model, x0: np.ndarray, dt: float, steps: int,
                project: Projection | None = None, *, floor: float | None = None,
                settled: float | None = None) -> StopSpread:
    """The model's and its fold models' runs from ``x0``, and how far the folds' stops
    spread (:class:`StopSpread`).

    Parameters
    ----------
    model : PolicyAlign
        Fitted; its ``fold_regressors_`` (empty: the spread is NaN).
    x0 : ndarray (n,)
        The start, state units.
    dt : float
        Step (s), as the model's policy is per second (per step for an untimed model:
        give 1).
    steps : int
        Steps of each run at most.
    project : callable, optional
        As for :func:`settle`: the constraint in force.
    floor : float, optional
        The travel at least (state units): a start at the stop travels nowhere, and the
        folds' disagreement there is measured against this. Default: the model's
        ``support_spacing_``.
    settled : float, optional
        A run whose command's norm falls to this (state units/s) has stopped. Default:
        :func:`settled_speed`.

    Returns
    -------
    StopSpread
    """
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (model.n_features_in_,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"x0: must be {model.n_features_in_} finite numbers, got shape "
                         f"{x0.shape}")
    if not (dt > 0.0 and np.isfinite(dt)):
        raise ValueError(f"dt: must be finite and > 0, got {dt!r}")
    if int(steps) < 1:
        raise ValueError(f"steps: must be >= 1, got {steps!r}")
    settled = settled_speed(model) if settled is None else settled
    stop = settle(model.policy, x0, dt, int(steps), project, settled)
    folds: Sequence = getattr(model, "fold_regressors_", ())
    ends = [settle(_descent(r), x0, dt, int(steps), project, settled) for r in folds]
    return spread_of(x0, stop, ends, model.support_spacing_ if floor is None else floor)


def spread_of(x0: np.ndarray, stop: np.ndarray, fold_stops: Sequence[np.ndarray],
              floor: float) -> StopSpread:
    """The :class:`StopSpread` of a run from ``x0`` (n,) that the model stops at ``stop``
    (n,) and its fold models at ``fold_stops`` (K of (n,)), its travel at least ``floor``
    (state units)."""
    ends = np.array(fold_stops, dtype=float).reshape(len(fold_stops), len(x0))
    travel = max(float(np.linalg.norm(stop - x0)), float(floor), 1e-12)
    spread = (float(np.max(np.linalg.norm(ends - stop, axis=1))) / travel
              if len(ends) else float("nan"))
    return StopSpread(np.asarray(stop, dtype=float), ends, travel, spread)


def _descent(regressor) -> Field:
    """The fold model's policy, ``-grad f``, as the model's own (``PolicyAlign.policy``)."""
    return lambda X: -regressor.gradient(X)
