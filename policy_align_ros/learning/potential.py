"""Potential estimates along single trajectories (paper section III-A).

Notation: a trajectory ``x_1 ... x_N`` in ``R^n`` with time steps ``dt_i = t_{i+1} - t_i``
(seconds; ``dt = 1`` in the paper's units). For a potential-based policy ``pi = -grad phi``
observed through a projection ``xdot = N pi``, a step satisfies
``x_{i+1} - x_i ~= dt_i N_i pi_i`` and, because ``N`` is a symmetric idempotent projection,

    phi_{i+1} - phi_i ~= -(x_{i+1} - x_i)^T pi_i = -||x_{i+1} - x_i||^2 / dt_i   (Euler, eq. 7)

or, with measured velocities ``v_i = N_i pi_i``, the trapezoid rule

    phi_{i+1} - phi_i ~= -(v_i + v_{i+1})^T (x_{i+1} - x_i) / 2
                       = -v_i^T dx_i + F_i / 2,   F_i = (v_i - v_{i+1})^T dx_i,

with ``F_i`` its estimate of the step's curvature term ``dx_i^T H dx_i`` (``H`` the
Hessian of ``phi``). ``F_i`` is exact only while ``dx_i`` lies in the range of ``N_{i+1}``;
across a constraint switch it is wrong by a first-order amount (:func:`step_curvatures`
replaces it there).

Both return potentials with ``phi_1 = 0``; the unknown offset is found by alignment. With
times in seconds, the learnt policy ``-grad phi`` is in state units per second.

Which rule: the Euler drop ``||x_{i+1} - x_i||^2 / dt_i`` is ``-grad phi(x_i)`` times the
step exactly when the state moves at ``v_i`` for the whole step (a velocity command held
over a control period, or simulated data), and then misses the step's second-order term
``1/2 dx^T H dx``: a bias of relative order ``dt`` that no global model can remove. The
trapezoid rule averages the gradient at both ends of the step, which is exact for a
quadratic potential under held commands and second order for smooth motion; measured
velocities enter it linearly, so their noise does not bias it. It needs to know which
velocity moved the state over a step: recorders differ (:data:`TIMINGS`), and a velocity
one sample late doubles the Euler bias instead of removing it. And the trapezoid is only
exact while the constraint holds still over a step: a constraint that turns with the
state (a hand plane seen in joint space) or a commanded velocity that is not the
projected policy costs it accuracy that the Euler rule need not lose. So
:func:`choose_method` names the trapezoid with the velocity timing that explains the
steps best (or the Euler rule: no velocities, or velocity fields a driver leaves at zero
or fills with something else), and ``PolicyAlign(integration="auto")`` fits both that
and the Euler rule and keeps the one the regressor's cross-validation scores better.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.stats

from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["euler_potential", "trapezoid_potential", "estimate_potential", "METHODS",
           "best_timing", "switch_cuts", "sampling_gaps", "GAP_RATIO",
           "velocity_disagreement", "choose_method", "position_noise", "noise_to_step",
           "euler_scale",
           "VELOCITY_AGREEMENT", "TIMINGS", "step_curvatures", "SWITCH_RATIO", "leading_rest",
           "REST_FALSE_ALARM"]

METHODS = ("auto", "euler", "trapezoid", "trapezoid_late")
#: Velocity timing conventions: which recorded velocity moved the state from ``x_i`` to
#: ``x_{i+1}``. ``"ahead"``: ``v_i``, the command held from sample ``i`` on (simulated
#: data, logged commands); ``"mid"``: ``(v_i + v_{i+1}) / 2``, instantaneous velocities of
#: smooth motion; ``"late"``: ``v_{i+1}``, the velocity of the step that ended at the
#: sample (what a simulator or a driver differentiating its encoders reports).
TIMINGS = ("ahead", "mid", "late")
#: Largest :func:`velocity_disagreement` at which ``"auto"`` trusts recorded velocities.
VELOCITY_AGREEMENT = 0.5
#: How many times worse than its neighbours both curvature estimates that span a step
#: must agree before :func:`step_curvatures` takes that step for a constraint switch.
SWITCH_RATIO = 3.0
#: Relative step misses below this are round-off (``sqrt`` of the machine epsilon).
ROUND_OFF = math.sqrt(np.finfo(float).eps)
#: Probability that :func:`leading_rest` takes a sample of pure noise for motion.
REST_FALSE_ALARM = 1e-6
#: A step longer than this many times its trajectory's median step spans lost samples
#: (:func:`sampling_gaps`): halfway between an even step (1) and one lost sample (2).
GAP_RATIO = 1.5


def noise_to_step(positions: list[np.ndarray], noise: float) -> float:
    """``2 noise`` over the mean squared step of ``positions`` (each (N_k, n)): the share
    of the steps that is white position noise of variance ``noise`` (squared state
    units, summed over the coordinates)."""
    squared = [np.einsum("ij,ij->i", d, d) for d in (np.diff(p, axis=0) for p in positions)]
    mean = float(np.mean(np.concatenate(squared)))
    return 2.0 * noise / mean if mean > 0 else math.inf


def position_noise(positions: list[np.ndarray]) -> float:
    """Variance of white measurement noise on the states, summed over the coordinates.

    The ``k``-th differences of white noise of variance ``s_d^2`` per coordinate have the
    variance ``C(2k, k) s_d^2`` (20 for third, 70 for fourth differences), whatever the
    order; those of smooth or piecewise smooth motion shrink by a factor of the step
    with every order. So each order's median (robust to the few differences that
    straddle a constraint switch), corrected from the median to the mean of a chi-square
    with ``n`` degrees of freedom, estimates ``sum_d s_d^2`` plus what is left of the
    motion, and the smaller of the third- and fourth-order estimates is kept (its
    accuracy: ``docs/design/potential.md``).

    Parameters
    ----------
    positions : list of ndarray, shape (N_k, n)
        The trajectories' states; those with fewer than 5 samples are ignored.

    Returns
    -------
    float
        ``sum_d s_d^2`` in squared state units (0 without a trajectory of 5 samples).
    """
    usable = [p for p in positions if len(p) >= 5]
    if not usable:
        return 0.0
    median_to_mean = (1.0 - 2.0 / (9.0 * usable[0].shape[1])) ** 3  # Wilson-Hilferty
    estimates = []
    for order, gain in ((3, 20.0), (4, 70.0)):
        squared = np.concatenate([np.einsum("ij,ij->i", d, d) for d in
                                  (np.diff(p, n=order, axis=0) for p in usable)])
        estimates.append(float(np.median(squared)) / (gain * median_to_mean))
    return min(estimates)


def euler_potential(positions: np.ndarray, dt: np.ndarray | float = 1.0, noise: float = 0.0
                    ) -> np.ndarray:
    """Euler estimate of the potential along one trajectory (paper eq. 7).

    Parameters
    ----------
    positions : ndarray, shape (N, n)
        States along the trajectory.
    dt : float or ndarray, shape (N-1,)
        Time steps in seconds (1 in the paper's units).
    noise : float
        Variance of white noise on the states, summed over the coordinates
        (:func:`position_noise`; squared state units). Noise adds ``2 noise`` to every
        squared step on average, a drift of the potential with time that is subtracted.

    Returns
    -------
    ndarray, shape (N,)
        ``phi_1 = 0`` and ``phi_{i+1} = phi_i - (||x_{i+1} - x_i||^2 - 2 noise) / dt_i``.
    """
    steps = np.diff(positions, axis=0)
    drops = (np.einsum("ij,ij->i", steps, steps) - 2.0 * noise) / dt
    return np.concatenate(([0.0], -np.cumsum(drops)))


def trapezoid_potential(positions: np.ndarray, velocities: np.ndarray, late: bool = False
                        ) -> np.ndarray:
    """Trapezoid estimate of the potential from positions and measured velocities.

    Parameters
    ----------
    positions : ndarray, shape (N, n)
        States along the trajectory.
    velocities : ndarray, shape (N, n)
        Observed ``xdot_i = N_i pi_i`` in state units per second.
    late : bool
        The velocities are reported one sample late (``v_{i+1}`` is what moved the state
        from ``x_i``; see :data:`TIMINGS`): they are shifted back by one sample first, and
        the last one repeated.

    Returns
    -------
    ndarray, shape (N,)
        ``phi_1 = 0`` and ``phi_{i+1} = phi_i - v_i' dx_i + c_i / 2`` with
        ``dx_i = x_{i+1} - x_i`` and ``c_i`` the curvature term of
        :func:`step_curvatures`: ``F_i = (v_i - v_{i+1})' dx_i``, which gives the
        trapezoid ``phi_i - (v_i + v_{i+1})' dx_i / 2``, except at the steps it marks as
        constraint switches, where ``c_i`` is ``B_i = (v_{i-1} - v_i)' dx_i`` instead
        (the velocity after the switch would spoil the drop).
    """
    if late:
        velocities = np.concatenate([velocities[1:], velocities[-1:]])
    steps = np.diff(positions, axis=0)
    drops = (np.einsum("ij,ij->i", velocities[:-1], steps)
             - 0.5 * step_curvatures(steps, velocities))
    return np.concatenate(([0.0], -np.cumsum(drops)))


def step_curvatures(steps: np.ndarray, velocities: np.ndarray) -> np.ndarray:
    """The trapezoid rule's curvature term per step, robust to constraint switches.

    Two estimates of ``q_i = dx_i' H dx_i`` use the velocities on either side of step
    ``i``: ``F_i = (v_i - v_{i+1})' dx_i`` (the trapezoid's own; exact for a quadratic
    under held commands) and ``B_i = (v_{i-1} - v_i)' dx_i`` (``= dx_{i-1}' H dx_i``, off
    by a third-order amount). A switch between samples ``i`` and ``i+1`` spoils ``F_i``
    and ``B_{i+1}`` by first-order amounts, as both take a velocity of one constraint
    along a step of the other. So step ``i`` takes ``B_i`` where ``F_i`` disagrees with
    ``B_{i+1}`` (rescaled to step ``i``) more than :data:`SWITCH_RATIO` times as much as
    ``B_i`` does with ``F_{i-1}``, and the same pattern, mirrored, marks step ``i+1``: a
    switch breaks both pairs that straddle it, smooth motion and constraints that turn
    with the state break neither.

    Parameters
    ----------
    steps : ndarray, shape (N-1, n)
        ``dx_i = x_{i+1} - x_i``.
    velocities : ndarray, shape (N, n)
        ``v_i``, already aligned so that ``v_i`` moved the state over step ``i``.

    Returns
    -------
    ndarray, shape (N-1,)
        ``F_i``, with ``B_i`` at the steps taken for switches.
    """
    forward = np.einsum("ij,ij->i", velocities[:-1] - velocities[1:], steps)
    if len(steps) < 4:
        return forward
    # backward[j] is B_{j+1}, for steps 1 .. N-2.
    backward = np.einsum("ij,ij->i", velocities[:-2] - velocities[1:-1], steps[1:])
    length = np.sqrt(np.einsum("ij,ij->i", steps, steps))
    with np.errstate(divide="ignore", invalid="ignore"):
        i = np.arange(1, len(steps) - 1)
        # after[k]: F_i against B_{i+1} scaled to step i; before[k]: B_i against F_{i-1}.
        after = np.abs(forward[i] - backward[i] * length[i] / length[i + 1])
        before = np.abs(backward[i - 1] - forward[i - 1] * (length[i] / length[i - 1]) ** 2)
    # A step that does not move tells nothing: its NaN comparisons are False.
    broken = after > SWITCH_RATIO * before
    # The switch between i and i+1 also shows from step i+1's side, mirrored.
    broken[:-1] &= before[1:] > SWITCH_RATIO * after[1:]
    broken[-1] = False
    out = forward.copy()
    out[i[broken]] = backward[i[broken] - 1]
    return out


def _step_residuals(positions: np.ndarray, velocities: np.ndarray, dt: np.ndarray | float,
                    timing: str) -> tuple[np.ndarray, np.ndarray]:
    """The steps ``dx_i`` (N-1, n) and what the timing's velocity ``u_i`` leaves of them,
    ``dx_i - dt_i u_i`` (N-1, n)."""
    steps = np.diff(positions, axis=0)
    dt = np.reshape(dt, (-1, 1)) if np.ndim(dt) else dt
    if timing == "ahead":
        u = velocities[:-1]
    elif timing == "mid":
        u = 0.5 * (velocities[:-1] + velocities[1:])
    elif timing == "late":
        u = velocities[1:]
    else:
        raise ValueError(f"unknown velocity timing {timing!r}; expected one of {TIMINGS}")
    return steps, steps - dt * u


def _step_misses(positions: np.ndarray, velocities: np.ndarray, dt: np.ndarray | float,
                 timing: str, noise: float = 0.0) -> tuple[float, float]:
    """Sum of ``||dx_i - dt_i u_i||^2`` for the timing's velocity ``u_i``, and of
    ``||dx_i||^2``; both less the ``2 noise`` per step that noise on the states adds."""
    steps, residual = _step_residuals(positions, velocities, dt, timing)
    floor = 2.0 * noise * len(steps)
    return (max(float(np.sum(residual**2)) - floor, 0.0),
            float(np.sum(steps**2)) - floor)


def velocity_disagreement(positions: np.ndarray, velocities: np.ndarray,
                          dt: np.ndarray | float, timing: str = "mid", noise: float = 0.0
                          ) -> float:
    """How far recorded velocities are from explaining the recorded steps.

    Parameters
    ----------
    positions, velocities : ndarray, shape (N, n)
        States and their recorded time derivatives (state units per second).
    dt : float or ndarray, shape (N-1,)
        Time steps in seconds.
    timing : {"ahead", "mid", "late"}
        Which recorded velocity is taken to have moved the state over a step
        (:data:`TIMINGS`).
    noise : float
        Variance of white noise on the states (:func:`position_noise`), whose share of
        every step is taken out of both sums.

    Returns
    -------
    float
        ``sqrt(sum ||dx_i - dt_i u_i||^2 / sum ||dx_i||^2)``: near 0 when the velocities
        are those of the motion (a constraint switch adds one bad step), 1 for velocities
        left at zero, 2 for the opposite sign; ``inf`` if nothing moves beyond the noise.
    """
    return _relative_miss(*_step_misses(positions, velocities, dt, timing, noise))


def _relative_miss(miss: float, moved: float) -> float:
    """``sqrt(miss / moved)``, ``inf`` when nothing moved."""
    return math.sqrt(miss / moved) if moved > 0 else math.inf


def choose_method(trajs: list[Trajectory], noise: float = 0.0) -> str:
    """The potential rule for a data set: one rule for all, so that every trajectory's
    potential carries the same kind of error.

    ``"euler"`` unless every trajectory has velocities that explain the steps
    (:func:`best_timing`); then ``"trapezoid_late"`` for the timing ``"late"`` and
    ``"trapezoid"`` for the others. ``noise``: the variance of noise on the states
    (:func:`position_noise`); without its correction, steps dominated by noise look like
    velocities left at zero.
    """
    timing = best_timing(trajs, noise)
    if timing is None:
        return "euler"
    return "trapezoid_late" if timing == "late" else "trapezoid"


def euler_scale(euler: list[np.ndarray], trapezoid: list[np.ndarray]) -> float:
    """The factor that removes the Euler rule's first-order bias on average.

    Over a step under a held command the Euler rule misses ``dx' H dx / 2`` of the drop, a
    share ``dt h / 2`` of it for the curvature ``h`` along the step: for a potential whose
    Hessian is a multiple of the identity, the same share on every step, so the Euler
    potentials are the true ones times a constant that no cross-validation over shapes
    can see. Where the velocities are trusted (the trapezoid rule named by
    :func:`choose_method`), the ratio of the trapezoid's drop to the Euler rule's on each
    step measures that share. Its median over all steps, each weighted by its Euler drop
    (steps that move little are mostly noise; a constraint switch spoils the trapezoid on
    one step), is returned.

    Parameters
    ----------
    euler, trapezoid : list of ndarray, shape (N_k,)
        The same trajectories' potentials by the Euler rule (noise-corrected) and by the
        trapezoid rule (:func:`estimate_potential`).

    Returns
    -------
    float
        The factor, > 0; 1 when no step moved.
    """
    euler = np.concatenate([-np.diff(p) for p in euler])
    trap = np.concatenate([-np.diff(p) for p in trapezoid])
    moved = euler > 0
    if not moved.any():
        return 1.0
    ratio, weight = trap[moved] / euler[moved], euler[moved]
    order = np.argsort(ratio)
    cumulative = np.cumsum(weight[order])
    median = float(ratio[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])
    return median if math.isfinite(median) and median > 0 else 1.0


def best_timing(trajs: list[Trajectory], noise: float = 0.0) -> str | None:
    """The velocity timing (:data:`TIMINGS`) that best explains all the trajectories'
    steps together, or ``None`` unless every trajectory has velocities and the best
    timing's :func:`velocity_disagreement` is within :data:`VELOCITY_AGREEMENT`."""
    if any(t.velocities is None or t.n_samples < 2 for t in trajs):
        return None
    totals = {}
    for timing in TIMINGS:
        sums = [_step_misses(t.positions, t.velocities, t.dt, timing, noise) for t in trajs]
        totals[timing] = _relative_miss(sum(e for e, _ in sums), sum(m for _, m in sums))
    best = min(TIMINGS, key=totals.get)
    return best if totals[best] <= VELOCITY_AGREEMENT else None


