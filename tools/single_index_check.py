"""The single-index trend on potentials far from quadratic (a prototype, not part of the
package; see ``docs/design/single_index.md``), and the default model on the same data.

Usage: ``python tools/single_index_check.py KIND N [SEED [FORM]]`` with ``KIND`` one of ``sat``
(a velocity-limited attractor, ``phi = sqrt(r^2 + q) - r``) or ``quart`` (``phi = q / 2 +
q^2 / (4 r^2)``), ``q = (x - c)' W (x - c)``, in ``N`` dimensions; 30 demonstrations
(80 from 10-D up) of 4 s at 50 Hz under one to three random constraint rows re-drawn at
random times, and 10 more from new starts to score.

``PolicyAlign(regressor=TrendKernelRegression(trend_form=FORM))`` is fitted as a user
would (``FORM`` ``cv``, the default, or ``quadratic`` for the quadratic family alone). Then,
on its aligned potentials, the
single-index model ``f(z) = sum_j beta_j B_j(q(z))`` is fitted, with
``q = ||L'(z - z0)||^2`` (``L`` lower triangular), the basis
of ``single_index.profile_basis`` and ``c_j = s * KNEES`` (``s`` the median of
``sqrt(q)`` at the start), with one free offset per demonstration. ``(L, z0)`` start from
the trend-alone fit of ``TrendKernelRegression`` and are fitted by variable projection
(``policy_align_ros.learning.regressors.trend_kernel.single_index.fit_index``, which this prototype
became): ``beta`` and the offsets come from linear least squares inside the residual,
and the Jacobian is Kaufman's, ``-P_perp (dB/dtheta) beta``. Both models' nUPE on the new
starts is printed.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

from policy_align_ros.learning import PolicyAlign, metrics
from policy_align_ros.learning.regressors import TrendKernelRegression
from policy_align_ros.learning.regressors.trend_kernel.single_index import (
    fit_index,
    index_form,
    profile_basis,
    profile_gradient,
    profile_weights,
)
from policy_align_ros.sim.demonstrations import rollout


class RadialPotential:
    """``phi = g((x - c)' W (x - c))`` for the two profiles ``g`` of the module docstring."""

    def __init__(self, kind: str, centre: np.ndarray, W: np.ndarray, r: float) -> None:
        self.kind, self.centre, self.W, self.r = kind, centre, W, r

    def _q(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        D = np.atleast_2d(X) - self.centre
        return D, np.einsum("ij,jk,ik->i", D, self.W, D)

    def value(self, X: np.ndarray) -> np.ndarray:
        _, q = self._q(X)
        if self.kind == "sat":
            return np.sqrt(self.r**2 + q) - self.r
        return q / 2 + q**2 / (4 * self.r**2)

    def policy(self, X: np.ndarray) -> np.ndarray:
        D, q = self._q(X)
        slope = (1 / np.sqrt(self.r**2 + q) if self.kind == "sat" else 1 + q / self.r**2)
        return -(D @ self.W) * slope[:, None]


def make_potential(kind: str, n: int, rng: np.random.Generator) -> RadialPotential:
    """Condition number 10, centre in [-1, 1]^n."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    W = Q @ np.diag(np.exp(rng.uniform(0, np.log(10), n)) / np.sqrt(10)) @ Q.T
    r = 0.3 * np.sqrt(n) if kind == "sat" else np.sqrt(n)
    return RadialPotential(kind, rng.uniform(-1, 1, n), 3.0 * W, r)


def random_rows(n: int, duration: float, rng: np.random.Generator):
    """One to n/2 random constraint rows, re-drawn at one to three random times."""
    times = np.sort(rng.uniform(0, duration, rng.integers(1, 4)))
    rows = [rng.standard_normal((int(rng.integers(1, max(1, n // 2) + 1)), n))
            for _ in range(len(times) + 1)]

    def constraint(x, t, pi):
        return rows[int(np.searchsorted(times, t))]
    return constraint


def main() -> None:
    kind, n = sys.argv[1], int(sys.argv[2])
    seed = int(sys.argv[3]) if len(sys.argv) > 3 else 7 + 100 * n
    rng = np.random.default_rng(seed)
    pot = make_potential(kind, n, rng)
    k, dt, steps, duration = (30 if n < 10 else 80), 0.02, 200, 4.0
    train = [rollout(pot.centre + rng.uniform(-1, 1, n), pot, random_rows(n, duration, rng),
                     steps, dt, name=str(i)) for i in range(k)]
    test = [rollout(pot.centre + rng.uniform(-1, 1, n), pot, random_rows(n, duration, rng),
                    steps, dt) for _ in range(10)]
    Xt = np.concatenate([d.trajectory.positions for d in test])
    pi = np.concatenate([d.policy for d in test])

    form = sys.argv[4] if len(sys.argv) > 4 else "cv"
    t0 = time.perf_counter()
    model = PolicyAlign(regressor=TrendKernelRegression(trend_form=form), random_state=0)
    model.fit([d.trajectory for d in train])
    print(f"{kind} {n}-D seed {seed}: PolicyAlign(trend_form={form!r}) nUPE "
          f"{metrics.nupe(pi, model.policy(Xt)):.4f} (picked {model.regressor_.trend_form_}, "
          f"fit {time.perf_counter() - t0:.1f} s)")

    X = np.concatenate([d.trajectory.positions for d in train])
    y = np.concatenate(model.aligned_potentials_)
    groups = np.repeat(np.arange(k), steps)
    trend = TrendKernelRegression(trend_form="quadratic", kernel_ridge=math.inf).fit(
        X, y, groups=groups)
    H = trend._p * np.eye(n) + 2.0 * trend._S
    z0 = -np.linalg.solve(H, trend._b)
    lam, V = np.linalg.eigh(H)
    L0 = np.linalg.cholesky((V * np.maximum(lam, 0.01 * lam[-1])) @ V.T)
    sub = np.random.default_rng(0).choice(len(X), min(3000, len(X)), replace=False)
    Z = (X[sub] - trend.mean_) / trend.scale_
    u = (y[sub] - y.mean()) / y.std()
    t0 = time.perf_counter()
    s = math.sqrt(float(np.median(index_form(Z, L0, z0)[1])))
    L, z = fit_index(Z, u, groups[sub], L0, z0, s, max_nfev=50)
    _, demo = np.unique(groups[sub], return_inverse=True)
    beta = profile_weights(profile_basis(index_form(Z, L, z)[1], s)[0], u, demo)
    grad = profile_gradient((Xt - trend.mean_) / trend.scale_, L, z, s, beta)
    nupe = metrics.nupe(pi, -grad * y.std() / trend.scale_)
    print(f"{kind} {n}-D: single-index trend nUPE {nupe:.4f} "
          f"({time.perf_counter() - t0:.1f} s)")

if __name__ == "__main__":
    main()
