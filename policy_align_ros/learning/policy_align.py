"""The PolicyAlign estimator (paper Algorithm 1).

Notation: ``K`` trajectories ``X_k`` (``N_k`` x ``n``), Euler potentials ``phi_hat_k``,
offsets ``b_k``, kernel width ``sigma^2``; the global model ``f(x)`` of the potential is
trained on ``(x_kn, phi_hat_kn + b_k)`` for the kept trajectories (eq. 16) and the
policy is ``pi_hat(x) = -grad f(x)``, in state units per second when the trajectories carry
times (per step otherwise).

1. estimate ``phi_hat_k`` along each trajectory (``integration``; with ``"auto"`` and
   recorded velocities, both the Euler and the trapezoid estimates go through steps 3-4
   and the regressor's cross-validation score decides). Trajectories are first cut where
   no rule gets a step's drop right (:mod:`~policy_align_ros.learning.pieces`: lost
   samples, a constraint switch inside a sample period), and a leading rest is left out;
   the pieces' shapes are fitted apart, their levels tied across a switch by the midpoint
   drop and left to the alignment across lost samples. The learnt attributes are merged
   back per trajectory;
2. build the sparse alignment system and find the weakly connected groups (``outliers``);
3. align each group (``b = -pinv(H) a`` restricted to the group); the largest group is
   the aligned set;
4. fit the global regressor on the aligned data. The default,
   :class:`~policy_align_ros.learning.regressors.TrendKernelRegression`, may correct the
   offsets of step 3 jointly with its model (its ``offset_ridge``, chosen by
   cross-validation over whole demonstrations); ``aligned_potentials_`` keep the
   alignment's offsets. A regressor whose ``fit`` takes ``free_groups`` (the default
   does) is also given the trajectories outside the aligned set, with offsets it re-fits
   freely: the paper discards them because no offset can be found for them by the
   alignment, but their shape is data all the same
   (``docs/design/alignment_and_outliers.md``). Their ``offsets_`` are then the levels the
   global model gives them.

The stages that refit the global model (4a, the tracking lag; 4b, the goal anchor; 4c,
each demonstration's clock) are the methods of
:class:`~policy_align_ros.learning.fit_stages.FitStages`.
"""

from __future__ import annotations

import copy
import math
import numbers
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from policy_align_ros.learning import policy_file
from policy_align_ros.learning.alignment import (
    LocalModelTable,
    alignment_system,
    local_model_table,
    solve_chained_offsets,
)
from policy_align_ros.learning.anchor import anchor_decision, bowl_curvature, step_scale
from policy_align_ros.learning.bandwidth import (
    HEURISTIC_POINTS,
    closest_approach_matrix,
    resolve_sigma2,
)
from policy_align_ros.learning.base import BaseEstimator, check_is_fitted
from policy_align_ros.learning.estimates import Estimates, estimate_potentials
from policy_align_ros.learning.fit_stages import FitStages
from policy_align_ros.learning.fitting import check_masks, check_query
from policy_align_ros.learning.global_model import cv_score, level_free, training_set
from policy_align_ros.learning.model_io import json_float
from policy_align_ros.learning.outliers import largest_group, weakly_connected_groups
from policy_align_ros.learning.pieces import merge_pieces, switch_junctions
from policy_align_ros.learning.potential import METHODS, estimate_potential, noise_to_step
from policy_align_ros.learning.regressors import (
    Regressor,
    TrendKernelRegression,
    takes_free_groups,
    takes_goal,
)
from policy_align_ros.learning.regressors.trend_kernel import shared_sums
from policy_align_ros.learning.support import (
    query_support,
    support_spacing,
    support_states,
)
from policy_align_ros.learning.thinning import thin_each
from policy_align_ros.learning.timing import TIME_UNITS
from policy_align_ros.learning.trajectory import Trajectory, as_trajectories

__all__ = ["PolicyAlign"]


