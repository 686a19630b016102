"""The paper's 2-D toy experiment (section IV-B, Table I, Fig. 3).

Notation: state ``x`` in ``R^2``; potentials ``phi(x) = x^T W x`` with ``W = 0.05 I``
(eq. 20, attractor at 0) and ``phi_s(x) = 0.1 sin(x1) cos(x2)`` (eq. 22); policy
``pi = -grad phi``. Each trajectory starts uniformly in ``[-2, 2]^2`` and follows
``x_{i+1} = x_i + N_i pi(x_i)`` (``dt = 1``) under one constraint row ``alpha ~ N(0, I)``
(eq. 21), re-sampled twice at regular intervals (three constant segments).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from policy_align_ros.learning import Trajectory

__all__ = [
    "POTENTIALS",
    "ToyDataset",
    "make_toy_dataset",
    "nullspace_projectors_1row",
]


def _parabola(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return 0.05 * np.sum(X**2, axis=1), -0.1 * X


def _sinusoid(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s1, c1 = np.sin(X[:, 0]), np.cos(X[:, 0])
    s2, c2 = np.sin(X[:, 1]), np.cos(X[:, 1])
    grad = 0.1 * np.stack([c1 * c2, -s1 * s2], axis=1)
    return 0.1 * s1 * c2, -grad


POTENTIALS = {"parabola": _parabola, "sinusoid": _sinusoid}


@dataclass
class ToyDataset:
    """Trajectories with their ground truth at every sample.

    Attributes
    ----------
    trajectories : list of Trajectory
        ``K`` trajectories of ``N`` samples each (``dt = 1``).
    phi, pi : list of ndarray
        True potential (N,) and unconstrained policy (N, 2) at each sample.
    nullspace : list of ndarray
        Projector ``N_i`` (N, 2, 2) of the constraint in force at each sample.
    """

    trajectories: list[Trajectory]
    phi: list[np.ndarray]
    pi: list[np.ndarray]
    nullspace: list[np.ndarray]


def nullspace_projectors_1row(alpha: np.ndarray) -> np.ndarray:
    """``N = I - alpha alpha^T / ||alpha||^2`` for rows ``alpha`` of shape (m, n)."""
    unit = alpha / np.linalg.norm(alpha, axis=1, keepdims=True)
    return np.eye(alpha.shape[1])[None] - unit[:, :, None] * unit[:, None, :]


def make_toy_dataset(
    potential: str, n_traj: int, n_samples: int, rng: np.random.Generator
) -> ToyDataset:
    """Simulate one toy data set.

    Parameters
    ----------
    potential : {"parabola", "sinusoid"}
    n_traj, n_samples : int
        ``K`` trajectories of ``N`` samples.
    rng : numpy Generator

    Returns
    -------
    ToyDataset
    """
    field = POTENTIALS[potential]
    x = rng.uniform(-2.0, 2.0, size=(n_traj, 2))
    # Constraint segment of each sample: three equal parts, so alpha is re-sampled twice.
    segment = np.minimum((3 * np.arange(n_samples)) // n_samples, 2)
    alphas = rng.standard_normal((n_traj, 3, 2))
    projectors = np.stack([nullspace_projectors_1row(alphas[:, s]) for s in range(3)], axis=1)
    X = np.empty((n_traj, n_samples, 2))
    P = np.empty((n_traj, n_samples, 2, 2))
    for i in range(n_samples):
        X[:, i] = x
        P[:, i] = projectors[:, segment[i]]
        _, pi = field(x)
        x = x + np.einsum("kij,kj->ki", P[:, i], pi)
    phi, pi = field(X.reshape(-1, 2))
    phi = phi.reshape(n_traj, n_samples)
    pi = pi.reshape(n_traj, n_samples, 2)
    return ToyDataset(
        trajectories=[Trajectory(X[k], name=str(k)) for k in range(n_traj)],
        phi=list(phi),
        pi=list(pi),
        nullspace=list(P),
    )


# -- Table I reproduction (`policy-align bench toy`) ------------------------------------------

SETUPS = (("parabola", 40, 40), ("sinusoid", 40, 40), ("sinusoid", 100, 100))
RULES = ("narrow", "medium", "wide")
# Table I of the paper: (mean, std) of alignment nMSE, potential nMSE, nUPE, nCPE, discarded %.
PAPER_TABLE_I = {
    ("parabola", 40, "narrow"): ((0.0047, 0.0026), (0.0052, 0.0024), (0.0486, 0.0211),
                                 (0.0235, 0.0092), (17.55, 15.96)),
    ("parabola", 40, "medium"): ((0.0204, 0.0211), (0.0195, 0.0203), (0.0859, 0.0486),
                                 (0.0224, 0.0074), (0.48, 1.11)),
    ("parabola", 40, "wide"): ((0.3542, 0.1089), (0.3143, 0.1045), (0.5758, 0.2726),
                               (0.1135, 0.0371), (0.0, 0.0)),
    ("sinusoid", 40, "narrow"): ((0.0017, 0.0022), (0.0026, 0.0019), (0.1275, 0.1125),
                                 (0.0535, 0.0353), (50.18, 14.37)),
    ("sinusoid", 40, "medium"): ((0.0534, 0.0647), (0.0522, 0.0645), (0.1399, 0.0422),
                                 (0.0376, 0.0097), (1.03, 3.99)),
    ("sinusoid", 40, "wide"): ((0.6259, 0.1330), (0.5670, 0.1363), (0.8373, 0.2188),
                               (0.2464, 0.0638), (0.0, 0.0)),
    ("sinusoid", 100, "narrow"): ((0.0005, 0.0002), (0.0014, 0.0004), (0.0657, 0.0142),
                                  (0.0308, 0.0065), (25.46, 11.42)),
    ("sinusoid", 100, "medium"): ((0.0011, 0.0017), (0.0019, 0.0017), (0.0628, 0.0089),
                                  (0.0284, 0.0044), (1.25, 3.33)),
    ("sinusoid", 100, "wide"): ((0.2892, 0.1198), (0.2137, 0.1000), (0.4262, 0.1367),
                                (0.1554, 0.0483), (0.0, 0.0)),
}


def run_toy_dataset(task: tuple[str, int, int, int]) -> dict[str, dict[str, float]]:
    """Fit one data set with every sigma rule; returns ``{rule: metrics}``.

    ``task`` is ``(potential, K, N, seed)``; the same data and hold-out split serve all
    three rules, as in the paper's table.
    """
    from policy_align_ros.experiments.evaluation import evaluate_policy_align, holdout_masks
    from policy_align_ros.learning import PolicyAlign

    potential, n_traj, n_samples, seed = task
    rng = np.random.default_rng(seed)
    data = make_toy_dataset(potential, n_traj, n_samples, rng)
    masks = holdout_masks([n_samples] * n_traj, rng)
    positions = [t.positions for t in data.trajectories]
    out = {}
    for rule in RULES:
        model = PolicyAlign(sigma=rule, random_state=seed).fit(
            data.trajectories, train_mask=masks
        )
        out[rule] = evaluate_policy_align(
            model, positions, data.phi, data.pi, data.nullspace, masks
        )
    return out