def sampling_gaps(traj: Trajectory) -> np.ndarray:
    """Steps that span lost samples: longer than :data:`GAP_RATIO` times the median step,
    and with their two neighbours longer than ``2 + GAP_RATIO`` times it.

    A recorder that loses messages (a loaded machine, a lossy network) leaves a step over
    which the state moved at velocities that nobody recorded. Where the constraint or the
    speed changed in between, no rule gets that step's potential drop right to first
    order, whatever the velocity timing. A jittered stamp lengthens one step by as much as
    it shortens a neighbour, so three steps span three medians give or take two stamps'
    offsets, and four over a lost sample: halfway between, stamps off by up to a quarter
    of a step are told from a lost sample (a missing neighbour, at an end, counts as one
    median step). Measured with ``tools/recording_check.py``
    (``docs/design/constraint_switches.md``).

    Returns
    -------
    ndarray of int
        Step indices ``i`` (the cut falls between samples ``i`` and ``i + 1``), sorted;
        empty for a trajectory without times.
    """
    if traj.times is None or traj.n_samples < 3:
        return np.zeros(0, dtype=np.int64)
    dt = traj.dt
    median = np.median(dt)
    span = dt + np.r_[median, dt[:-1]] + np.r_[dt[1:], median]
    return np.flatnonzero((dt > GAP_RATIO * median)
                          & (span > (2.0 + GAP_RATIO) * median)).astype(np.int64)


