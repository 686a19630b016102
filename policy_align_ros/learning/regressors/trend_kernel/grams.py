"""Per-fold sums of a design for cross-validation over whole demonstrations, with the
demonstrations' offsets eliminated in closed form (see :mod:`.model`, "Offsets")."""

from __future__ import annotations

import contextlib
import contextvars
import copy
import dataclasses
import hashlib
import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator

import numpy as np
import scipy.sparse

from policy_align_ros.learning.regressors.trend_kernel.features import (
    _gaussian,
    _kernel,
    _kernel_directions,
)
from policy_align_ros.learning.regressors.trend_kernel.solvers import (
    _convex_solves,
    _gram,
    _nonneg_solve,
)

#: Steps shorter than this fraction of the median step get no row along the motion
#: (:func:`along_motion`).
MIN_STEP = 0.05


class _FoldGrams:
    """Per-fold and per-demonstration sums of a design, for CV with per-demo offsets.

    ``A`` (m, p) is the design at the samples, ``u`` (m,) the targets, ``demo`` (m,) the
    demonstration of every sample as ``0..K-1`` and ``demo_fold`` (K,) the fold of every
    demonstration. The offsets ``b_k`` are eliminated in closed form: with
    ``c_k = 1 / (n_k + m lambda)``, the objective profiled over ``b`` has the Gram
    ``sum_i a_i a_i' - sum_k c_k A_k A_k'`` (``A_k`` the sum of ``a_i`` over demonstration
    ``k``), so every score below costs one (p, p) solve per fold.
    """

    def __init__(self, A: np.ndarray, u: np.ndarray, demo: np.ndarray, demo_fold: np.ndarray,
                 n: int, base: _FoldGrams | None = None, free: np.ndarray | None = None,
                 nonneg: bool = False, D: np.ndarray | None = None,
                 Dt: np.ndarray | None = None):
        """``base``, when given, holds the sums of the first columns of ``A`` (the trend,
        shared by every length scale), so only the blocks of the new columns are summed.
        ``free`` (K,) bool: demonstrations whose offsets are free at every
        ``offset_ridge`` (default: none). The folds' solves: by default the first columns
        of ``A`` are :func:`quadratic_features`, whose Hessian :func:`_convex_solve` keeps
        positive definite; with ``nonneg``, ``A`` is the single-index design ``[1, B]``,
        whose profile weights :func:`_nonneg_solve` keeps >= 0. ``D`` (m, r, p), optional:
        direction rows of every sample (:func:`direction_rows`), observations added to the
        Grams of their folds only (no offsets), of ``Dt`` (m, r) where given (the slope
        along the motion, :func:`along_motion`), else of zero; with ``base``, ``base``
        holds their first columns' sums already. The held-out scores are of the values
        only."""
        self.n = n
        self.nonneg = nonneg
        self.free = (np.zeros(len(demo_fold), dtype=bool) if free is None
                     else np.asarray(free, dtype=bool))
        n_demos = len(demo_fold)
        onehot = scipy.sparse.csr_matrix(
            (np.ones(len(u)), (demo, np.arange(len(u)))), shape=(n_demos, len(u)))
        self.nk = np.bincount(demo, minlength=n_demos).astype(float)
        self.demo_fold = demo_fold
        n_folds = int(demo_fold.max()) + 1
        fold = demo_fold[demo]
        if np.any(np.diff(fold) < 0):
            raise ValueError("_FoldGrams: samples must be sorted by fold")
        bounds = np.searchsorted(fold, np.arange(n_folds + 1))
        rows = [slice(bounds[f], bounds[f + 1]) for f in range(n_folds)]
        q = 0 if base is None else base.G.shape[1]
        new = A[:, q:]
        Ak = np.asarray(onehot @ new)
        self.Ak = Ak if base is None else np.hstack([base.Ak, Ak])  # (K, p) per-demo sums
        p = A.shape[1]
        self.G = np.empty((n_folds, p, p))
        for f, r in enumerate(rows):
            self.G[f, q:, q:] = _gram(new[r])
            if base is not None:
                self.G[f, :q, :q] = base.G[f]
                self.G[f, :q, q:] = A[r, :q].T @ new[r]
                self.G[f, q:, :q] = self.G[f, :q, q:].T
        if D is not None:
            self._add_directions(D, rows, q, base is not None)
        # The design itself is kept to score held-out folds from their residuals: at a
        # near-perfect fit the expanded sums (u'u - 2 w'r + w'Gw) cancel to round-off.
        self.A, self.D, self.demo, self.rows = A, D, demo, rows
        self.G_all = self.G.sum(axis=0)
        self._set_targets(u, Dt, onehot)

    def _set_targets(self, u: np.ndarray, Dt: np.ndarray | None,
                     onehot: scipy.sparse.csr_matrix | None = None) -> None:
        """The sums that depend on the targets ``u`` (m,) and ``Dt`` (m, r) (None: zero)."""
        if onehot is None:
            onehot = scipy.sparse.csr_matrix(
                (np.ones(len(u)), (self.demo, np.arange(len(u)))),
                shape=(len(self.demo_fold), len(u)))
        self.u, self.sk = u, onehot @ u
        self.r = np.stack([self.A[r].T @ u[r] for r in self.rows])
        if self.D is not None and Dt is not None:
            for f, r in enumerate(self.rows):
                self.r[f] += np.einsum("mip,mi->p", self.D[r], Dt[r])
        self.uu = np.array([u[r] @ u[r] for r in self.rows])
        self.r_all = self.r.sum(axis=0)
        self._free: tuple[np.ndarray, ...] | None = None
        # Held-out error is scored against the within-demonstration spread of u.
        self.shape_ss = max(float(self.uu.sum() - np.sum(self.sk**2 / self.nk)), 1e-300)

    def with_targets(self, u: np.ndarray, Dt: np.ndarray | None, free: np.ndarray
                     ) -> _FoldGrams:
        """These sums for other targets ``u`` (m,), ``Dt`` (m, r) and free offsets ``free``
        (K,) on the same design: the Grams, the costly part, are shared, not copied."""
        out = copy.copy(self)
        out.free = np.asarray(free, dtype=bool)
        out._set_targets(u, Dt)
        return out

    def _add_directions(self, D: np.ndarray, rows: list[slice], q: int, has_base: bool
                        ) -> None:
        """Add each fold's sums of its direction rows ``D`` (m, r, p) to ``G``."""
        p = D.shape[2]
        for f, r in enumerate(rows):
            new = D[r][:, :, q:].reshape(-1, p - q)
            self.G[f, q:, q:] += new.T @ new
            if q and has_base:
                cross = D[r][:, :, :q].reshape(-1, q).T @ new
                self.G[f, :q, q:] += cross
                self.G[f, q:, :q] += cross.T
            elif q:
                old = D[r][:, :, :q].reshape(-1, q)
                self.G[f, :q, :q] += old.T @ old
                cross = old.T @ new
                self.G[f, :q, q:] += cross
                self.G[f, q:, :q] += cross.T

    def free_offset_sums(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per fold, the Gram and right-hand side terms that free offsets remove
        (``offset_ridge = 0``: ``c_k = 1 / n_k``), and their sums over all folds; they do
        not depend on the other folds, and are summed on first use (the final fit never
        needs them)."""
        if self._free is None:
            per_demo = self.Ak / self.nk[:, None]
            folds = [self.demo_fold == f for f in range(len(self.G))]
            G0 = np.stack([per_demo[k].T @ self.Ak[k] for k in folds])
            r0 = np.stack([per_demo[k].T @ self.sk[k] for k in folds])
            self._free = (G0, r0, G0.sum(axis=0), r0.sum(axis=0))
        return self._free

    def scores(self, penalties: list[np.ndarray], offset_ridge: float, shared: int = 0,
               floor: float = 0.0) -> list[tuple[float, float]]:
        """Held-out shape error per penalty, and its standard error over the folds.

        The shape error sums the squared residuals of the held-out demonstrations about
        their own mean (every held-out demonstration gets its best offset), over their
        spread. ``shared``: the penalties are block diagonal and equal in their first
        ``shared`` rows and columns (negative: in their last ``-shared``; see
        :func:`_solve_shared`). ``floor``: the trend's smallest curvature (see
        :func:`_convex_solve`).
        """
        n_folds = len(self.G)
        err = np.array([self.fold_errors(f, penalties, offset_ridge, shared, floor=floor)
                        for f in range(n_folds)]).T
        return _fold_summary(err, self.shape_ss)

    def fold_errors(self, f: int, penalties: list[np.ndarray], offset_ridge: float,
                    shared: int = 0, accept=None, floor: float = 0.0) -> list[float]:
        """Held-out squared shape residuals of fold ``f`` per penalty, fitted on the other
        folds (``inf`` where the solve fails or ``accept(w)`` is false); ``floor`` as in
        :meth:`scores`."""
        G, r, m = self.without(f, offset_ridge)
        M = G / m
        if self.nonneg:
            solved = [_nonneg_solve(M + penalty, r / m, 1) for penalty in penalties]
        else:
            solved = _convex_solves(M, r / m, penalties, shared, self.n, floor)
        out = []
        for w in solved:
            ok = w is not None and np.all(np.isfinite(w)) and (accept is None or accept(w))
            out.append(self.shape_error(f, w) if ok else math.inf)
        return out

    def without(self, f: int, offset_ridge: float) -> tuple[np.ndarray, np.ndarray, float]:
        """:meth:`profiled` over every demonstration outside fold ``f``."""
        held = self.demo_fold == f
        if offset_ridge == 0.0:
            G0, r0, G0_all, r0_all = self.free_offset_sums()
            G = self.G_all - self.G[f] - (G0_all - G0[f])
            r = self.r_all - self.r[f] - (r0_all - r0[f])
            return G, r, float(self.nk[~held].sum())
        return self.profiled(~held, self.G_all - self.G[f], self.r_all - self.r[f],
                             offset_ridge)

    def shape_error(self, fold: int, w: np.ndarray) -> float:
        """Squared residuals of fold ``fold``'s demonstrations about their own means."""
        r = self.rows[fold]
        e = self.u[r] - self.A[r] @ w
        demo = self.demo[r]
        mean = np.bincount(demo, weights=e, minlength=len(self.nk)) / np.maximum(self.nk, 1)
        return float(np.sum((e - mean[demo]) ** 2))

    def profiled_all(self, offset_ridge: float) -> tuple[np.ndarray, np.ndarray, float]:
        """:meth:`profiled` over every demonstration: the system of a fit on all data."""
        return self.profiled(np.ones(len(self.nk), bool), self.G_all, self.r_all, offset_ridge)

    def profiled(self, train: np.ndarray, G: np.ndarray, r: np.ndarray, offset_ridge: float
                 ) -> tuple[np.ndarray, np.ndarray, float]:
        """Gram and right-hand side of demonstrations ``train`` (bool, K) whose sums are
        ``G, r``, with their offsets eliminated; and their number of samples."""
        m = float(self.nk[train].sum())
        free = self.free[train]
        if math.isfinite(offset_ridge) or free.any():
            nk = self.nk[train]
            c = (np.zeros_like(nk) if math.isinf(offset_ridge)
                 else 1.0 / (nk + m * offset_ridge))
            c[free] = 1.0 / nk[free]
            Ak = self.Ak[train]
            G = G - (Ak * c[:, None]).T @ Ak
            r = r - Ak.T @ (c * self.sk[train])
        return G, r, m


