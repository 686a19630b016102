"""Data shared by the tests of the local-linear regression (not a test module)."""

import numpy as np

W = 0.05  # the paper's toy potential phi(x) = x^T W x, W = 0.05 I


def constrained_trajectories(K, N, n, rng, scale=2.0, rows=1, rate=2 * W):
    """Trajectories descending phi = W ||x||^2 under random constraints (paper IV-B).

    Each trajectory starts uniform in [-scale, scale]^n and follows x += N(-grad phi),
    dt = 1, with ``rows`` random constraint rows re-sampled twice at regular intervals.

    Returns
    -------
    X : ndarray, shape (K * N, n)
    groups : ndarray of int, shape (K * N,)
    """
    T = np.empty((K, N, n))
    for k in range(K):
        x = rng.uniform(-scale, scale, n)
        for seg in np.array_split(np.arange(N), 3):
            A = rng.normal(size=(rows, n))
            P = np.eye(n) - np.linalg.pinv(A) @ A
            for i in seg:
                T[k, i] = x
                x = x - rate * (P @ x)
    return T.reshape(-1, n), np.repeat(np.arange(K), N)


def potential(X):
    return W * np.sum(X**2, axis=1)


def nupe(pi, pi_hat):
    return np.mean(np.sum((pi - pi_hat) ** 2, axis=1)) / np.sum(np.var(pi, axis=0))


def central_differences(fun, X, eps=1e-6):
    cols = [(fun(X + eps * e) - fun(X - eps * e)) / (2 * eps) for e in np.eye(X.shape[1])]
    return np.stack(cols, axis=-1)