def leading_rest(positions: np.ndarray, noise: float) -> int:
    """The last sample of a trajectory's leading rest (0 when it moves at once).

    A recorder started before the motion adds samples of a robot held still: one state
    repeated with its measurement noise. They tell nothing of the policy, yet the step
    where the motion starts inside a sample period is wrong to first order under every
    rule, as at a constraint switch, and there the motion is usually at its fastest. A
    rest of noisy samples then weighs that error as much as the motion beside it
    (``docs/design/leading_rest.md``).
    The rest is the samples that stay as close to the first one as noise alone keeps
    two samples, with probability ``1 -`` :data:`REST_FALSE_ALARM` (a chi-square with
    ``n`` degrees of freedom scaled by ``2 noise / n``; without noise, the first state
    repeated exactly). Under noise as large as the steps, motion itself stays a few
    samples in that neighbourhood, so a prefix no longer than motion at the median step
    takes to leave it is kept (trimming motion costs more than keeping rest). Recorded
    velocities do not tell the two apart there: motion moves less than the noise in a
    step, too. A rest at the end is kept: a robot settling at its goal moves
    less than the noise, per step and over many steps, and those samples still inform
    the fit.

    Parameters
    ----------
    positions : ndarray, shape (N, n)
        States along the trajectory.
    noise : float
        Variance of white noise on the states, summed over the coordinates
        (:func:`position_noise`; squared state units).

    Returns
    -------
    int
        The sample before the first that leaves the first sample's neighbourhood; 0 when
        none leaves it or the first step already does.
    """
    n = positions.shape[1]
    bound = 2.0 * noise / n * float(scipy.stats.chi2.isf(REST_FALSE_ALARM, n))
    left = np.flatnonzero(np.sum((positions - positions[0]) ** 2, axis=1) > bound)
    if len(left) == 0:
        return 0
    rest = int(left[0]) - 1
    if rest <= 0:
        return 0
    # Exact repeats (rests without noise) are not steps of the motion.
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    steps = steps[steps > 0.0]
    return rest if rest * float(np.median(steps)) > math.sqrt(bound) else 0


