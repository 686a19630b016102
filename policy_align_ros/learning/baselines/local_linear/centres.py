"""Field centres of the local-linear regression: their cover of the data, the neighbour
index between points and centres, and per-field widths.

Notation and units: ``X`` (m, n) data and ``centres`` (C, n) in state units, ``h`` a field
width (state units).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from policy_align_ros.learning.baselines.local_linear.kernels import (
    CUTOFF,
    FAR_WIDENING,
    blend_width2,
    kernel,
)

__all__ = ["CentreIndex", "FarthestPointCover", "adaptive_widths", "neighbour_distance"]

#: Spacing of the cover of centres in units of ``h``.
SPACING = 1.0
#: Largest number of points used to place centres (a random subsample beyond).
MAX_COVER_POINTS = 20000
#: Largest number of points used for cross-validation (whole trajectories, thinned).
#: Rows of data processed at once, to bound memory.
CHUNK = 20000
#: Up to this input dimension neighbours are found with a k-d tree, beyond with BLAS.
KDTREE_MAX_DIM = 4
#: Entries of one block of dense point-centre distances.
DENSE_BLOCK = 250_000
#: A dense block of weights is made sparse below this fraction of non-zeros.
DENSE_FRACTION = 0.1
#: Per-field widths (``widths="adaptive"``): exponent of the local spacing ratio,
#: neighbour rank defining the spacing, and the clip of the ratio (see :func:`adaptive_widths`).
ADAPT_EXPONENT = 0.5
ADAPT_NEIGHBOURS = 30
ADAPT_CLIP = (0.5, 1.0)
#: 2 added the optional arrays ``floors`` and ``softness`` (version 1: linear models);


class FarthestPointCover:
    """Centres in farthest-point order, giving a cover of the data for every radius.

    Each new centre is the (subsampled) data point farthest from the centres so far, so
    the first ``k`` centres lie at least ``radii[k - 1]`` apart and cover every point
    within ``radii[k]``, the distance of the next one: LWPR's rule of adding a receptive
    field where no field is active, for all widths at once. The order is extended lazily,
    as finer covers are asked for.

    Parameters
    ----------
    X : ndarray, shape (m, n)
        Data (state units).
    max_centers : int
        Cap on the number of centres.
    rng : numpy.random.Generator
        Picks the subsample (``MAX_COVER_POINTS``) and the first centre.
    """

    def __init__(self, X: np.ndarray, max_centers: int, rng: np.random.Generator) -> None:
        self.points = X[rng.permutation(X.shape[0])[:MAX_COVER_POINTS]]
        self.max_centers = min(max_centers, len(self.points))
        self.sq = np.einsum("ij,ij->i", self.points, self.points)
        self.order = [0]
        self.radii = [math.inf]
        self.dist = self._sqdist(0)

    def _sqdist(self, i: int) -> np.ndarray:
        d = self.sq + self.sq[i] - 2.0 * (self.points @ self.points[i])
        return np.maximum(d, 0.0, out=d)

    @property
    def capped(self) -> bool:
        """Whether the cap on centres has been reached."""
        return len(self.order) >= self.max_centers

    def centres(self, radius: float) -> np.ndarray:
        """Fewest leading centres covering the data within ``radius`` (or the cap).

        Returns
        -------
        ndarray, shape (C, n)
        """
        limit = radius * radius
        while not self.capped:
            i = int(np.argmax(self.dist))
            if self.dist[i] <= limit:
                break
            self.order.append(i)
            self.radii.append(math.sqrt(self.dist[i]))
            np.minimum(self.dist, self._sqdist(i), out=self.dist)
        count = max(1, int(np.sum(np.asarray(self.radii) > radius)))
        return self.points[self.order[:count]]

    @property
    def radius(self) -> float:
        """Cover radius of all centres placed so far (state units)."""
        return float(np.sqrt(self.dist.max()))


class CentreIndex:
    """Kernel weights between points and fixed centres, block by block.

    Below ``KDTREE_MAX_DIM`` dimensions neighbours come from a k-d tree and blocks are
    sparse. Above, k-d trees lose their edge, and blocks of squared distances
    ``|x|^2 + |c|^2 - 2 x.c`` come from one matrix product; a block stays dense when more
    than ``DENSE_FRACTION`` of its weights are non-zero, else it is made sparse.

    Parameters
    ----------
    centres : ndarray, shape (C, n)
        Centres (state units).
    """

    def __init__(self, centres: np.ndarray) -> None:
        self.centres = centres
        self.tree = cKDTree(centres) if centres.shape[1] <= KDTREE_MAX_DIM else None
        self.sq = np.einsum("ij,ij->i", centres, centres)

    def _starts(self, m: int) -> tuple[range, int]:
        step = CHUNK if self.tree is not None else DENSE_BLOCK // len(self.centres)
        step = max(1, min(step, CHUNK))
        return range(0, m, step), step

    def _sqdist(self, X: np.ndarray) -> np.ndarray:
        d2 = np.einsum("ij,ij->i", X, X)[:, None] + self.sq[None, :]
        d2 -= 2.0 * (X @ self.centres.T)
        return np.maximum(d2, 0.0, out=d2)

    def _exact(self, X: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        diff = X[rows] - self.centres[cols]
        return np.einsum("ij,ij->i", diff, diff)

    def weight_blocks(self, X: np.ndarray, h: float):
        """Kernel weights ``g(||x_i - c_j||^2)`` for consecutive blocks of points.

        Parameters
        ----------
        X : ndarray, shape (m, n)
        h : float or ndarray, shape (C,)
            Field width, common or per field (state units).

        Yields
        ------
        start, stop : int
            The block is ``X[start:stop]``.
        W : ndarray or scipy.sparse.csr_matrix, shape (stop - start, C)
        """
        C = len(self.centres)
        hs = np.asarray(h, dtype=float)
        per_field = hs.ndim > 0
        radius = CUTOFF * float(hs.max())
        starts, step = self._starts(X.shape[0])
        for start in starts:
            Xb = X[start : start + step]
            b = len(Xb)
            if self.tree is not None:
                res = cKDTree(Xb).sparse_distance_matrix(
                    self.tree, radius, output_type="ndarray"
                )
                rows, cols = res["i"].astype(np.intp), res["j"].astype(np.intp)
            else:
                d2 = self._sqdist(Xb)
                mask = d2 < radius * radius
                if mask.mean() > DENSE_FRACTION:
                    yield start, start + b, kernel(d2, hs * hs, derivative=False)
                    continue
                rows, cols = np.nonzero(mask)
            h2 = hs[cols] ** 2 if per_field else hs * hs
            w = kernel(self._exact(Xb, rows, cols), h2, derivative=False)
            yield start, start + b, sp.csr_matrix((w, (rows, cols)), shape=(b, C))

    def relative_blocks(self, X: np.ndarray, h: float | np.ndarray, derivative: bool = True):
        """Blending weights of every point on the centres, by blocks.

        ``v_j = g(rel_j; H_j^2)`` with ``rel_j = ||x - c_j||^2 - t``, ``t = d_min(x)^2``, and
        the width ``H_j^2 = blend_width2(t, h_j)``, which equals ``h_j^2`` near the data and
        grows with the distance far from it. Every point keeps at least its nearest centre
        (``v = 1``), however far it is.

        Parameters
        ----------
        X : ndarray, shape (m, n)
        h : float or ndarray, shape (C,)
            Field width, common or per field (state units). Per field, ``d H_j^2 / d t``
            differs between fields, so it is folded into the returned ``dv/dH^2`` and
            ``dwidth`` is 1.
        derivative : bool
            Also compute the derivatives (else they are None).

        Yields
        ------
        start, stop : int
            The block is ``X[start:stop]``.
        nearest : ndarray of intp, shape (b,)
            Index of each point's nearest centre.
        dwidth : ndarray, shape (b,), or None
            ``d H^2 / d t`` per point.
        weights : tuple
            Dense ``(v, dv/drel, dv/dH^2)``, each (b, C); or sparse
            ``(rows, cols, v, dv/drel, dv/dH^2)``, each (nnz,).
        """
        hs = np.asarray(h, dtype=float)
        per_field = hs.ndim > 0
        hmax = float(hs.max())
        a2 = FAR_WIDENING * FAR_WIDENING
        starts, step = self._starts(X.shape[0])
        for start in starts:
            Xb = X[start : start + step]
            b = len(Xb)
            if self.tree is None:
                d2 = self._sqdist(Xb)
                nearest = np.argmin(d2, axis=1)
                t = d2[np.arange(b), nearest]
            else:
                dmin, nearest = self.tree.query(Xb, k=1)
                nearest = np.asarray(nearest, dtype=np.intp)
                t = dmin * dmin
            # Support of every field: rel < CUTOFF^2 H_j^2. Per field, H^2 is not monotonic
            # in h, but H_j^2 <= h_j^2 + a^2 t bounds it.
            reach = hmax * hmax + a2 * t if per_field else blend_width2(t, hmax)[0]
            reach *= CUTOFF * CUTOFF
            if self.tree is None:
                rel = d2 - t[:, None]
                mask = rel < reach[:, None]
                if mask.mean() > DENSE_FRACTION:
                    rel = np.maximum(rel, 0.0, out=rel)
                    yield start, start + b, nearest, *self._weights(rel, t, hs, derivative)
                    continue
                rows, cols = np.nonzero(mask)
            else:
                lists = self.tree.query_ball_point(Xb, np.sqrt(t + reach), return_sorted=False)
                lens = np.fromiter(map(len, lists), dtype=np.intp, count=len(lists))
                chain = itertools.chain.from_iterable(lists)
                rows = np.repeat(np.arange(b), lens)
                cols = np.fromiter(chain, dtype=np.intp, count=int(lens.sum()))
            # Exact pairwise distances: the weights are then exactly smooth functions of x.
            t = self._exact(Xb, np.arange(b), nearest)
            rel = np.maximum(self._exact(Xb, rows, cols) - t[rows], 0.0)
            rel[cols == nearest[rows]] = 0.0
            dwidth, weights = self._weights(rel, t, hs, derivative, rows, cols)
            yield start, start + b, nearest, dwidth, (rows, cols, *weights)

    @staticmethod
    def _weights(rel, t, hs, derivative, rows=None, cols=None):
        """``dwidth`` and the weights ``(v, dv/drel, dv/dH^2)`` of a block.

        ``rel`` is dense, (b, C), without ``rows`` and ``cols``, else per pair (nnz,).
        """
        if hs.ndim == 0:
            # A common width is the per-field case with all h_j equal, but H^2 is then one
            # per point: computing it per pair and folding dH^2/dt into every weight would
            # slow the common case down for nothing.
            w2, dw2 = blend_width2(t, float(hs))
            w2 = w2[:, None] if rows is None else w2[rows]
        elif rows is None:
            w2, dw2 = blend_width2(t[:, None], hs[None, :])
        else:
            w2, dw2 = blend_width2(t[rows], hs[cols])
        if not derivative:
            return None, (kernel(rel, w2, derivative=False), None, None)
        v, dvs, dvh = kernel(rel, w2)
        if hs.ndim == 0:
            return dw2, (v, dvs, dvh)
        # dH_j^2/dt differs between fields: folded in here, the blend's common factor is 1.
        return np.ones(len(t)), (v, dvs, dvh * dw2)


def neighbour_distance(centres: np.ndarray, X: np.ndarray, k: int) -> np.ndarray:
    """Distance from every centre to its ``k``-th nearest sample of ``X``.

    Parameters
    ----------
    centres : ndarray, shape (C, n)
    X : ndarray, shape (m, n)
    k : int
        Rank, clipped to ``m`` (a centre that is a sample counts itself as the first).

    Returns
    -------
    ndarray, shape (C,)
        State units.
    """
    k = max(1, min(k, len(X)))
    if X.shape[1] <= KDTREE_MAX_DIM:
        dist, _ = cKDTree(X).query(centres, k=[k])
        return dist[:, 0]
    sq = np.einsum("ij,ij->i", X, X)
    out = np.empty(len(centres))
    step = max(1, DENSE_BLOCK // len(X))
    for a in range(0, len(centres), step):
        c = centres[a : a + step]
        d2 = np.einsum("ij,ij->i", c, c)[:, None] + sq[None, :] - 2.0 * (c @ X.T)
        out[a : a + step] = np.partition(d2, k - 1, axis=1)[:, k - 1]
    return np.sqrt(np.maximum(out, 0.0))


def adaptive_widths(centres: np.ndarray, X: np.ndarray, h: float) -> np.ndarray:
    """Per-field widths ``h_j = h clip((rho_j / median(rho)) ** a, lo, hi)``.

    ``rho_j`` is the distance from centre ``j`` to its ``ADAPT_NEIGHBOURS``-th nearest
    sample (of at most ``MAX_COVER_POINTS``, taken at a regular stride), a measure of the
    local spacing of the data; ``a = ADAPT_EXPONENT`` and ``(lo, hi) = ADAPT_CLIP``. Fields
    where the data are denser than typical get narrower, as LWPR's adapted metrics do.

    Parameters
    ----------
    centres : ndarray, shape (C, n)
    X : ndarray, shape (m, n)
        Same origin as ``centres``.
    h : float
        Global width (state units).

    Returns
    -------
    ndarray, shape (C,)
        Widths (state units), positive.
    """
    stride = max(1, math.ceil(len(X) / MAX_COVER_POINTS))
    rho = neighbour_distance(centres, X[::stride], ADAPT_NEIGHBOURS)
    scale = float(np.median(rho))
    if not scale > 0.0:
        return np.full(len(centres), float(h))
    lo, hi = ADAPT_CLIP
    ratio = np.maximum(rho / scale, np.finfo(float).tiny)
    return float(h) * np.clip(ratio**ADAPT_EXPONENT, lo, hi)
