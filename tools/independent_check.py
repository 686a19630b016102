#!/usr/bin/env python3
"""PolicyAlign on data generated independently of the package's own benchmarks.

The suite's data come from :mod:`policy_align_ros.experiments`; this script has its own
generator, so that defaults tuned on the suite are tried on data they never saw, as a user
would try them. Every demonstration integrates ``xdot = N(x, t) pi(x)`` (RK4, 20 substeps
per sample), ``N = I - A^+ A`` with ``A`` a Gaussian (k, n) matrix, ``k`` uniform in
``1..n/2``, re-drawn at 1-3 random times; velocities are recorded at the samples; starts
are uniform in ``c +- hw`` per coordinate. Problems (``--problem``):

1. 5-D ``phi = sum_i w_i log cosh(x_i - c_i)`` (grows linearly far from ``c``), 50 Hz,
   40 demonstrations of 4 s, ``hw = 2.5``;
2. 10-D rotated quadratic, condition number 30, 20 Hz, 60 demonstrations of 5 s;
3. 3-D ``phi = r^2 / 2 + 0.3 r^4``, 100 Hz, 30 demonstrations of 3 s;
4. 6-D quadratic, 12 demonstrations at 10 Hz;
5. 4-D quadratic with position noise (std 2e-3, box size 2), 50 Hz, 40 demonstrations;
6. 22-D anisotropic quadratic (condition 10) off the origin, 10 Hz, 100 demonstrations of
   6 s;
7. 7-D rotated quadratic under joint locks: ``A`` is 1 to 3 rows of the identity (locked
   joints), 50 Hz, 40 demonstrations of 4 s;
8. 3-D anisotropic quadratic sampled with jittered time steps (50 Hz +- 30 %), positions
   and times only;
9. 12-D rotated ``sum_i w_i (z_i^2 / 2 + z_i^4 / 4)``, ``z = R (x - c)``, 20 Hz, 30
   demonstrations of 5 s.

``PolicyAlign(random_state=0)`` with its defaults is scored by nUPE and nCPE on 10
held-out demonstrations from new starts, and closed loop: ``xdot = pi_hat(x)`` from 10 new
starts (RK4 at the data's time step) over the horizon in which the true policy gets within
1 % of its start distance from every start; the final distance to ``c`` over the start
distance (median and max). For reference (an upper-bound-style fit the package never
gets), a global quadratic fitted with a small ridge to the *true* potential values at
the training samples.

``--rest S`` holds every training demonstration still for ``S`` seconds before and after its
motion (``N = 0``; a recorder left running), the motion starting at a random instant inside
a sample period; the random draws of the problem are the same as without it.

Usage: ``python tools/independent_check.py --problem 1 [--seed 1001] [--no-velocities]
[--rest 1.0]``; prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

import numpy as np

from policy_align_ros.learning import PolicyAlign, Trajectory, metrics

Field = Callable[[np.ndarray], np.ndarray]


def make_problem(pid: int, rng: np.random.Generator) -> dict:
    """Potential ``phi`` (m, n) -> (m,), policy ``pi`` (m, n) -> (m, n) and sampling."""
    if pid == 1:
        n = 5
        c, w = rng.uniform(-0.5, 0.5, n), rng.uniform(0.5, 3.0, n)
        return dict(n=n, c=c, hw=2.5, rate=50, demos=40, T=4.0, noise=0.0,
                    phi=lambda X: np.sum(w * np.log(np.cosh(X - c)), axis=-1),
                    pi=lambda X: -w * np.tanh(X - c))
    if pid in (2, 4, 5):
        n, cond, rate, demos, T = {2: (10, 30.0, 20, 60, 5.0), 4: (6, 6.0, 10, 12, 5.0),
                                   5: (4, 6.0, 50, 40, 4.0)}[pid]
        Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
        scale = 0.5
        W = Q @ np.diag(scale * np.geomspace(1.0, cond, n)) @ Q.T
        c = rng.uniform(-1.0, 1.0, n) if pid == 2 else rng.uniform(-0.5, 0.5, n)
        return dict(n=n, c=c, hw=1.0, rate=rate, demos=demos, T=T,
                    noise=2e-3 if pid == 5 else 0.0,
                    phi=lambda X: 0.5 * np.einsum("...i,ij,...j->...", X - c, W, X - c),
                    pi=lambda X: -(X - c) @ W)
    if pid == 3:
        n = 3
        c = rng.uniform(-0.5, 0.5, n)

        def phi(X: np.ndarray) -> np.ndarray:
            r2 = np.sum((X - c) ** 2, axis=-1)
            return 0.5 * r2 + 0.3 * r2**2

        def pi(X: np.ndarray) -> np.ndarray:
            d = X - c
            return -(1.0 + 1.2 * np.sum(d**2, axis=-1, keepdims=True)) * d

        return dict(n=n, c=c, hw=1.0, rate=100, demos=30, T=3.0, noise=0.0, phi=phi, pi=pi)
    if pid in (6, 7, 8):
        n, cond, rate, demos, T = {6: (22, 10.0, 10, 100, 6.0), 7: (7, 8.0, 50, 40, 4.0),
                                   8: (3, 5.0, 50, 40, 4.0)}[pid]
        Q = np.linalg.qr(rng.normal(size=(n, n)))[0] if pid == 7 else np.eye(n)
        W = Q @ np.diag(0.5 * rng.permutation(np.geomspace(1.0, cond, n))) @ Q.T
        c = rng.uniform(-1.0, 1.0, n)
        return dict(n=n, c=c, hw=1.0, rate=rate, demos=demos, T=T, noise=0.0,
                    locks=pid == 7, jitter=0.3 if pid == 8 else 0.0,
                    phi=lambda X: 0.5 * np.einsum("...i,ij,...j->...", X - c, W, X - c),
                    pi=lambda X: -(X - c) @ W)
    if pid == 9:
        n = 12
        R = np.linalg.qr(rng.normal(size=(n, n)))[0]
        c, w = rng.uniform(-0.5, 0.5, n), rng.uniform(0.3, 1.5, n)

        def phi(X: np.ndarray) -> np.ndarray:
            z = (X - c) @ R.T
            return np.sum(w * (0.5 * z**2 + 0.25 * z**4), axis=-1)

        def pi(X: np.ndarray) -> np.ndarray:
            z = (X - c) @ R.T
            return -(w * (z + z**3)) @ R

        return dict(n=n, c=c, hw=1.0, rate=20, demos=30, T=5.0, noise=0.0, phi=phi, pi=pi)
    raise ValueError(f"--problem: expected 1-9, got {pid}")


def random_projector(n: int, rng: np.random.Generator, locks: bool = False) -> np.ndarray:
    """``N = I - A^+ A`` (n, n) of a Gaussian ``A`` with 1 to n/2 rows, or (``locks``) of
    1 to 3 rows of the identity."""
    if locks:
        A = np.eye(n)[rng.choice(n, rng.integers(1, 4), replace=False)]
    else:
        A = rng.normal(size=(rng.integers(1, max(1, n // 2) + 1), n))
    return np.eye(n) - np.linalg.pinv(A) @ A


def rk4(f: Field, x: np.ndarray, h: float, steps: int) -> np.ndarray:
    for _ in range(steps):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


def demonstration(P: dict, x0: np.ndarray, rng: np.random.Generator, sub: int = 20,
                  rest: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Positions (N, n), times (N,), velocities (N, n) and projectors (N, n, n);
    ``rest``: seconds held still (``N = 0``) before and after the motion."""
    n, dt = P["n"], 1.0 / P["rate"]
    samples = int(round((P["T"] + 2 * rest) * P["rate"])) + 1
    switches = np.sort(rng.uniform(0.1 * P["T"], 0.9 * P["T"], rng.integers(1, 4)))
    projectors = [random_projector(n, rng, P.get("locks", False))
                  for _ in range(len(switches) + 1)]
    if rest > 0.0:
        # The motion starts inside a sample period, from a stream of its own.
        start = rest + np.random.default_rng(x0.view(np.uint64)).uniform(0.0, dt)
        switches = np.concatenate([[start], start + switches, [start + P["T"]]])
        projectors = [np.zeros((n, n)), *projectors, np.zeros((n, n))]
    times = np.arange(samples) * dt
    if P.get("jitter", 0.0):
        steps = dt * (1.0 + P["jitter"] * rng.uniform(-1.0, 1.0, samples - 1))
        times = np.concatenate([[0.0], np.cumsum(steps)])
    X, V, Ns = np.empty((samples, n)), np.empty((samples, n)), np.empty((samples, n, n))
    x = x0.copy()
    for i, t in enumerate(times):
        N = projectors[int(np.searchsorted(switches, t, side="right"))]
        X[i], V[i], Ns[i] = x, N @ P["pi"](x[None])[0], N
        h = (times[i + 1] - t) / sub if i + 1 < samples else 0.0
        for s in range(sub if i + 1 < samples else 0):
            # The constraint in force over this substep.
            N = projectors[int(np.searchsorted(switches, t + (s + 0.5) * h, side="right"))]
            x = rk4(lambda y, N=N: N @ P["pi"](y[None])[0], x, h, 1)
    return X, times, V, Ns


