"""The stages of :meth:`PolicyAlign.fit <policy_align_ros.learning.policy_align.PolicyAlign.fit>`
that refit its global model: 4a, the demonstrations' tracking lag; 4b, the goal anchor;
4c, each demonstration on its own clock; the record of a fit they choose between; and,
for the fit kept, whether its fold models reach the goal from held-out starts.

They are methods of :class:`FitStages`, a base class of ``PolicyAlign`` that holds no
state of its own: each reads and sets the estimator's learnt attributes (``regressor_``,
``inliers_``, ``aligned_potentials_``, ...) and calls its alignment and global fit
(``_offsets``, ``_fit_global``). The maths they call lives in module functions:
:mod:`~policy_align_ros.learning.lag`, :mod:`~policy_align_ros.learning.anchor`,
:mod:`~policy_align_ros.learning.timing` and :mod:`~policy_align_ros.learning.folds`.
"""

from __future__ import annotations

import copy
import dataclasses
import warnings

import numpy as np

from policy_align_ros.learning.alignment import LocalModelTable
from policy_align_ros.learning.anchor import (
    choose_direction_weight,
    direction_candidates,
    goal_curvature,
    step_scale,
)
from policy_align_ros.learning.estimates import Estimates
from policy_align_ros.learning.folds import (
    fit_checks,
    fold_models,
    heldout_reach,
    heldout_reach_message,
)
from policy_align_ros.learning.global_model import cv_error, cv_score, fixed_copy, training_set
from policy_align_ros.learning.goal import data_extent, starts_elsewhere, typical_speed
from policy_align_ros.learning.lag import choose_lag, kinetic_term, lagged_potentials
from policy_align_ros.learning.model_io import json_float
from policy_align_ros.learning.new_starts import (
    new_start_runs,
    new_starts_late,
    new_starts_late_message,
    new_starts_message,
    stiffer_residual,
)
from policy_align_ros.learning.regressors import takes_final
from policy_align_ros.learning.timing import (
    TIMING_RESOLUTION,
    heldout_ratio,
    timed_is_better,
    timing_scales,
)
from policy_align_ros.learning.trajectory import sample_period

__all__ = ["FitStages"]