class PolicyAlign(FitStages, BaseEstimator):
    """Learn a potential-based policy from trajectories observed under unknown constraints.

    Parameters
    ----------
    sigma : {"narrow", "medium", "wide"} or float
        Kernel width rule (paper eqs. 17-19) or ``sigma^2`` itself (squared state units).
    integration : {"auto", "euler", "trapezoid", "trapezoid_late"}
        Rule for the potential along each trajectory; the trapezoid rules need
        velocities (:mod:`policy_align_ros.learning.potential`). ``"auto"``: where every
        trajectory has velocities that explain its steps, the Euler rule and the
        trapezoid with the matching velocity timing are both aligned and fitted, and the
        one with the better cross-validation score of the regressor is kept (the Euler
        rule for regressors without one), and the Euler potentials are first rescaled by
        the velocities' measure of the Euler rule's bias (``euler_scale_``); otherwise the
        Euler rule.
    tracking_lag : "auto" or float
        Time constant (s, >= 0) by which the demonstrated velocity lagged the policy's
        (:mod:`policy_align_ros.learning.lag`): a robot tracking velocity commands, a
        person's speed building up from rest. ``"auto"`` (default): chosen by the
        regressor's cross-validation among 0 and ``LAG_GRID``, 0 (the paper's estimate)
        unless a lag predicts held-out demonstrations better by more than two standard
        errors (lags below one sample period are not scored); untimed trajectories and
        regressors without a CV score use 0.
    time_units : {"per_demonstration", "shared"}
        ``"per_demonstration"`` (default): each demonstration's potential estimates are
        multiplied by the least-squares slope of the fitted model on them (which undoes
        the teacher's speed on that demonstration) and the model is fitted again
        (:mod:`policy_align_ros.learning.timing`); that fit is kept when it strands
        fewer demonstrated starts or, as many, predicts held-out demonstrations' motion
        better by more than two standard errors over the CV folds. Factors within 1 % of
        1 keep the paper's estimate without a second fit. ``"shared"``: every
        demonstration on the paper's one clock. Untimed trajectories share the sample
        index.
    weight_tol : float
        Responsibility weights below this are treated as zero (sets the neighbour cut-off).
        Kept well below ``eigen_tol``: many tiny weights add up to a link that decides
        whether a trajectory is an outlier.
    merge_tol : float
        Samples closer than ``merge_tol * sigma`` along a trajectory are merged in the
        alignment (0: every sample, as in the paper); it bounds the work when a robot
        rests or is sampled densely.
    eigen_tol : float
        Eigenvalues of the alignment Hessian below this mark weakly connected groups.
    max_neighbours : int
        When the exact responsibility table would not fit in memory (large data sets in
        high dimension, whose kernels overlap near a common attractor), each sample sees
        only the trajectories that come closest to its own, this many at most.
    regressor : estimator, optional
        Global model with ``fit(X, y, groups)``, ``predict``, ``gradient``, ``get_state``
        and ``from_state`` (see :mod:`policy_align_ros.learning.regressors`); default
        ``TrendKernelRegression``, whose gradient is analytic and whose hyperparameters
        are chosen per data set by CV over whole held-out demonstrations.
    random_state : int, numpy.random.Generator or None
        Seed of the default regressor (``TrendKernelRegression(random_state=...)``: its
        kernel centres and CV folds), the only random choice of the fit; the kernel width
        heuristics and the alignment are deterministic. Not used when ``regressor`` is
        given (seed that one). Saved with the model as a plain int; a Generator, whose
        state a file cannot hold, is saved as ``None``.
    verbose : bool
        Print the progress of each stage to stderr.

    Attributes
    ----------
    groups_ : ndarray of int, shape (K,)
        The alignment's groups of well connected trajectories; group 0, the largest, is
        the aligned set (:func:`~policy_align_ros.learning.outliers.weakly_connected_groups`).
    inliers_ : ndarray of int
        Trajectories the global model is fitted on: the aligned set, and the other groups'
        trajectories when the regressor re-fits their offsets (``free_groups``); the rest
        are discarded.
    integration_ : {"euler", "trapezoid", "trapezoid_late"}
        The rule used (also ``fit_summary_["integration"]``, saved with the model;
        ``fit_summary_["integration_cv"]`` holds the scores it was chosen by).
    tracking_lag_ : float
        The lag used (s; also ``fit_summary_["tracking_lag"]``, with the scores it was
        chosen by in ``fit_summary_["tracking_lag_cv"]``).
    timing_scales_ : ndarray, shape (K,)
        The factor each demonstration's potential estimates were multiplied by: below 1
        for one moved faster than the others, 1 everywhere where the paper's shared clock
        was kept (also ``fit_summary_["timing_scales"]``; ``fit_summary_["timing_heldout"]``
        holds both fits' held-out error ratios when both were made, else None).
    euler_scale_ : float
        Factor applied to the Euler potentials with ``integration="auto"`` where
        velocities are trusted (:func:`~policy_align_ros.learning.potential.euler_scale`;
        1 otherwise; also ``fit_summary_["euler_scale"]``).
    position_noise_ : float
        Estimated variance of white noise on the states, summed over the coordinates
        (squared state units; :func:`~policy_align_ros.learning.potential.position_noise`);
        the Euler rule and the velocity check are corrected for it.
        ``fit_summary_["noise_to_step"]`` is the share of the mean squared step it
        explains: near 1, the recording's steps are mostly noise.
    fit_summary_ : dict
        The fit's counts and measures, saved with the model; with ``goal``,
        ``heldout_vs_zero``, ``worse_than_zero``, ``poor_fit``, ``no_minimum`` and
        ``unfixed_goal`` (:func:`~policy_align_ros.learning.folds.fit_checks`: a
        ``UserWarning`` when the held-out error is at least half of a zero policy's, and
        when the CV folds' models put the minimum more than 5 % of the extent apart).
    fold_regressors_ : list
        The CV folds' global models, each fitted without some demonstrations
        (:func:`~policy_align_ros.learning.folds.fold_models`), saved with the model
        (files without them load with none): where they stop a run elsewhere than the
        model does, its stop is uncertain (:mod:`~policy_align_ros.learning.fold_stops`).
    state_definition_ : dict or None
        What the state ``x`` is when it is not the joint positions: ``None`` for joint
        states; for task-space states the JSON-able definition (robot, joints, frames,
        root frame, locked posture, URDF hash, rest posture) set by the learning pipeline
        (:mod:`policy_align_ros.data.pipeline`). Saved in the model header; files without
        it load as joint-state models.
    robot_ : str or None
        The robot the model was learnt for (example-robot-data name or URDF path), set
        by the learning pipeline when it knows it; saved in the model header (files
        without it load with None). The executor takes its robot and joints from it
        when its own ``robot`` and ``joints`` are unset.
    """

    def __init__(
        self,
        sigma: str | float = "medium",
        *,
        integration: str = "auto",
        tracking_lag: str | float = "auto",
        time_units: str = "per_demonstration",
        weight_tol: float = 1e-12,
        merge_tol: float = 0.1,
        eigen_tol: float = 1e-8,
        max_neighbours: int = 32,
        regressor: Regressor | None = None,
        random_state: int | np.random.Generator | None = 0,
        verbose: bool = False,
    ) -> None:
        self.sigma = sigma
        self.integration = integration
        self.tracking_lag = tracking_lag
        self.time_units = time_units
        self.weight_tol = weight_tol
        self.merge_tol = merge_tol
        self.eigen_tol = eigen_tol
        self.max_neighbours = max_neighbours
        self.regressor = regressor
        self.random_state = random_state
        self.verbose = verbose

    def _validate_params(self) -> None:
        """Check the constructor arguments (NumPy scalars count as numbers)."""
        if self.integration not in METHODS:
            raise ValueError(
                f"integration must be one of {METHODS}, got {self.integration!r}"
            )
        lag = self.tracking_lag
        if lag != "auto" and not (isinstance(lag, numbers.Real) and 0 <= lag < math.inf):
            raise ValueError(f"tracking_lag must be 'auto' or a finite float >= 0 (s), "
                             f"got {lag!r}")
        if self.time_units not in TIME_UNITS:
            raise ValueError(f"time_units must be one of {TIME_UNITS}, got "
                             f"{self.time_units!r}")
        for name in ("weight_tol", "eigen_tol"):
            value = getattr(self, name)
            if not (isinstance(value, numbers.Real) and 0 < value < 1):
                raise ValueError(f"{name} must be a float in (0, 1), got {value!r}")
        if not (isinstance(self.max_neighbours, numbers.Integral)
                and self.max_neighbours >= 1):
            raise ValueError(
                f"max_neighbours must be a positive int, got {self.max_neighbours!r}"
            )
        if not (isinstance(self.merge_tol, numbers.Real) and 0 <= self.merge_tol < 1):
            raise ValueError(f"merge_tol must be a float in [0, 1), got {self.merge_tol!r}")

    def _log(self, message: str) -> None:
        if self.verbose:
            print(f"[PolicyAlign] {message}", file=sys.stderr, flush=True)
    # -- fitting ----------------------------------------------------------------------
    def fit(
        self,
        trajectories: Sequence[Trajectory | np.ndarray],
        *,
        train_mask: Sequence[np.ndarray] | None = None,
        joint_names: Sequence[str] | None = None,
    ) -> PolicyAlign:
        """Run Algorithm 1 on the demonstrations.

        Parameters
        ----------
        trajectories : sequence of Trajectory or array_like (N_k, n)
            At least two demonstrations of equal dimension.
        train_mask : sequence of bool arrays (N_k,), optional
            Samples the global model is trained on (default: all). Held-out samples still
            take part in the potential estimate and the alignment, which need whole
            trajectories.
        joint_names : sequence of str, optional
            Names of the ``n`` state coordinates, stored in the model file.

        Returns
        -------
        self
        """
        self._validate_params()
        trajs, masks = self._check_data(trajectories, train_mask, joint_names)
        # The global model is refitted on the same samples (lag, anchor, clocks): their
        # CV searches share the sums of equal designs (docs/design/scaling.md).
        with shared_sums():
            return self._fit(trajs, masks, joint_names)

    def _fit(self, trajs: list[Trajectory], masks: list[np.ndarray],
             joint_names: Sequence[str] | None) -> PolicyAlign:
        """:meth:`fit` on checked data."""
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        self._new_start_runs = None  # the anchored fits' runs from new starts (FitStages)
        positions = [t.positions for t in trajs]
        closest = closest_approach_matrix(thin_each(positions, HEURISTIC_POINTS))
        self.sigma2_ = resolve_sigma2(self.sigma, positions, closest)
        timings["sigma"] = time.perf_counter() - t0
        self._log(f"{len(trajs)} trajectories, {sum(t.n_samples for t in trajs)} samples, "
                  f"sigma^2 = {self.sigma2_:.4g}")

        t1 = time.perf_counter()
        est, self.position_noise_, self.euler_scale_, self.tracking_lag_ = (
            estimate_potentials(trajs, masks, closest, self.integration, self.tracking_lag))
        template = (TrendKernelRegression(random_state=self.random_state)
                    if self.regressor is None else self.regressor)
        table, free, aligned = self._align(est, template)
        timings["alignment"] = time.perf_counter() - t1
        unit = "pieces of trajectories" if est.split else "trajectories"
        self._log(
            f"aligned with {len(table.q)} responsibilities; {len(self.inliers_) - len(free)} "
            f"of {len(est.trajs)} {unit} aligned, {len(free)} more levelled by the global "
            f"model ({timings['alignment']:.2f} s)"
        )

        t2 = time.perf_counter()
        scores, n_fitted = self._fit_global(est, template, free, aligned)
        # Stage 4a: the demonstrations' tracking lag, where the CV finds one.
        lag_scores = self._fit_lag(est, table, free)
        if self.tracking_lag_ > 0.0:
            aligned = self._offsets(est, table)
            scores, n_fitted = self._fit_global(est, template, free, aligned)
        # Stage 4b: made stationary where the demonstrations end if the paper's potential
        # has no minimum there (learning/anchor.py).
        anchor = anchor_decision(self.regressor_, trajs, takes_goal(template),
                                 cv_score(self.regressor_))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")  # held back until this fit is the one kept
            starts, out = self._fit_anchored(est, template, free, aligned, anchor)
        scores, n_fitted = out if out is not None else (scores, n_fitted)
        timings["regression"] = time.perf_counter() - t2
        self._log(f"global model fitted on {n_fitted} samples with the {self.integration_} "
                  f"potentials ({timings['regression']:.2f} s)")
        t3 = time.perf_counter()
        # The learnt goal and the held-out error against a zero policy (warns when no better).
        self.timing_scales_ = np.ones(len(trajs))
        fit = self._choose_clocks(est, table, template, free, anchor,
                                  self._checked_fit(est, free, starts, scores, anchor,
                                                    caught))
        self._restore(fit, est)
        self._reach_heldout(fit, est)
        self._new_starts(fit, est)
        scores, anchor = fit["scores"], fit["anchor"]
        for held in fit["warnings"]:
            warnings.warn_explicit(held.message, held.category, held.filename, held.lineno)
        timings["checks"] = time.perf_counter() - t3
        timings["total"] = time.perf_counter() - t0

        self._merge_and_support(est, trajs[0].n_dims, joint_names)
        self.fit_summary_ = {**self._summary(est, table, scores, timings), **fit["checks"],
                             "anchor": anchor, "tracking_lag": self.tracking_lag_,
                             "timing_scales": self.timing_scales_.tolist(),
                             "timing_heldout": fit["timing_heldout"],
                             "tracking_lag_cv": {f"{t:g}": json_float(v)
                                                 for t, v in lag_scores.items()}}
        return self

    def _check_data(self, trajectories: Sequence[Trajectory | np.ndarray],
                    train_mask: Sequence[np.ndarray] | None,
                    joint_names: Sequence[str] | None
                    ) -> tuple[list[Trajectory], list[np.ndarray]]:
        """The demonstrations as trajectories and their training masks (ValueError naming
        the problem)."""
        trajs = as_trajectories(trajectories)
        if len(trajs) < 2:
            raise ValueError("PolicyAlign needs at least 2 trajectories to align")
        n = trajs[0].n_dims
        if joint_names is not None and len(joint_names) != n:
            raise ValueError(f"joint_names has {len(joint_names)} names for a {n}-D state")
        masks = check_masks(train_mask, trajs)
        if all(not np.any(np.diff(t.positions, axis=0)) for t in trajs):
            # Nothing to learn from (a robot that never moved, a frozen driver): the fit
            # would otherwise end in a bowl of arbitrary scale fitted to zeros.
            raise ValueError("trajectories: none of them moves (every step is zero)")
        return trajs, masks

    def _align(self, est: Estimates, template
               ) -> tuple[LocalModelTable, np.ndarray, dict[str, tuple]]:
        """Stages 2-3: the alignment system, its weakly connected groups (``groups_``),
        the trajectories fitted (``inliers_``) and, per rule, the offsets and aligned
        potentials of every piece. Returns the responsibility table, the pieces whose
        offsets the regressor re-fits freely, and ``{rule: (offsets, potentials)}``."""
        X = np.concatenate([t.positions for t in est.trajs])
        labels = np.repeat(np.arange(len(est.trajs)), [t.n_samples for t in est.trajs])
        table = local_model_table(
            X, labels, np.concatenate(est.phi[est.rules[0]]), self.sigma2_,
            weight_tol=self.weight_tol, merge_tol=self.merge_tol,
            max_neighbours=self.max_neighbours, closest=est.closest,
        )
        # The outlier groups depend on the states only, not on the potentials.
        _, _, W = alignment_system(table)
        self.groups_ = weakly_connected_groups(W, self.eigen_tol)
        free = np.zeros(0, dtype=np.int64)
        if takes_free_groups(template):
            free = np.flatnonzero((self.groups_ != 0)
                                  & np.array([m.any() for m in est.masks], dtype=bool))
        self.inliers_ = np.union1d(largest_group(self.groups_), free)
        return table, free, self._offsets(est, table)

    def _offsets(self, est: Estimates, table: LocalModelTable) -> dict[str, tuple]:
        """Stage 3: per rule of ``est``, the offsets and aligned potentials of every piece
        on the responsibilities of ``table`` and the groups ``groups_``."""
        aligned = {}
        for rule in est.rules:
            rule_table = table.with_potential(np.concatenate(est.phi[rule]))
            H, a, _ = alignment_system(rule_table, self.groups_)
            pairs, jumps = switch_junctions(est.spans, est.switch_end, est.parents,
                                             est.phi[rule], self.groups_)
            offsets = solve_chained_offsets(H, a, pairs, jumps)
            aligned[rule] = (offsets, [p + b for p, b in zip(est.phi[rule], offsets,
                                                              strict=True)])
        return aligned

    def _fit_global(self, est: Estimates, template, free: np.ndarray,
                    aligned: dict[str, tuple], goal: np.ndarray | None = None
                    ) -> tuple[dict[str, float | None], int]:
        """Stage 4: a copy of ``template`` fitted on every rule's aligned potentials; the
        rule whose fit has the better CV score is kept (``integration_``, ``regressor_``,
        ``offsets_``, ``aligned_potentials_``); with a ``goal``, stationary there, its bowl
        no flatter than :func:`~policy_align_ros.learning.anchor.bowl_curvature`. Returns
        the scores and the samples fitted."""
        fits, scores = {}, {}
        bowl = None if goal is None else bowl_curvature(est.parents)
        scale = step_scale(est.parents)
        for rule in est.rules:
            Xtr, ytr, gtr, extra = training_set(est.trajs, est.masks, self.inliers_,
                                                aligned[rule][1], free, template, goal,
                                                bowl, scale)
            fits[rule] = copy.deepcopy(template).fit(Xtr, ytr, groups=gtr, **extra)
            scores[rule] = cv_score(fits[rule])
            if len(est.rules) > 1 and scores[rule] is None:
                break  # a regressor without CV scores cannot choose: the paper's Euler rule
        # Between potential rules, the one whose aligned potentials the regressor's CV
        # predicts best across held-out demonstrations: a biased rule leaves potentials no
        # single smooth function explains.
        self.integration_ = est.rules[0] if any(v is None for v in scores.values()) else min(
            scores, key=scores.get)
        self.regressor_ = fits[self.integration_]
        self.offsets_, self.aligned_potentials_ = level_free(
            *aligned[self.integration_], free, self.regressor_, est.trajs, est.masks)
        return scores, len(Xtr)

    def _merge_and_support(self, est: Estimates, n: int,
                           joint_names: Sequence[str] | None) -> None:
        """Stage 5: the pieces' attributes merged back per trajectory
        (:meth:`_merge_pieces`), the support of the fitted trajectories and the
        description of the state."""
        if est.split:
            self._merge_pieces(est.spans, est.parents)
        trajs = est.parents
        self.support_states_, groups = support_states([trajs[k].positions
                                                       for k in self.inliers_])
        self.support_spacing_ = support_spacing(self.support_states_, groups)
        self._support_tree = None
        self.n_features_in_ = n
        self.joint_names_ = None if joint_names is None else [str(j) for j in joint_names]
        # Set by whoever maps joint states to another state (the learning pipeline).
        self.state_definition_ = None
        # Set by whoever knows the robot (the learning pipeline's ``robot``).
        self.robot_ = None
        self.timed_ = trajs[0].times is not None

    def _summary(self, est: Estimates, table: LocalModelTable,
                 scores: dict[str, float | None], timings: dict[str, float]) -> dict:
        """Stage 6: ``fit_summary_``, the fit's counts and measures (saved with the
        model)."""
        trajs, keep = est.parents, self.inliers_
        n_left_out = int(sum(t.n_samples for t in trajs)
                         - sum(t.n_samples for t in est.trajs))
        return {
            "n_trajectories": len(trajs),
            "n_samples": int(sum(t.n_samples for t in trajs)),
            "n_inliers": int(len(keep)),
            # Counted in trajectories, as n_inliers (not in pieces where demonstrations
            # were split): the fitted ones outside the aligned set. Without a split these
            # are exactly the free groups' trajectories.
            "n_levelled_by_model": int(np.count_nonzero(self.groups_[keep] != 0)),
            "n_pieces": int(len(est.trajs)),
            "n_samples_left_out": n_left_out,
            "n_groups": int(self.groups_.max() + 1),
            "n_responsibilities": int(len(table.q)),
            "integration": self.integration_,
            "integration_cv": {rule: score for rule, score in scores.items()
                               if score is not None},
            "euler_scale": self.euler_scale_,
            "position_noise_rms": math.sqrt(self.position_noise_),
            "noise_to_step": noise_to_step([t.positions for t in trajs],
                                            self.position_noise_),
            "timings_s": timings,
        }

    def _merge_pieces(self, spans: np.ndarray, parents: list[Trajectory]) -> None:
        """Learnt per-piece attributes back to the trajectories
        (:func:`~policy_align_ros.learning.pieces.merge_pieces`)."""
        self.offsets_, self.aligned_potentials_, self.groups_, self.inliers_ = merge_pieces(
            spans, parents, self.offsets_, self.groups_, self.inliers_,
            self.aligned_potentials_, self._whole_potential)

    def _whole_potential(self, k: int, trajectory: Trajectory) -> np.ndarray:
        """The chosen rule's potential estimate (N,) along a whole ``trajectory``, the
        ``k``-th, in its own time unit (``timing_scales_``)."""
        whole = estimate_potential(trajectory, self.integration_, self.position_noise_)
        if self.integration_ == "euler":
            whole = self.euler_scale_ * whole
        scales = getattr(self, "timing_scales_", None)
        return whole if scales is None else scales[k] * whole

    # -- prediction -------------------------------------------------------------------
    def _check_X(self, X: np.ndarray) -> np.ndarray:
        check_is_fitted(self, "regressor_")
        return check_query(X, self.n_features_in_)

    def potential(self, X: np.ndarray) -> np.ndarray:
        """Learnt potential ``f(x)``, shape (m,), for states ``X`` of shape (m, n)."""
        X = self._check_X(X)
        return self.regressor_.predict(X)

    def policy(self, X: np.ndarray) -> np.ndarray:
        """Learnt unconstrained policy ``-grad f(x)``, shape (m, n)."""
        X = self._check_X(X)
        return -self.regressor_.gradient(X)

    def support_query(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """How far states lie from the demonstrated data.

        Parameters
        ----------
        X : ndarray (m, n)

        Returns
        -------
        d : ndarray (m,)
            Distance to the nearest support state (thinned training state), in units of
            ``support_spacing_`` (the spacing of the demonstrations, see
            :mod:`policy_align_ros.learning.support`).
        nearest : ndarray (m, n)
            That support state.
        """
        X = self._check_X(X)
        if getattr(self, "_support_tree", None) is None:
            self._support_tree = cKDTree(self.support_states_)
        return query_support(self._support_tree, self.support_states_,
                             self.support_spacing_, X)

    # -- persistence ------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write the fitted model atomically to ``path`` (an ``.npz`` file).

        Parameters
        ----------
        path : str or Path
            The file to write.

        Returns
        -------
        Path
            The path written.

        Raises
        ------
        ValueError
            A hyperparameter, ``state_definition_`` or ``fit_summary_`` entry that JSON
            cannot hold; the message names the field. NumPy scalars are written as plain
            numbers and a Generator ``random_state`` as ``None`` (``get_params`` keeps
            the values as given).
        """
        return policy_file.write_model(self, path)

    @classmethod
    def load(cls, path: str | Path) -> PolicyAlign:
        """Read a model written by ``save``.

        Parameters
        ----------
        path : str or Path
            An ``.npz`` file written by :meth:`save`.

        Returns
        -------
        PolicyAlign
            The fitted model, with the attributes of a fit (not the regressor's CV
            scores). Files written before ``position_noise_`` and ``euler_scale_`` were
            saved give ``0.0`` and ``1.0``: no noise correction and no rescaling, as the
            code that wrote them did.

        Raises
        ------
        FileNotFoundError
            The file does not exist.
        ValueError
            The file is not a readable model file, or its header or arrays are malformed
            or inconsistent with each other; the message names the file and the problem.
        """
        return policy_file.read_model(cls, path)
