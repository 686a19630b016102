"""The PolicyAlign estimator (paper Algorithm 1).

Notation: ``K`` trajectories ``X_k`` (``N_k`` x ``n``), Euler potentials ``phi_hat_k``,
offsets ``b_k``, kernel width ``sigma^2``; the global model ``f(x)`` of the potential is
trained on ``(x_kn, phi_hat_kn + b_k)`` for the kept trajectories (eq. 16) and the
policy is ``pi_hat(x) = -grad f(x)``, in state units per second when the trajectories carry
times (per step otherwise).

1. estimate ``phi_hat_k`` along each trajectory (``integration``; with ``"auto"`` and
   recorded velocities, both the Euler and the trapezoid estimates go through steps 3-4
   and the regressor's cross-validation score decides). Trajectories are first split at
   steps that span lost samples (:func:`~policy_align_ros.learning.potential.sampling_gaps`)
   and, where their instantaneous velocities show one, at a constraint switch inside a
   sample period (:func:`~policy_align_ros.learning.potential.switch_cuts`): no rule gets
   such a step's drop right to first order, so the pieces' shapes are fitted apart (those
   of fewer than :data:`MIN_PIECE_SAMPLES` samples are left out). Their levels are tied
   across a switch by the midpoint drop ``-dt (|v_i|^2 + |v_{i+1}|^2) / 2``, which misses
   the true drop 4-100 times less than the alignment levels touching pieces
   (``docs/notes/potential.md``, "Pieces tied across a switch"), and are left to the
   alignment across lost samples. A leading rest (the robot held still before its
   motion, :func:`~policy_align_ros.learning.potential.leading_rest`) is left out too.
   The learnt attributes are merged back per trajectory;
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
   alignment, but their shape is data all the same (``docs/notes/outliers.md``). Their
   ``offsets_`` are then the levels the global model gives them.
"""

from __future__ import annotations

import copy
import math
import numbers
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from policy_align_ros.learning import model_io
from policy_align_ros.learning.alignment import (
    alignment_system,
    local_model_table,
    solve_chained_offsets,
)
from policy_align_ros.learning.bandwidth import (
    HEURISTIC_POINTS,
    closest_approach_matrix,
    resolve_sigma2,
)
from policy_align_ros.learning.fitting import check_query
from policy_align_ros.learning.outliers import largest_group, weakly_connected_groups
from policy_align_ros.learning.potential import (
    METHODS,
    best_timing,
    choose_method,
    estimate_potential,
    euler_scale,
    leading_rest,
    position_noise,
    sampling_gaps,
    switch_cuts,
)
from policy_align_ros.learning.regressors import (
    NotFittedError,
    TrendKernelRegression,
    regressor_class,
    takes_free_groups,
)
from policy_align_ros.learning.support import (
    query_support,
    support_spacing,
    support_states,
)
from policy_align_ros.learning.thinning import thin_each
from policy_align_ros.learning.trajectory import Trajectory, as_trajectories

__all__ = ["PolicyAlign", "MIN_PIECE_SAMPLES"]

#: Fewest samples a piece of a trajectory split at constraint switches must keep to be
#: fitted; shorter ones (a switch in the first or last two steps) are left out.
MIN_PIECE_SAMPLES = 3