class FitStages:
    """Stages 4a-4c of ``PolicyAlign.fit`` (module docstring)."""

    def _fit_lag(self, est: Estimates, table: LocalModelTable, free: np.ndarray
                 ) -> dict[float, float]:
        """Stage 4a: with ``tracking_lag="auto"``, the lag whose potentials the fitted
        regressor predicts best across held-out demonstrations, its hyperparameters fixed
        (:func:`~policy_align_ros.learning.lag.choose_lag`). A lag found replaces the
        potentials of the rule chosen in ``est`` (the caller aligns and fits again); sets
        ``tracking_lag_``. Returns the scores."""
        if (self.tracking_lag != "auto" or cv_score(self.regressor_) is None
                or est.trajs[0].times is None):
            return {}
        fixed = fixed_copy(self.regressor_)
        rule = self.integration_
        kinetic = [kinetic_term(t) for t in est.trajs]
        lagged = dataclasses.replace(est, rules=[rule])

        def score(tau: float) -> tuple[float | None, float]:
            if tau == 0.0:
                return cv_score(self.regressor_), cv_error(self.regressor_)
            lagged.phi = {rule: lagged_potentials(est.phi[rule], kinetic, tau)}
            potentials = self._offsets(lagged, table)[rule][1]
            Xtr, ytr, gtr, extra = training_set(est.trajs, est.masks, self.inliers_,
                                                potentials, free, fixed)
            if takes_final(fixed):
                extra["final"] = False  # the scores are all a lag is chosen by
            fit = copy.deepcopy(fixed).fit(Xtr, ytr, groups=gtr, **extra)
            return cv_score(fit), cv_error(fit)

        tau, scores = choose_lag(score, sample_period(est.trajs))
        self.tracking_lag_ = tau
        if tau > 0.0:
            est.rules = [rule]
            est.phi = {rule: lagged_potentials(est.phi[rule], kinetic, tau)}
        return scores

    def _fit_anchored(self, est: Estimates, template, free: np.ndarray,
                      aligned: dict[str, tuple], anchor: dict
                      ) -> tuple[dict | None, tuple | None]:
        """Stage 4b: the global model made stationary at ``anchor["goal"]`` when
        ``anchor["anchored"]`` (:func:`~policy_align_ros.learning.anchor.anchor_decision`),
        with the direction weight chosen from the starts, the bowl's least curvature
        (:func:`~policy_align_ros.learning.anchor.bowl_curvature`) and the steps' factor
        (:func:`~policy_align_ros.learning.anchor.step_scale`), all recorded in
        ``anchor``. Returns the starts check of the kept fit and its scores and sample
        count (None, None unanchored)."""
        if not anchor["anchored"]:
            return None, None
        goal, fitted = np.asarray(anchor["goal"]), {}

        def fit_anchored(candidate):
            fitted["out"] = self._fit_global(est, candidate, free, aligned, goal)
            return self.regressor_

        choice = choose_direction_weight(fit_anchored, direction_candidates(template),
                                         est.parents, goal)
        choice["kernel_ridge_raised"], starts = self._stiffer_if_fewer_minima(
            est, template, goal, choice["direction_weight"], fit_anchored, fitted,
            choice.pop("starts"))
        anchor.update(choice)
        anchor["min_curvature"] = json_float(getattr(self.regressor_, "min_curvature_", None),
                                             "null")
        anchor["step_scale"] = step_scale(est.parents)
        return starts, fitted["out"]

    def _stiffer_if_fewer_minima(self, est: Estimates, template, goal: np.ndarray,
                                 weight, fit_anchored, fitted: dict, starts: dict | None
                                 ) -> tuple[bool, dict | None]:
        """Refit with :func:`~policy_align_ros.learning.new_starts.stiffer_residual` where
        runs from new starts stop away from the goal, and keep that fit when fewer of them
        do, no more demonstrated starts stop elsewhere, and the goal stays a minimum;
        otherwise restore the fit before. ``starts``: the fitted model's
        :func:`~policy_align_ros.learning.goal.starts_elsewhere`, if the direction weight's
        choice computed it. Returns whether the refit was kept, and the kept fit's
        ``starts_elsewhere`` (None when not computed)."""
        trajs = est.parents
        extent, speed = data_extent(trajs) or 1.0, typical_speed(trajs)

        def minima_off_paths(r) -> int:
            runs = new_start_runs(trajs, r.predict, r.gradient, goal, extent, speed,
                                  self.random_state)
            # The goal report's, if this fit is kept: the shared clock's fit or the one on
            # each demonstration's clock, whichever _choose_clocks keeps.
            self._new_start_runs = [*(self._new_start_runs or []), (r, runs)]
            return runs[0]["n_new_starts_elsewhere"]

        def starts_check(r) -> dict:
            return starts_elsewhere(trajs, r.predict, r.gradient, extent, speed)

        before = minima_off_paths(self.regressor_)
        candidate = stiffer_residual(template, self.regressor_, weight)
        if not before or candidate is None:
            return False, starts
        kept = (self.regressor_, self.offsets_, self.aligned_potentials_,
                self.integration_, fitted["out"])
        if starts is None:
            starts = starts_check(self.regressor_)
        stiffer = fit_anchored(candidate)
        if minima_off_paths(stiffer) < before:
            stiffer_starts = starts_check(stiffer)
            if (stiffer_starts["n_starts_elsewhere"] <= starts["n_starts_elsewhere"]
                    and goal_curvature(stiffer.gradient, goal, extent) > 0.0):
                return True, stiffer_starts
        (self.regressor_, self.offsets_, self.aligned_potentials_, self.integration_,
         fitted["out"]) = kept
        return False, starts

    def _checked_fit(self, est: Estimates, free: np.ndarray, starts: dict | None,
                     scores: dict, anchor: dict, caught: list) -> dict:
        """The fitted global model's checks (:func:`~policy_align_ros.learning.folds.
        fit_checks`) with what :meth:`_restore` sets again and the warnings of its fit
        (``caught``) and checks, held back until the fit is kept."""
        caught = list(caught)
        folds = fold_models(self.regressor_, est.trajs, est.masks, self.inliers_,
                            self.aligned_potentials_, free, random_state=self.random_state,
                            step_scale=step_scale(est.parents))
        with warnings.catch_warnings(record=True) as checked:
            warnings.simplefilter("always")
            checks = fit_checks(self.regressor_, folds, est.trajs, est.parents,
                                starts_check=starts, owners=est.spans[:, 0])
        return {"regressor_": self.regressor_, "integration_": self.integration_,
                "offsets_": self.offsets_, "aligned_potentials_": self.aligned_potentials_,
                "timing_scales_": self.timing_scales_, "phi": est.phi, "scores": scores,
                "anchor": anchor, "folds": folds,
                "checks": checks, "warnings": caught + list(checked),
                "timing_heldout": None}

    def _reach_heldout(self, fit: dict, est: Estimates) -> None:
        """The kept fit's :func:`~policy_align_ros.learning.folds.heldout_reach`, into its
        goal report, and its warning into its warnings. Run once, for the fit kept: the
        choice between the clocks does not read it."""
        goal, end = fit["checks"]["goal"], fit["anchor"]["goal"]  # demonstrated_goal's
        goal.update(heldout_reach(fit["folds"], est.spans, est.parents,
                                  None if end is None else np.asarray(end), goal["extent"]))
        _hold_warning(fit, heldout_reach_message(goal))

    def _new_starts(self, fit: dict, est: Estimates) -> None:
        """The kept fit's :func:`~policy_align_ros.learning.new_starts.new_start_runs`
        and, for the runs that stop at the goal, :func:`~policy_align_ros.learning.
        new_starts.new_starts_late`, into its goal report (``n_new_starts_late``), and
        their warnings into its warnings. Run once, for the fit kept, like
        :meth:`_reach_heldout`."""
        goal, end = fit["checks"]["goal"], fit["anchor"]["goal"]  # demonstrated_goal's
        regressor = fit["regressor_"]
        cached = [runs for r, runs in self._new_start_runs or []
                  if r is regressor]
        if cached:
            runs, starts, at_goal = cached[0]  # the anchored fit's own check of it
        else:
            runs, starts, at_goal = new_start_runs(
                est.parents, regressor.predict, regressor.gradient,
                None if end is None else np.asarray(end), goal["extent"],
                goal["typical_speed"], self.random_state)
        self._new_start_runs = None
        goal.update(runs)
        goal["n_new_starts_late"] = None if end is None else new_starts_late(
            est.parents, regressor.gradient, np.asarray(end), goal["extent"],
            starts[at_goal])
        _hold_warning(fit, new_starts_message(goal))
        _hold_warning(fit, new_starts_late_message(goal))

    def _restore(self, fit: dict, est: Estimates) -> None:
        """The attributes of a fit recorded by :meth:`_checked_fit`, and the estimates it
        was fitted on in ``est``."""
        for name in ("regressor_", "integration_", "offsets_", "aligned_potentials_",
                     "timing_scales_"):
            setattr(self, name, fit[name])
        # Kept for a run's own check of where it stops (learning/fold_stops.py).
        self.fold_regressors_ = [f.regressor for f in fit["folds"]]
        est.phi = fit["phi"]

    def _choose_clocks(self, est: Estimates, table: LocalModelTable, template,
                       free: np.ndarray, anchor: dict, fit: dict) -> dict:
        """Stage 4c: each demonstration on its own clock (:mod:`~policy_align_ros.learning.
        timing`). Where the factors differ from 1, stages 3-4b run again on the rescaled
        estimates, and that fit is kept when :func:`~policy_align_ros.learning.timing.
        timed_is_better`. Returns the kept fit's record, with both held-out ratios in
        ``timing_heldout``."""
        scales = self._timing_scales(est)
        if scales is None:
            return fit
        timed = self._fit_timed(est, table, template, free, anchor, scales)
        ratios = {"shared": heldout_ratio(fit["checks"]),
                  "per_demonstration": heldout_ratio(timed["checks"])}
        kept = timed if timed_is_better(timed["checks"], fit["checks"]) else fit
        kept["timing_heldout"] = {k: json_float(v) for k, v in ratios.items()}
        return kept

    def _timing_scales(self, est: Estimates) -> np.ndarray | None:
        """With ``time_units="per_demonstration"``, each demonstration's speed factor
        against the fitted global model (:func:`~policy_align_ros.learning.timing.
        timing_scales`); None where every factor is within :data:`~policy_align_ros.
        learning.timing.TIMING_RESOLUTION` of 1, or the samples are untimed (they share
        one clock, the sample index)."""
        if self.time_units == "shared" or est.trajs[0].times is None:
            return None
        keep = self.inliers_
        fitted = [self.regressor_.predict(est.trajs[k].positions[est.masks[k]]) for k in keep]
        values = [self.aligned_potentials_[k][est.masks[k]] for k in keep]
        scales = timing_scales(fitted, values, est.spans[keep, 0], len(est.parents))
        return None if np.all(np.abs(scales - 1.0) <= TIMING_RESOLUTION) else scales

    def _fit_timed(self, est: Estimates, table: LocalModelTable, template,
                   free: np.ndarray, anchor: dict, scales: np.ndarray) -> dict:
        """Stages 3-4b again on the estimates multiplied by each demonstration's factor
        ``scales`` (K,): aligned, fitted, and anchored at the goal of the first fit when
        it was (the direction weight chosen again). Returns :meth:`_checked_fit`'s
        record."""
        piece_scale = scales[est.spans[:, 0]]
        est.phi = {rule: [s * p for s, p in zip(piece_scale, phi, strict=True)]
                   for rule, phi in est.phi.items()}
        self.timing_scales_ = scales
        aligned = self._offsets(est, table)
        anchor = copy.deepcopy(anchor)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            if anchor["anchored"]:
                starts, out = self._fit_anchored(est, template, free, aligned, anchor)
                scores = out[0]
            else:
                scores, _ = self._fit_global(est, template, free, aligned)
                starts = None
        return self._checked_fit(est, free, starts, scores, anchor, caught)


def _hold_warning(fit: dict, message: str | None) -> None:
    """``message`` as a ``UserWarning`` into ``fit``'s held-back warnings (none if None):
    they are issued once the fit is the one kept."""
    if message is None:
        return
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.warn(message, UserWarning, stacklevel=2)
    fit["warnings"] += list(caught)
