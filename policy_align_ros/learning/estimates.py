"""Stage 1 of PolicyAlign: the potential estimated along every demonstration.

The demonstrations are first cut where no rule gets a step's drop right
(:mod:`~policy_align_ros.learning.pieces`: lost samples, a constraint switch inside a
sample period); every potential rule tried then estimates the potential along every piece
(:mod:`~policy_align_ros.learning.potential`). The result, :class:`Estimates`, is handed
from stage to stage of :class:`~policy_align_ros.learning.policy_align.PolicyAlign`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from policy_align_ros.learning.bandwidth import HEURISTIC_POINTS, closest_approach_matrix
from policy_align_ros.learning.lag import kinetic_term, lagged_potentials
from policy_align_ros.learning.pieces import split_pieces
from policy_align_ros.learning.potential import (
    choose_method,
    estimate_potential,
    euler_scale,
    position_noise,
)
from policy_align_ros.learning.thinning import thin_each
from policy_align_ros.learning.trajectory import Trajectory

__all__ = ["Estimates", "estimate_potentials"]


@dataclasses.dataclass
class Estimates:
    """The potential estimates of a fit, handed from stage to stage.

    ``parents`` and ``parent_masks`` are the trajectories and their training masks as
    given; ``trajs`` and ``masks`` the pieces they were split into (the same lists when
    nothing was cut), ``spans`` (P, 3) and ``switch_end`` (P,) as returned by
    :func:`~policy_align_ros.learning.pieces.split_pieces`; ``closest`` the pieces'
    closest-approach matrix; ``rules`` the potential rules tried (the first is the
    fallback) and ``phi`` each rule's estimate along every piece.
    """

    parents: list[Trajectory]
    parent_masks: list[np.ndarray]
    trajs: list[Trajectory]
    masks: list[np.ndarray]
    spans: np.ndarray
    switch_end: np.ndarray
    closest: np.ndarray
    rules: list[str]
    phi: dict[str, list[np.ndarray]]

    @property
    def split(self) -> bool:
        """Whether any trajectory was cut into pieces."""
        return self.trajs is not self.parents


def estimate_potentials(trajs: list[Trajectory], masks: list[np.ndarray],
                        closest: np.ndarray, integration: str, tracking_lag: str | float
                        ) -> tuple[Estimates, float, float, float]:
    """The position noise, the pieces and every rule's potential estimate along them.

    Parameters
    ----------
    trajs, masks : list
        The demonstrations and their training masks (bool, (N_k,)).
    closest : ndarray (K, K)
        The demonstrations' closest-approach matrix (state units).
    integration : str
        PolicyAlign's ``integration``: one rule, or ``"auto"`` (the Euler rule and the
        one :func:`~policy_align_ros.learning.potential.choose_method` picks).
    tracking_lag : "auto" or float
        PolicyAlign's ``tracking_lag``; a fixed lag (s) > 0 shifts every estimate by it
        (:func:`~policy_align_ros.learning.lag.lagged_potentials`), ``"auto"`` is chosen
        later, from the fitted model.

    Returns
    -------
    tuple
        The :class:`Estimates`; the position noise (squared state units); the Euler
        rule's scale (1 unless velocities are trusted); the tracking lag applied (s).
    """
    noise = position_noise([t.positions for t in trajs])
    pieces, piece_masks, spans, switch_end = split_pieces(trajs, masks, integration, noise)
    if pieces is not trajs:
        closest = closest_approach_matrix(
            thin_each([t.positions for t in pieces], HEURISTIC_POINTS))
    rules = [integration]
    if integration == "auto":
        rules = list(dict.fromkeys(["euler", choose_method(pieces, noise)]))
    phi = {rule: [estimate_potential(t, rule, noise) for t in pieces] for rule in rules}
    scale = 1.0
    if len(rules) > 1:
        # Trusted velocities measure the Euler rule's bias: a rescaling, to first order.
        scale = euler_scale(phi["euler"], phi[rules[1]])
        phi["euler"] = [scale * p for p in phi["euler"]]
    lag = 0.0
    if tracking_lag != "auto" and tracking_lag > 0.0 and pieces[0].times is not None:
        lag = float(tracking_lag)
        kinetic = [kinetic_term(t) for t in pieces]
        phi = {rule: lagged_potentials(p, kinetic, lag) for rule, p in phi.items()}
    return (Estimates(trajs, masks, pieces, piece_masks, spans, switch_end, closest, rules,
                      phi), noise, scale, lag)