class PolicyAlign:
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
    state_definition_ : dict or None
        What the state ``x`` is when it is not the joint positions: ``None`` for joint
        states; for task-space states the JSON-able definition (robot, joints, frames,
        root frame, locked posture, URDF hash, rest posture) set by the learning pipeline
        (:mod:`policy_align_ros.data.pipeline`). Saved in the model header; files without
        it load as joint-state models.
    """

    def __init__(
        self,
        sigma: str | float = "medium",
        *,
        integration: str = "auto",
        weight_tol: float = 1e-12,
        merge_tol: float = 0.1,
        eigen_tol: float = 1e-8,
        max_neighbours: int = 32,
        regressor=None,
        random_state: int | np.random.Generator | None = 0,
        verbose: bool = False,
    ) -> None:
        self.sigma = sigma
        self.integration = integration
        self.weight_tol = weight_tol
        self.merge_tol = merge_tol
        self.eigen_tol = eigen_tol
        self.max_neighbours = max_neighbours
        self.regressor = regressor
        self.random_state = random_state
        self.verbose = verbose

    # -- scikit-learn style parameter access ------------------------------------------
    def get_params(self) -> dict:
        """Constructor arguments, as given."""
        return {
            "sigma": self.sigma,
            "integration": self.integration,
            "weight_tol": self.weight_tol,
            "merge_tol": self.merge_tol,
            "eigen_tol": self.eigen_tol,
            "max_neighbours": self.max_neighbours,
            "regressor": self.regressor,
            "random_state": self.random_state,
            "verbose": self.verbose,
        }

    def _validate_params(self) -> None:
        """Check the constructor arguments (NumPy scalars count as numbers)."""
        if self.integration not in METHODS:
            raise ValueError(
                f"integration must be one of {METHODS}, got {self.integration!r}"
            )
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
        trajs = as_trajectories(trajectories)
        if len(trajs) < 2:
            raise ValueError("PolicyAlign needs at least 2 trajectories to align")
        n = trajs[0].n_dims
        if joint_names is not None and len(joint_names) != n:
            raise ValueError(f"joint_names has {len(joint_names)} names for a {n}-D state")
        masks = self._check_masks(train_mask, trajs)
        if all(not np.any(np.diff(t.positions, axis=0)) for t in trajs):
            # Nothing to learn from (a robot that never moved, a frozen driver): the fit
            # would otherwise end in a bowl of arbitrary scale fitted to zeros.
            raise ValueError("trajectories: none of them moves (every step is zero)")
        timings: dict[str, float] = {}
        t0 = time.perf_counter()

        X = np.concatenate([t.positions for t in trajs])
        labels = np.repeat(np.arange(len(trajs)), [t.n_samples for t in trajs])
        positions = [t.positions for t in trajs]
        closest = closest_approach_matrix(thin_each(positions, HEURISTIC_POINTS))
        self.sigma2_ = resolve_sigma2(self.sigma, positions, closest)
        timings["sigma"] = time.perf_counter() - t0
        self._log(f"{len(trajs)} trajectories, {len(X)} samples, sigma^2 = {self.sigma2_:.4g}")

        t1 = time.perf_counter()
        self.position_noise_ = position_noise(positions)
        parents, parent_masks = trajs, masks
        trajs, masks, spans, switch_end = self._split(trajs, masks)
        split = trajs is not parents
        if split:
            X = np.concatenate([t.positions for t in trajs])
            labels = np.repeat(np.arange(len(trajs)), [t.n_samples for t in trajs])
            closest = closest_approach_matrix(
                thin_each([t.positions for t in trajs], HEURISTIC_POINTS))
        rules = [self.integration]
        if self.integration == "auto":
            rules = list(dict.fromkeys(["euler", choose_method(trajs, self.position_noise_)]))
        phi = {rule: [estimate_potential(t, rule, self.position_noise_) for t in trajs]
               for rule in rules}
        self.euler_scale_ = 1.0
        if len(rules) > 1:
            # Trusted velocities measure the Euler rule's bias: a rescaling, to first order.
            self.euler_scale_ = euler_scale(phi["euler"], phi[rules[1]])
            phi["euler"] = [self.euler_scale_ * p for p in phi["euler"]]
        phi_all = {rule: np.concatenate(phi[rule]) for rule in rules}
        table = local_model_table(
            X, labels, phi_all[rules[0]], self.sigma2_,
            weight_tol=self.weight_tol, merge_tol=self.merge_tol,
            max_neighbours=self.max_neighbours, closest=closest,
        )
        # The outlier groups depend on the states only, not on the potentials.
        _, _, W = alignment_system(table)
        self.groups_ = weakly_connected_groups(W, self.eigen_tol)
        template = (TrendKernelRegression(random_state=self.random_state)
                    if self.regressor is None else self.regressor)
        free = np.zeros(0, dtype=np.int64)
        if takes_free_groups(template):
            free = np.flatnonzero((self.groups_ != 0)
                                  & np.array([m.any() for m in masks], dtype=bool))
        keep = self.inliers_ = np.union1d(largest_group(self.groups_), free)
        aligned = {}
        for rule in rules:
            rule_table = table if rule == rules[0] else table.with_potential(phi_all[rule])
            H, a, _ = alignment_system(rule_table, self.groups_)
            pairs, jumps = _switch_junctions(spans, switch_end, parents, phi[rule],
                                             self.groups_)
            offsets = solve_chained_offsets(H, a, pairs, jumps)
            aligned[rule] = (offsets, [p + b for p, b in zip(phi[rule], offsets, strict=True)])
        timings["alignment"] = time.perf_counter() - t1
        unit = "pieces of trajectories" if split else "trajectories"
        self._log(
            f"aligned with {len(table.q)} responsibilities; {len(keep) - len(free)} of "
            f"{len(trajs)} {unit} aligned, {len(free)} more levelled by the global "
            f"model ({timings['alignment']:.2f} s)"
        )

        t2 = time.perf_counter()
        Xtr = np.concatenate([trajs[k].positions[masks[k]] for k in keep])
        gtr = np.concatenate([np.full(int(masks[k].sum()), k) for k in keep])
        extra = {"free_groups": free} if free.size else {}
        fits, scores = {}, {}
        for rule in rules:
            ytr = np.concatenate([aligned[rule][1][k][masks[k]] for k in keep])
            fits[rule] = copy.deepcopy(template).fit(Xtr, ytr, groups=gtr, **extra)
            scores[rule] = _cv_score(fits[rule])
            if len(rules) > 1 and scores[rule] is None:
                break  # a regressor without CV scores cannot choose: the paper's Euler rule
        # Between potential rules, the one whose aligned potentials the regressor's CV
        # predicts best across held-out demonstrations: a biased rule leaves potentials no
        # single smooth function explains.
        self.integration_ = rules[0] if any(v is None for v in scores.values()) else min(
            scores, key=scores.get)
        self.regressor_ = fits[self.integration_]
        self.offsets_, self.aligned_potentials_ = _level_free(
            *aligned[self.integration_], free, self.regressor_, trajs, masks)
        timings["regression"] = time.perf_counter() - t2
        timings["total"] = time.perf_counter() - t0
        self._log(f"global model fitted on {len(Xtr)} samples with the {self.integration_} "
                  f"potentials ({timings['regression']:.2f} s)")

        n_pieces = len(trajs)
        n_left_out = int(sum(t.n_samples for t in parents) - sum(t.n_samples for t in trajs))
        if split:
            self._merge_pieces(spans, parents)
            trajs, masks = parents, parent_masks
            keep = self.inliers_
        self.support_states_, groups = support_states([trajs[k].positions for k in keep])
        self.support_spacing_ = support_spacing(self.support_states_, groups)
        self._support_tree = None

        self.n_features_in_ = n
        self.joint_names_ = None if joint_names is None else [str(j) for j in joint_names]
        # Set by whoever maps joint states to another state (the learning pipeline).
        self.state_definition_ = None
        self.timed_ = trajs[0].times is not None
        self.fit_summary_ = {
            "n_trajectories": len(trajs),
            "n_samples": int(sum(t.n_samples for t in trajs)),
            "n_inliers": int(len(keep)),
            # Counted in trajectories, as n_inliers (not in pieces where demonstrations
            # were split): the fitted ones outside the aligned set. Without a split these
            # are exactly the free groups' trajectories.
            "n_levelled_by_model": int(np.count_nonzero(self.groups_[keep] != 0)),
            "n_pieces": int(n_pieces),
            "n_samples_left_out": n_left_out,
            "n_groups": int(self.groups_.max() + 1),
            "n_responsibilities": int(len(table.q)),
            "integration": self.integration_,
            "integration_cv": {rule: score for rule, score in scores.items()
                               if score is not None},
            "euler_scale": self.euler_scale_,
            "position_noise_rms": math.sqrt(self.position_noise_),
            "noise_to_step": _noise_to_step(positions, self.position_noise_),
            "timings_s": timings,
        }
        return self

    def _split(self, trajs: list[Trajectory], masks: list[np.ndarray]
               ) -> tuple[list[Trajectory], list[np.ndarray], np.ndarray, np.ndarray]:
        """Pieces of the trajectories between steps that no rule gets right, their masks,
        the ``(trajectory, first sample, end)`` each piece spans (P, 3), and whether each
        piece ends at a switch cut, one that lost no samples (P,) bool.

        Such steps span lost samples
        (:func:`~policy_align_ros.learning.potential.sampling_gaps`), or, where the
        velocities are sampled at the samples (timing ``"mid"``) and trusted, a constraint
        switch inside the sample period
        (:func:`~policy_align_ros.learning.potential.switch_cuts`). The pieces' levels
        are tied across a switch (:func:`_switch_junctions`) and left to the alignment
        across lost samples. A demonstration's leading rest (the robot held still before
        its motion, :func:`~policy_align_ros.learning.potential.leading_rest`) is left
        out. Pieces of fewer than :data:`MIN_PIECE_SAMPLES` samples
        (a cut in the first or last steps, or two cuts close together) are left out of
        the fit; a trajectory that would keep no piece is kept whole. Nothing cut: the
        inputs themselves."""
        spans = np.array([(k, 0, t.n_samples) for k, t in enumerate(trajs)], dtype=np.int64)
        switches = (self.integration in ("auto", "trapezoid")
                    and best_timing(trajs, self.position_noise_) == "mid")
        pieces, piece_masks, out, switch_end = [], [], [], []
        for k, (t, m) in enumerate(zip(trajs, masks, strict=True)):
            gaps = sampling_gaps(t)
            switch = np.setdiff1d(switch_cuts(t), gaps) if switches else gaps[:0]
            cuts = np.union1d(gaps, switch)
            first = leading_rest(t.positions, self.position_noise_)
            bounds = [first, *(int(i) + 1 for i in cuts if i >= first), t.n_samples]
            kept = [(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)
                    if b - a >= MIN_PIECE_SAMPLES] or [(0, t.n_samples)]
            for a, b in kept:
                pieces.append(t if (a, b) == (0, t.n_samples) else Trajectory(
                    t.positions[a:b], None if t.times is None else t.times[a:b],
                    None if t.velocities is None else t.velocities[a:b],
                    name=f"{t.name}[{a}:{b}]"))
                piece_masks.append(m[a:b])
                out.append((k, a, b))
                switch_end.append(b - 1 in switch)
        if len(pieces) == len(trajs) and all(
                p is t for p, t in zip(pieces, trajs, strict=True)):
            # The caller then redoes no per-trajectory work.
            return trajs, masks, spans, np.zeros(len(trajs), dtype=bool)
        return pieces, piece_masks, np.array(out, dtype=np.int64), np.array(switch_end)

    def _merge_pieces(self, spans: np.ndarray, parents: list[Trajectory]) -> None:
        """Learnt per-piece attributes back to the trajectories: offsets of each first
        piece, aligned potentials joined, a trajectory kept if any piece is, its group the
        best of its pieces'. Samples left out (pieces too short to fit, and the pieces of a
        kept trajectory that were not kept, whose level is their own group's) get the
        aligned potential of the nearest kept sample plus the chosen rule's own estimate
        of the drop between them, the best that is known there. The trajectories' groups
        are numbered again 0, 1, ... in the order of the pieces' groups (group 0, the
        aligned set, stays 0), so that ``groups_.max() + 1`` counts them."""
        owner = spans[:, 0]
        first = np.searchsorted(owner, np.arange(len(parents)))
        self.offsets_ = self.offsets_[first]
        kept = np.zeros(len(spans), dtype=bool)
        kept[self.inliers_] = True
        aligned = []
        for k, t in enumerate(parents):
            rows = np.flatnonzero(owner == k)
            if kept[rows].any():
                rows = rows[kept[rows]]
            values = np.full(t.n_samples, np.nan)
            for j in rows:
                values[spans[j, 1]:spans[j, 2]] = self.aligned_potentials_[j]
            known = np.flatnonzero(~np.isnan(values))
            if len(known) < t.n_samples:
                whole = estimate_potential(t, self.integration_, self.position_noise_)
                if self.integration_ == "euler":
                    whole = self.euler_scale_ * whole
                gaps = np.flatnonzero(np.isnan(values))
                near = known[np.abs(gaps[:, None] - known[None, :]).argmin(axis=1)]
                values[gaps] = values[near] + whole[gaps] - whole[near]
            aligned.append(values)
        self.aligned_potentials_ = aligned
        merged = np.array([self.groups_[owner == k].min() for k in range(len(parents))])
        # A group whose pieces all belong to trajectories with a piece in a lower group
        # vanishes: renumber without gaps, keeping the order.
        self.groups_ = np.unique(merged, return_inverse=True)[1].reshape(-1).astype(np.int64)
        self.inliers_ = np.unique(owner[self.inliers_])

    @staticmethod
    def _check_masks(
        train_mask: Sequence[np.ndarray] | None, trajs: list[Trajectory]
    ) -> list[np.ndarray]:
        if train_mask is None:
            return [np.ones(t.n_samples, dtype=bool) for t in trajs]
        masks = list(train_mask)
        if len(masks) != len(trajs):
            raise ValueError(f"train_mask has {len(masks)} entries for {len(trajs)} trajectories")
        out = []
        for k, (m, t) in enumerate(zip(masks, trajs, strict=True)):
            m = np.asarray(m)
            if m.shape != (t.n_samples,) or m.dtype != bool:
                raise ValueError(
                    f"train_mask {k}: must be a bool array of shape ({t.n_samples},), "
                    f"got {m.dtype} {m.shape}"
                )
            out.append(m)
        return out

    # -- prediction -------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not hasattr(self, "regressor_"):
            raise NotFittedError("this PolicyAlign is not fitted yet: call fit() or load()")

    def _check_X(self, X: np.ndarray) -> np.ndarray:
        self._check_fitted()
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
        self._check_fitted()
        reg_arrays, reg_meta = self.regressor_.get_state()
        params = {k: v for k, v in self.get_params().items() if k != "regressor"}
        if isinstance(params["random_state"], np.random.Generator):
            params["random_state"] = None  # a file cannot hold its state
        definition = getattr(self, "state_definition_", None)
        if definition is not None and not isinstance(definition, dict):
            raise ValueError("state_definition_ must be None or a JSON-able dict, got "
                             f"{type(definition).__name__}")
        state = ("frame positions" if definition is not None
                 else "joint positions" if self.joint_names_ else "positions")
        header = {
            "kind": "policy_align",
            "joint_names": self.joint_names_,
            "state": state,
            "state_definition": definition,
            "policy_units": "per second" if self.timed_ else "per step",
            "n_features": self.n_features_in_,
            "sigma2": self.sigma2_,
            "params": params,
            "regressor": {"class": type(self.regressor_).__name__, "meta": reg_meta},
            "training": self.fit_summary_,
            "support_spacing": self.support_spacing_,
            # Exact (fit_summary_ holds its square root) and the Euler rule's factor.
            "position_noise": self.position_noise_,
            "euler_scale": self.euler_scale_,
        }
        lengths = np.array([len(p) for p in self.aligned_potentials_])
        arrays = {
            "offsets": self.offsets_,
            "groups": self.groups_,
            "inliers": self.inliers_,
            "aligned_lengths": lengths,
            "aligned_potentials": np.concatenate(self.aligned_potentials_),
            "support_states": self.support_states_,
            **{f"regressor.{k}": v for k, v in reg_arrays.items()},
        }
        return model_io.save_npz(path, header, arrays)

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
        header, arrays = model_io.load_npz(path, kind="policy_align")
        try:
            params = dict(_field(header, "params", dict))
            model = cls(**params)
            regressor = _field(header, "regressor", dict)
            reg_arrays = {
                k.split(".", 1)[1]: v for k, v in arrays.items() if k.startswith("regressor.")
            }
            reg_class = regressor_class(_field(regressor, "class", str))
            model.regressor_ = reg_class.from_state(reg_arrays, _field(regressor, "meta", dict))
            model.sigma2_ = float(header["sigma2"])
            n = _field(header, "n_features", int)
            if n < 1:
                raise ValueError(f"n_features must be positive, got {n}")
            model.n_features_in_ = n
            reg_n = getattr(model.regressor_, "n_features_in_", n)
            if reg_n != n:
                raise ValueError(f"the regressor takes {reg_n} features, n_features is {n}")
            model.joint_names_ = header["joint_names"]
            if model.joint_names_ is not None and (
                    not isinstance(model.joint_names_, list) or len(model.joint_names_) != n):
                raise ValueError(f"joint_names must be null or a list of {n} names")
            # Files written before task-space states have no definition: joint states.
            model.state_definition_ = header.get("state_definition")
            if model.state_definition_ is not None and not isinstance(
                    model.state_definition_, dict):
                raise ValueError("state_definition is not a dict")
            model.timed_ = header["policy_units"] == "per second"
            model.fit_summary_ = _field(header, "training", dict)
            # Files written before "auto" existed used the rule they name.
            model.integration_ = model.fit_summary_.get("integration", params.get(
                "integration", "euler"))
            model.euler_scale_, model.position_noise_ = _noise_and_scale(
                header, model.fit_summary_)
            model.offsets_ = _array(arrays, "offsets", "f", 1)
            K = len(model.offsets_)
            expected = model.fit_summary_.get("n_trajectories", K)
            if expected != K:
                raise ValueError(f"{K} offsets for n_trajectories = {expected!r}")
            model.groups_ = _array(arrays, "groups", "iu", 1, K)
            model.inliers_ = _array(arrays, "inliers", "iu", 1)
            if np.any(model.inliers_ < 0) or np.any(model.inliers_ >= K):
                raise ValueError(f"inliers must index the {K} trajectories")
            lengths = _array(arrays, "aligned_lengths", "iu", 1, K)
            potentials = _array(arrays, "aligned_potentials", "f", 1)
            if np.any(lengths < 0) or int(lengths.sum()) != len(potentials):
                raise ValueError(f"aligned_lengths sum to {int(lengths.sum())}, "
                                 f"aligned_potentials holds {len(potentials)} values")
            model.aligned_potentials_ = np.split(potentials, np.cumsum(lengths)[:-1])
            model.support_states_ = np.asarray(_array(arrays, "support_states", "fiu", 2),
                                               dtype=float)
            if model.support_states_.shape[1] != n:
                raise ValueError(f"support_states has {model.support_states_.shape[1]} "
                                 f"columns, n_features is {n}")
            model.support_spacing_ = float(header["support_spacing"])
            model._support_tree = None
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise ValueError(f"{path}: malformed policy_align model file ({err})") from None
        return model


def _field(mapping: dict, key: str, kind: type) -> Any:
    """``mapping[key]``, which must be a ``kind`` (an int is not a bool); ValueError (or
    KeyError when missing) naming the key otherwise."""
    value = mapping[key]
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise ValueError(f"{key} must be a JSON {_JSON_NAMES.get(kind, kind.__name__)}, "
                         f"got {type(value).__name__}")
    return value


_JSON_NAMES = {dict: "object", list: "array", str: "string", int: "integer"}


def _array(arrays: dict[str, np.ndarray], name: str, kinds: str, ndim: int,
           length: int | None = None) -> np.ndarray:
    """The model file's array ``name``, checked for its dtype kinds (``"f"``, ``"iu"``),
    number of dimensions and (first) length; ValueError naming it otherwise."""
    value = arrays[name]
    if value.dtype.kind not in kinds or value.ndim != ndim:
        raise ValueError(f"array {name!r} must be {ndim}-D of kind {kinds!r}, got "
                         f"{value.dtype} of shape {value.shape}")
    if length is not None and len(value) != length:
        raise ValueError(f"array {name!r} has {len(value)} entries for {length} "
                         "trajectories")
    return value


def _noise_and_scale(header: dict, summary: dict) -> tuple[float, float]:
    """``euler_scale_`` and ``position_noise_`` of a model file: the header's exact values,
    else the training summary's (``position_noise_rms`` squared), else 1 and 0 (files
    written before either existed)."""
    scale = float(header.get("euler_scale", summary.get("euler_scale", 1.0)))
    if "position_noise" in header:
        noise = float(header["position_noise"])
    else:
        noise = float(summary.get("position_noise_rms", 0.0)) ** 2
    if not (math.isfinite(scale) and math.isfinite(noise)):
        raise ValueError(f"euler_scale ({scale!r}) and position_noise ({noise!r}) must be "
                         "finite")
    return scale, noise


def _noise_to_step(positions: list[np.ndarray], noise: float) -> float:
    """``2 noise`` over the mean squared step: the share of the steps that is noise."""
    squared = [np.einsum("ij,ij->i", d, d) for d in (np.diff(p, axis=0) for p in positions)]
    mean = float(np.mean(np.concatenate(squared)))
    return 2.0 * noise / mean if mean > 0 else math.inf


def _switch_junctions(spans: np.ndarray, switch_end: np.ndarray, parents: list[Trajectory],
                      phi: list[np.ndarray], groups: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive pieces cut at a constraint switch, and the jump of their offsets there.

    Parameters
    ----------
    spans : ndarray of int, shape (P, 3)
        ``(trajectory, first sample, end)`` of each piece (:meth:`PolicyAlign._split`).
    switch_end : ndarray of bool, shape (P,)
        Whether each piece ends at a switch cut that lost no samples (the same).
    parents : list of Trajectory
        The whole trajectories.
    phi : list of ndarray
        Each piece's potential estimate (starting at 0).
    groups : ndarray of int, shape (P,)
        The pieces' alignment groups; pieces are tied within a group only.

    Returns
    -------
    pairs : ndarray of int, shape (L, 2)
        Pieces ``(p, p + 1)`` that touch across a step ``i`` that lost no samples.
    jumps : ndarray, shape (L,)
        ``b_{p+1} - b_p`` that makes the aligned potential drop by
        ``dt_i (|v_i|^2 + |v_{i+1}|^2) / 2`` over the step: the drop is ``dt`` times the
        squared speed, the old constraint's before the switch and the new one's after.
    """
    pairs, jumps = [], []
    for p in np.flatnonzero(switch_end[:-1]):
        k, _, end = spans[p]
        t = parents[k]
        if spans[p + 1, 0] != k or spans[p + 1, 1] != end or groups[p] != groups[p + 1]:
            continue
        # A switch cut needs trusted velocities (timing "mid"), so they are there.
        i = int(end) - 1
        v, dt = t.velocities, float(t.dt[i])
        drop = -0.5 * dt * (v[i] @ v[i] + v[i + 1] @ v[i + 1])
        pairs.append((p, p + 1))
        jumps.append(drop + phi[p][-1] - phi[p + 1][0])
    return np.array(pairs, dtype=np.int64).reshape(-1, 2), np.array(jumps, dtype=float)


def _cv_score(regressor) -> float | None:
    """The regressor's cross-validation score of the hyperparameters it chose, if any."""
    best = getattr(regressor, "cv_best_", None)
    scores = getattr(regressor, "cv_scores_", None)
    if best is None or not scores or best not in scores:
        return None
    score = float(scores[best])
    return score if math.isfinite(score) else None


def _level_free(offsets: np.ndarray, potentials: list[np.ndarray], free: np.ndarray,
                regressor, trajs: list[Trajectory], masks: list[np.ndarray]
                ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Offsets and aligned potentials with the trajectories ``free`` moved to the level of
    the global model: the mean of ``f(x) - phi`` over their training samples, which is the
    free offset a least-squares fit gives them."""
    offsets, potentials = offsets.copy(), list(potentials)
    for k in free:
        x = trajs[k].positions[masks[k]]
        level = float(np.mean(regressor.predict(x) - potentials[k][masks[k]]))
        offsets[k] += level
        potentials[k] = potentials[k] + level
    return offsets, potentials
