"""The extrapolation guard: scale down commands that lead away from the demonstrated data.

With ``d(q)`` the distance of the model's state at ``q`` to the demonstrated data in
spacings of the training data, ``d_max`` the parameter ``max_extrapolation`` and ``b`` the
band, a command leading further out (``grad d . qdot > 0``) is scaled by
``g = clip(1 - (d - d_max) / b, 0, 1)``; motion back in is never scaled. ``b`` is at
least the stopping distance at ``max_velocity`` and ``max_acceleration`` (in spacings),
so a joint ramping down from full speed at ``d_max`` stops inside the band. A second
bound, ``max_extrapolation_rad``, caps ``d_max + b`` in joint space: the robot stops
within that many rad (2-norm) of the data, whatever the spacing of the data.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

__all__ = [
    "DEFAULT_MAX_EXTRAPOLATION",
    "DEFAULT_MAX_EXTRAPOLATION_RAD",
    "MIN_BAND",
    "DistanceFn",
    "ExtrapolationGuard",
    "FrameSupportDistance",
    "SupportDistance",
]

#: ``distance(q (n,)) -> (d, grad)``: see :class:`ExtrapolationGuard`.
DistanceFn = Callable[[np.ndarray], tuple[float, "np.ndarray | None"]]

#: Default ``max_extrapolation`` (spacings): beyond the farthest distance that runs from
#: new starts of the demonstrations' own distribution reach, so those stay unscaled.
DEFAULT_MAX_EXTRAPOLATION = 6.0
#: Default ``max_extrapolation_rad`` (rad, joint-space 2-norm): how far beyond the data a
#: wrong model may take the robot. On the Talos demonstrations, runs from new starts of
#: their own distribution start up to 1.8 rad from the data but only approach it, which is
#: never scaled. Sparser data are another matter: from a Panda's 8 free demonstrations,
#: 0.43-0.60 rad apart, 20 of 100 runs from their starts lead further out than the cap
#: and are held at the edge (docs/executor_safety.md).
DEFAULT_MAX_EXTRAPOLATION_RAD = 0.5
#: Smallest band of the guard (spacings), whatever the stopping distance.
MIN_BAND = 1.0


def _support_spacing(model) -> float:
    """``model.support_spacing_`` (> 0, finite); ValueError when the model has none."""
    spacing = float(getattr(model, "support_spacing_", float("nan")))
    if not (math.isfinite(spacing) and spacing > 0.0):
        raise ValueError("model: has no support states (support_spacing_ missing)")
    return spacing


def _nearest_support(model, x: np.ndarray, spacing: float
                     ) -> tuple[float, np.ndarray | None]:
    """``d`` (spacings) of the state ``x`` to ``model``'s support, and ``(x - s) / (|x - s|
    h)`` with ``s`` the nearest support state and ``h = spacing`` (None on the data)."""
    d, nearest = model.support_query(x[None, :])
    diff = x - nearest[0]
    r = float(np.linalg.norm(diff))
    if r == 0.0:
        return 0.0, None
    return float(d[0]), diff / (r * spacing)


class SupportDistance:
    """``d(q)`` and its gradient for a model learnt on joint positions (the guard's input).

    Parameters
    ----------
    model : PolicyAlign
        Fitted or loaded, with support states (its ``support_query``).
    permutation : array_like of int, shape (n,), optional
        From :func:`~policy_align_ros.control.joint_order.model_permutation`:
        ``q[permutation]`` is ``q`` in model order.

    Notes
    -----
    With ``x = q[permutation]``, ``s`` the nearest support state and ``h`` the spacing
    (``model.support_spacing_``), ``d = |x - s| / h`` and ``grad d = (x - s) / (|x - s|
    h)`` mapped back to controller order; ``|grad d| = 1 / h``.
    """

    def __init__(self, model, permutation: np.ndarray | None = None) -> None:
        self.spacing = _support_spacing(model)
        self.model = model
        n = int(model.n_features_in_)
        self.permutation = (np.arange(n) if permutation is None
                            else np.asarray(permutation, dtype=int))

    def __call__(self, q: np.ndarray) -> tuple[float, np.ndarray | None]:
        """``(d, grad)`` at ``q`` (n,) in controller order (spacings, spacings per rad)."""
        p = self.permutation
        x = np.asarray(q, dtype=float)[p]
        d, unit = _nearest_support(self.model, x, self.spacing)
        if unit is None:
            return d, None
        grad = np.empty_like(x)
        grad[p] = unit
        return d, grad


class FrameSupportDistance:
    """The extrapolation guard's ``distance(q) -> (d, grad)`` for a frames model.

    The model's support states live in its state space, the stacked frame positions
    ``x = phi(q)`` (3F,), m. With ``s`` the support state nearest to ``x`` and ``h`` the
    spacing of the training data (``model.support_spacing_``, m), ``d = |x - s| / h``
    (spacings) and, to first order in ``q``, ``grad d = J^T (x - s) / (|x - s| h)``
    (spacings per rad) with ``J`` (3F, n) the frames' Jacobian: the contract of
    :class:`ExtrapolationGuard`.

    Parameters
    ----------
    model : PolicyAlign
        Learnt on the frame states of ``state_map`` (has ``support_query``).
    state_map : TaskSpaceMap
        The map from ``q`` (n,) in command order to ``x`` (3F,), of the executor's robot.
    """

    def __init__(self, model, state_map) -> None:
        self.spacing = _support_spacing(model)
        self.model = model
        self.state_map = state_map

    def __call__(self, q: np.ndarray) -> tuple[float, np.ndarray | None]:
        """``(d, grad)`` at ``q`` (n,): spacings and spacings per rad (None on the data)."""
        x, J = self.state_map.kinematics(np.asarray(q, dtype=float))
        d, unit = _nearest_support(self.model, x, self.spacing)
        if unit is None:
            return d, None
        return d, J.T @ unit

class ExtrapolationGuard:
    """Scales down commands that lead away from the demonstrated data.

    Parameters
    ----------
    distance : callable ``distance(q) -> (d, grad)``
        The contract: ``q`` (n,) joint positions in controller order (rad); ``d`` (float,
        >= 0) the distance of the model's state at ``q`` to the demonstrated data in
        spacings of the training data (``PolicyAlign.support_query``, which measures in
        ``support_spacing_``); ``grad`` (n,) the gradient of ``d`` with respect to ``q``
        in controller order (spacings per rad), or None where ``d`` has no direction
        (on a support state). For a joint-space model use :class:`SupportDistance`; for
        a task-space state ``x = phi(q)`` with Jacobian ``J`` (m, n) and nearest support
        state ``s``, ``grad = J^T (x - s) / (|x - s| h)``. It may raise ValueError (the
        step then gives zero with the reason).
    max_extrapolation : float
        ``d_max`` (spacings, > 0): the scale is 1 up to it.
    min_band : float
        Smallest band (spacings, > 0).
    max_extrapolation_rad : float or None
        ``R`` (rad, > 0): caps the reach ``d_max + b`` at ``R |grad d|`` spacings, i.e.
        ``R`` rad of joint motion along ``grad d`` (None: no cap).

    Notes
    -----
    The scale is ``g = clip(1 - (d - d_max) / b, 0, 1)`` for a command ``v`` with
    ``grad . v > 0``, else 1, and ``g v`` is sent: one factor for the whole command
    keeps its direction, so ``A v = 0`` still holds. The band is
    ``b = max(min_band, |grad| |v_max| max(v_max) / (2 a))``: a command of at most
    ``v_max`` per joint (2-norm ``|v_max|``) braked by a ramp at ``a`` per joint stops
    within ``max(v_max) / a`` s, over at most ``|v_max| max(v_max) / (2 a)`` rad, which
    moves ``d`` by at most ``|grad|`` times that: the stopping distance at
    ``max_velocity`` in spacings. With no acceleration limit ``b = min_band``.

    With ``R`` the reach is capped at ``r = R |grad|`` spacings: the band becomes
    ``max(min(min_band, r), stop)`` and ``d_max`` becomes ``min(d_max, max(r - b,
    0))``, so a command leading out stops within ``max(R, stop / |grad|)`` rad of the
    data (for a joint-space model ``|grad| = 1 / h``, so ``d / |grad|`` is in rad; for
    a task-space model it is the joint motion along ``grad`` that covers ``d``, to first
    order).
    """

    def __init__(self, distance: DistanceFn, max_extrapolation: float = DEFAULT_MAX_EXTRAPOLATION,
                 min_band: float = MIN_BAND,
                 max_extrapolation_rad: float | None = DEFAULT_MAX_EXTRAPOLATION_RAD) -> None:
        self.distance = distance
        self.max_extrapolation = max_extrapolation
        self.max_extrapolation_rad = max_extrapolation_rad
        if not (math.isfinite(min_band) and min_band > 0.0):
            raise ValueError(f"min_band: must be finite and > 0, got {min_band}")
        self.min_band = float(min_band)
        #: ``d`` (spacings) and ``|grad d|`` (spacings per rad; NaN where it has no
        #: direction) at the last :meth:`scale`: what the executor reports, never read by
        #: the scaling itself.
        self.last_distance = math.nan
        self.last_grad_norm = math.nan

    @property
    def last_distance_rad(self) -> float:
        """The last :meth:`scale`'s ``d`` in rad: ``d / |grad d|``, the joint motion that
        covers it (exact for a joint-state model, to first order for a frames one); 0 on a
        support state, NaN when unknown."""
        if self.last_distance == 0.0:
            return 0.0
        norm = self.last_grad_norm
        return self.last_distance / norm if norm > 0.0 else math.nan

    @property
    def max_extrapolation(self) -> float:
        """``d_max`` in spacings."""
        return self._max

    @max_extrapolation.setter
    def max_extrapolation(self, value: float) -> None:
        value = float(value)
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"max_extrapolation: must be finite and > 0, got {value}")
        self._max = value

    @property
    def max_extrapolation_rad(self) -> float | None:
        """``R`` in rad (None: no cap)."""
        return self._max_rad

    @max_extrapolation_rad.setter
    def max_extrapolation_rad(self, value: float | None) -> None:
        if value is not None:
            value = float(value)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(
                    f"max_extrapolation_rad: must be finite and > 0, got {value}")
        self._max_rad = value

    def bounds(self, grad_norm: float, max_velocity: np.ndarray,
               max_acceleration: float | None) -> tuple[float, float]:
        """``(d_max, b)`` in spacings for ``|grad d| = grad_norm`` (spacings per rad),
        with the reach capped by ``max_extrapolation_rad``."""
        stop = self._stop(grad_norm, max_velocity, max_acceleration)
        if self._max_rad is None or not grad_norm > 0.0:
            return self._max, max(self.min_band, stop)
        reach = self._max_rad * grad_norm
        b = max(min(self.min_band, reach), stop)
        return min(self._max, max(reach - b, 0.0)), b

    def edge(self, grad_norm: float, max_velocity: np.ndarray,
             max_acceleration: float | None) -> tuple[float, str]:
        """Where a command leading out is scaled to zero, ``d_max + b`` (spacings), for
        ``|grad d| = grad_norm``, and the parameter that puts it there:
        ``"max_extrapolation_rad"`` when its cap brings the edge nearer than
        ``max_extrapolation`` and the band alone would, else ``"max_extrapolation"``."""
        d_max, b = self.bounds(grad_norm, max_velocity, max_acceleration)
        uncapped = self._max + self.band(grad_norm, max_velocity, max_acceleration)
        capped = d_max + b < uncapped
        return d_max + b, "max_extrapolation_rad" if capped else "max_extrapolation"

    def band(self, grad_norm: float, max_velocity: np.ndarray,
             max_acceleration: float | None) -> float:
        """Band ``b`` (spacings) for ``|grad d| = grad_norm`` (spacings per rad).

        Raises ValueError when the stopping distance is not finite (an infinite
        ``max_velocity``).
        """
        return max(self.min_band, self._stop(grad_norm, max_velocity, max_acceleration))

    @staticmethod
    def _stop(grad_norm: float, max_velocity: np.ndarray, max_acceleration: float | None
              ) -> float:
        """The stopping distance at ``max_velocity`` in spacings (0 without a limit)."""
        if max_acceleration is None or not grad_norm > 0.0:
            return 0.0
        vmax = np.asarray(max_velocity, dtype=float)
        stop = grad_norm * float(np.linalg.norm(vmax)) * float(vmax.max()) / (
            2.0 * max_acceleration)
        if not math.isfinite(stop):
            # No finite stopping distance (a joint without speed limit): no safe band.
            raise ValueError("band needs finite max_velocity and gradient")
        return stop

    def scale(self, q: np.ndarray, v: np.ndarray, max_velocity: np.ndarray,
              max_acceleration: float | None) -> tuple[float, float]:
        """Scale ``g`` in [0, 1] for command ``v`` (n,) at ``q`` (n,), and ``d``.

        Raises
        ------
        ValueError
            When the distance is not finite or its gradient has the wrong shape.
        """
        d, grad = self.distance(q)
        d = float(d)
        if not (math.isfinite(d) and d >= 0.0):
            raise ValueError(f"extrapolation distance not finite ({d})")
        self.last_distance, self.last_grad_norm = d, math.nan
        if grad is None:
            return 1.0, d
        grad = np.asarray(grad, dtype=float)
        valid = grad.shape == np.shape(v) and bool(np.all(np.isfinite(grad)))
        if valid:  # for the report in rad; the scaling below is the same without it
            self.last_grad_norm = float(np.linalg.norm(grad))
        if self._max_rad is None and d <= self._max:
            return 1.0, d
        if not valid:
            raise ValueError("extrapolation distance gradient not finite or of wrong shape")
        if float(grad @ v) <= 0.0:
            return 1.0, d  # back towards the data, or along it: never scaled
        d_max, b = self.bounds(self.last_grad_norm, max_velocity, max_acceleration)
        if d <= d_max:
            return 1.0, d
        return float(np.clip(1.0 - (d - d_max) / b, 0.0, 1.0)), d