def switch_cuts(traj: Trajectory) -> np.ndarray:
    """Steps across which the constraint switched *inside* the sample period.

    With velocities sampled at the samples (timing ``"mid"``), a step ``i`` is explained
    by ``dt_i (v_i + v_{i+1}) / 2`` to second order, except where the constraint changed
    between the two samples: then the step is part one constraint's motion, part the
    other's, and no rule from the two end velocities gets its potential drop right to
    first order. Elsewhere the step's relative miss varies smoothly, if fast where stiff
    motion decays (it falls about geometrically); a switch makes it jump. A step is
    returned where its relative miss is more than :data:`SWITCH_RATIO` times the
    geometric mean of its neighbours' (the first and the last step: its one
    neighbour's), and above round-off (``sqrt(eps)``). The geometric mean, unlike the
    larger neighbour, still finds a switch right after a fast first step or next to
    another switch (``docs/design/constraint_switches.md``).

    Returns
    -------
    ndarray of int
        Step indices ``i`` (the cut falls between samples ``i`` and ``i + 1``), sorted.
    """
    if traj.velocities is None or traj.n_samples < 3:
        return np.zeros(0, dtype=np.int64)
    steps, residual = _step_residuals(traj.positions, traj.velocities, traj.dt, "mid")
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.linalg.norm(residual, axis=1) / np.linalg.norm(steps, axis=1)
    rel = np.where(np.isfinite(rel), rel, 0.0)  # a step of zero length holds no switch
    neighbours = np.empty_like(rel)
    neighbours[1:-1] = np.sqrt(rel[:-2] * rel[2:])
    neighbours[0], neighbours[-1] = rel[1], rel[-2]
    cut = (rel > SWITCH_RATIO * neighbours) & (rel > ROUND_OFF)
    return np.flatnonzero(cut).astype(np.int64)