@dataclasses.dataclass(frozen=True)
class _CVData:
    """The standardised data of one CV search, samples sorted by fold.

    ``F`` (m, p_t) trend features, ``Z`` (m, n) states, ``u`` (m,) targets, ``C`` (m_c, n)
    kernel centres, ``demo`` (m,) and ``demo_fold`` (K,) as in :class:`_FoldGrams`;
    ``trend`` the fold sums of ``F``, shared by every length scale; ``pinned``: kernel
    features flat at the goal (:func:`~.features._kernel`); ``bases`` (m, r, n) and
    ``trend_directions`` (m, r, p_t): the samples' direction bases (``r = n - 1`` rows
    across the motion, ``n`` with the row along it) and the trend's direction rows
    (:func:`direction_rows`), or None; ``direction_targets`` (m, r): what the direction
    rows observe (:func:`along_motion`), or None for zero; ``floor``: the trend's
    smallest curvature in standardised units (:func:`_convex_solve`; not part of the sums,
    which fits with other floors share).
    """

    F: np.ndarray
    Z: np.ndarray
    u: np.ndarray
    C: np.ndarray
    demo: np.ndarray
    demo_fold: np.ndarray
    trend: _FoldGrams
    pinned: bool = False
    bases: np.ndarray | None = None
    trend_directions: np.ndarray | None = None
    direction_targets: np.ndarray | None = None
    floor: float = 0.0

    @property
    def n(self) -> int:
        """State dimension."""
        return self.Z.shape[1]

    def kernel_sums(self, ell: float) -> tuple[_FoldGrams, np.ndarray]:
        """Fold sums of the trend and kernel features at length scale ``ell``, and the
        centres' Gram (m_c, m_c)."""

        def build() -> _FoldGrams:
            A = np.hstack([self.F, _kernel(self.Z, self.C, ell, self.pinned)])
            D = None
            if self.bases is not None:
                D = np.concatenate([self.trend_directions, _kernel_directions(
                    self.bases, self.Z, self.C, ell, self.pinned)], axis=2)
            return _FoldGrams(A, self.u, self.demo, self.demo_fold, self.n,
                              base=self.trend, free=self.trend.free, D=D,
                              Dt=self.direction_targets)

        # The trend's features and direction rows follow from the states, the pinning and
        # the bases, so the key need not hold them.
        design = ("folds", self.Z, self.C, self.demo, self.demo_fold, self.bases, ell,
                  self.pinned)
        return (memo_sums(design, build, self.u, self.direction_targets, self.trend.free),
                _gaussian(self.C, self.C, ell))