def quadratic_reference(X: np.ndarray, phi: np.ndarray, ridge: float = 1e-6) -> Field:
    """Policy of a global quadratic fitted to potential values ``phi`` at ``X``."""
    n = X.shape[1]
    iu = np.triu_indices(n)

    def features(Y: np.ndarray) -> np.ndarray:
        outer = Y[:, :, None] * Y[:, None, :]
        return np.hstack([outer[:, iu[0], iu[1]], Y, np.ones((len(Y), 1))])

    F = features(X)
    s = F.std(axis=0)
    s[s == 0] = 1.0
    coef = np.linalg.solve((F / s).T @ (F / s) + ridge * len(F) * np.eye(F.shape[1]),
                           (F / s).T @ phi) / s
    upper = np.zeros((n, n))
    upper[iu] = coef[: len(iu[0])]
    b = coef[len(iu[0]): len(iu[0]) + n]
    return lambda Y: -(Y @ (upper + upper.T).T + b)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--problem", type=int, required=True)
    parser.add_argument("--seed", type=int, default=None, help="default 1000 + problem")
    parser.add_argument("--no-velocities", action="store_true",
                        help="record positions and times only")
    parser.add_argument("--rest", type=float, default=0.0,
                        help="seconds every training demonstration is held still before "
                             "and after its motion")
    args = parser.parse_args(argv)
    seed = 1000 + args.problem if args.seed is None else args.seed
    rng = np.random.default_rng(seed)
    P = make_problem(args.problem, rng)
    no_velocities = args.no_velocities or P.get("jitter", 0.0) > 0.0
    c, hw = P["c"], P["hw"]

    def starts(m: int) -> np.ndarray:
        return c + rng.uniform(-hw, hw, (m, P["n"]))

    train, X_true, phi_true = [], [], []
    for k, x0 in enumerate(starts(P["demos"])):
        X, t, V, _ = demonstration(P, x0, rng, rest=args.rest)
        recorded = X + P["noise"] * rng.normal(size=X.shape) if P["noise"] else X
        train.append(Trajectory(recorded, t, None if no_velocities else V, name=f"d{k}"))
        X_true.append(recorded)
        phi_true.append(P["phi"](X))
    test = [demonstration(P, x0, rng) for x0 in starts(10)]
    X_test = np.vstack([d[0] for d in test])
    N_test = np.vstack([d[3] for d in test])
    pi_test = P["pi"](X_test)

    t0 = time.perf_counter()
    model = PolicyAlign(random_state=0).fit(train)
    out: dict = {"problem": args.problem, "seed": seed, "n": P["n"], "demos": P["demos"],
                 "rate_hz": P["rate"], "fit_s": time.perf_counter() - t0,
                 "velocities": not no_velocities}
    pi_hat = model.policy(X_test)
    out["nUPE"] = metrics.nupe(pi_test, pi_hat)
    out["nCPE"] = metrics.ncpe(pi_test, pi_hat, N_test)
    reference = quadratic_reference(np.vstack(X_true), np.concatenate(phi_true))
    out["reference_nUPE"] = metrics.nupe(pi_test, reference(X_test))
    out["reference_nCPE"] = metrics.ncpe(pi_test, reference(X_test), N_test)

    dt = 1.0 / P["rate"]
    x0s = starts(10)
    true_field: Field = lambda x: P["pi"](x[None])[0]  # noqa: E731
    horizon = 0
    for x0 in x0s:
        x, k = x0.copy(), 0
        while np.linalg.norm(x - c) > 0.01 * np.linalg.norm(x0 - c) and k < 100_000:
            x, k = rk4(true_field, x, dt, 1), k + 1
        horizon = max(horizon, k)
    out["horizon_s"] = horizon * dt
    fields = {"model": lambda x: model.policy(x[None])[0],
              "reference": lambda x: reference(x[None])[0], "true": true_field}
    for label, field in fields.items():
        ends = [np.linalg.norm(rk4(field, x0, dt, horizon) - c) / np.linalg.norm(x0 - c)
                for x0 in x0s]
        out[f"closed_loop_{label}_median"] = float(np.median(ends))
        out[f"closed_loop_{label}_max"] = float(np.max(ends))
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