def estimate_potential(traj: Trajectory, method: str = "euler", noise: float = 0.0
                       ) -> np.ndarray:
    """Potential along a trajectory by the chosen rule.

    Parameters
    ----------
    traj : Trajectory
        The demonstration; the trapezoid rules need its velocities.
    method : {"auto", "euler", "trapezoid", "trapezoid_late"}
        Integration rule (``"trapezoid_late"``: velocities reported one sample late, see
        :func:`trapezoid_potential`); ``"auto"`` is :func:`choose_method` for this
        trajectory alone.
    noise : float
        Variance of white noise on the states, summed over the coordinates
        (:func:`position_noise`); the Euler rule removes its bias. The trapezoid rule
        needs no correction: noise enters it linearly.

    Returns
    -------
    ndarray, shape (N,)
        Potential estimates with ``phi_1 = 0``.
    """
    if method == "auto":
        method = choose_method([traj], noise)
    if method == "euler":
        return euler_potential(traj.positions, traj.dt, noise)
    if method in ("trapezoid", "trapezoid_late"):
        if traj.velocities is None:
            raise ValueError(
                f"trajectory {traj.name}: the trapezoid estimate needs velocities"
            )
        return trapezoid_potential(traj.positions, traj.velocities,
                                   late=method == "trapezoid_late")
    raise ValueError(f"unknown potential estimate {method!r}; expected one of {METHODS}")