def memo_sums(design: tuple, build: Callable[[], _FoldGrams], u: np.ndarray,
              Dt: np.ndarray | None, free: np.ndarray) -> _FoldGrams:
    """``build()``, or within :func:`shared_sums` the sums of the same ``design`` built
    before, for the targets ``u`` (m,), ``Dt`` (m, r) (None: zero) and free offsets
    ``free`` (K,).

    ``design``: everything the design (features and direction rows) and its folds follow
    from, as arrays, numbers, strings or None; not the targets.
    """
    memo = _MEMO.get()
    if memo is None:
        return build()
    key = _digest(design)
    grams = memo.get(key)
    if grams is None:
        grams = build()
        memo.put(key, grams)
        return grams
    return grams.with_targets(u, Dt, free)


def _digest(parts: tuple) -> bytes:
    """A digest of ``parts``: arrays by shape, type and bytes, the rest by ``repr``."""
    h = hashlib.blake2b(digest_size=20)
    for part in parts:
        if isinstance(part, np.ndarray):
            a = np.ascontiguousarray(part)
            h.update(repr(("array", a.shape, a.dtype.str)).encode())
            h.update(a.tobytes())
        else:
            h.update(repr(part).encode())
    return h.digest()


class _GramMemo:
    """The fold sums of the last designs, by :func:`_digest` of what they follow from, up
    to ``max_bytes`` of arrays (least recently used dropped first)."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._entries: OrderedDict[bytes, tuple[_FoldGrams, int]] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = self.misses = 0

    def get(self, key: bytes) -> _FoldGrams | None:
        with self._lock:
            entry = self._entries.get(key)
            if entry is None:
                self.misses += 1
                return None
            self._entries.move_to_end(key)
            self.hits += 1
            return entry[0]

    def put(self, key: bytes, grams: _FoldGrams) -> None:
        size = sum(a.nbytes for a in (grams.A, grams.G, grams.Ak)
                   if a is not None) + (0 if grams.D is None else grams.D.nbytes)
        if size > self.max_bytes:
            return
        with self._lock:
            self._entries[key] = (grams, size)
            while sum(s for _, s in self._entries.values()) > self.max_bytes:
                self._entries.popitem(last=False)


_MEMO: contextvars.ContextVar[_GramMemo | None] = contextvars.ContextVar(
    "trend_kernel_gram_memo", default=None)
#: What :func:`shared_sums` keeps at most: a few length scales' sums of a LASA-sized fit.
MEMO_BYTES = 64 * 2**20


@contextlib.contextmanager
def shared_sums(max_bytes: int = MEMO_BYTES) -> Iterator[_GramMemo]:
    """Within this context, the trend-kernel CV searches of equal designs share their fold
    sums (:meth:`_CVData.kernel_sums`), whatever their targets.

    A fit that refits its global model on the same samples with other potentials (a
    tracking lag, each demonstration on its own clock, the models without each fold)
    or that scores one length scale twice sums its Grams, most of a search's cost
    outside the solves, once (:func:`memo_sums`). The results
    are the same to the last bit: the sums of a design do not depend on the targets. The
    memo lives as long as the context (nested contexts share the outer one's) and is
    local to the thread.
    """
    memo = _MEMO.get()
    if memo is not None:
        yield memo
        return
    memo = _GramMemo(max_bytes)
    token = _MEMO.set(memo)
    try:
        yield memo
    finally:
        _MEMO.reset(token)


def _fold_summary(err: np.ndarray, shape_ss: float) -> list[tuple[float, float]]:
    """CV score and its standard error per candidate from the held-out squared shape
    residuals ``err`` (candidates, folds) and the spread ``shape_ss`` of all samples."""
    n_folds = err.shape[1]
    # Per fold scaled so that the mean over folds is the total error over the spread.
    err = err * (n_folds / shape_ss)
    with np.errstate(invalid="ignore"):
        se = np.std(err, axis=1, ddof=1) / math.sqrt(n_folds)
    return [(float(e), float(s)) for e, s in zip(err.mean(axis=1), se, strict=True)]


def direction_rows(bases: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Direction rows (m, n - 1, p): ``bases`` (m, n - 1, n; :func:`direction_bases`) applied
    to the feature gradients ``J`` (m, n, p); a row is zero when the model's gradient follows
    the sample's motion."""
    return np.einsum("mij,mjp->mip", bases, J)


def direction_bases(steps: np.ndarray, weight: float) -> np.ndarray:
    """Per sample, ``sqrt(weight) |s|`` times an orthonormal basis (rows) of the directions
    across its step ``s``: ``R`` (m, n - 1, n) with ``R' R = weight |s|^2 (I - s s' / |s|^2)``.

    A direction row ``R grad f`` then penalises the slope across the motion exactly as the
    projector ``sqrt(weight) |s| (I - s s' / |s|^2)`` does (the same sum of squares), with
    ``n - 1`` rows per sample instead of ``n`` (half the rows in 2-D). The basis is the
    last ``n - 1`` rows of the Householder reflection that maps ``s / |s|`` to an axis.

    Parameters
    ----------
    steps : ndarray (m, n)
        Each sample's step along its demonstration (standardised state units).
    weight : float
        How much a slope across the motion over one step costs, against an error of the
        same size in the potential's values.

    Returns
    -------
    ndarray (m, n - 1, n)
        Zero for a sample that does not move.
    """
    norm = np.linalg.norm(steps, axis=1)
    unit = np.divide(steps, norm[:, None], out=np.zeros_like(steps), where=norm[:, None] > 0)
    n = steps.shape[1]
    h = unit.copy()
    h[:, 0] += np.where(unit[:, 0] >= 0.0, 1.0, -1.0)  # |h| >= 1: no cancellation
    H = np.eye(n)[None] - 2.0 * h[:, :, None] * h[:, None, :] / np.einsum(
        "ij,ij->i", h, h)[:, None, None]
    return H[:, 1:, :] * (np.sqrt(weight) * norm)[:, None, None]


def along_motion(steps: np.ndarray, drops: np.ndarray, bases: np.ndarray, weight: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The direction ``bases`` (m, n - 1, n; :func:`direction_bases`) with a first row along
    each sample's motion, and what the rows observe: the potential's slope along the step
    ``s`` is its estimate's drop over the step per unit length, ``d / |s|`` (under a
    constraint too: along a motion ``N pi`` the slope of ``phi`` is ``-|N pi|``), and across
    it zero.

    The row along is ``sqrt(weight) s_ref s' / |s|``: every sample weighs the same, as in
    the values, whatever its speed, so where a teacher sets off slowly or comes to rest
    the potential is as flat as the demonstration. ``s_ref`` is the median step, which
    keeps the weight's meaning that of the rows across at a typical step. Steps shorter
    than :data:`MIN_STEP` of it (a rest, whose direction is noise) get no row along.

    Parameters
    ----------
    steps : ndarray (m, n)
        Each sample's step (standardised state units).
    drops : ndarray (m,)
        The potential estimate's change over that step (standardised potential units;
        negative downhill).
    bases : ndarray (m, n - 1, n)
        The samples' rows across their motion.
    weight : float
        The weight of the rows along against an error of the same size in the values.

    Returns
    -------
    bases : ndarray (m, n, n)
    targets : ndarray (m, n)
        Zero but in the first column.
    """
    norm = np.linalg.norm(steps, axis=1)
    ref = float(np.median(norm)) if len(norm) else 0.0
    moving = norm > MIN_STEP * ref
    gain = np.divide(math.sqrt(weight) * ref, norm, out=np.zeros_like(norm), where=moving)
    along = (gain[:, None] * steps)[:, None, :]
    targets = np.zeros((len(steps), steps.shape[1]))
    targets[:, 0] = gain * drops
    return np.concatenate([along, bases], axis=1), targets
