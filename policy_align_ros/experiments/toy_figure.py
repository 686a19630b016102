"""A figure like the paper's Fig. 3 for one toy data set (parabola, K = N = 40, narrow).

Panels: (a) trajectories over the true potential's contours; (b) Euler potentials along
the trajectories before and (c) after alignment, outliers as light crosses; (d) learnt and
(e) true potential.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from policy_align_ros.experiments.toy import POTENTIALS, make_toy_dataset  # noqa: E402
from policy_align_ros.learning import PolicyAlign  # noqa: E402
from policy_align_ros.learning.outliers import largest_group  # noqa: E402
from policy_align_ros.learning.potential import euler_potential  # noqa: E402

__all__ = ["plot_toy_figure"]


def plot_toy_figure(path: str | Path, seed: int = 0, sigma: str = "narrow") -> Path:
    """Fit one parabola data set and draw the five panels to ``path`` (PNG)."""
    rng = np.random.default_rng(seed)
    data = make_toy_dataset("parabola", 40, 40, rng)
    model = PolicyAlign(sigma=sigma, random_state=seed).fit(data.trajectories)
    kept = set(largest_group(model.groups_).tolist())

    grid = np.linspace(-2.2, 2.2, 60)
    G1, G2 = np.meshgrid(grid, grid)
    G = np.column_stack([G1.ravel(), G2.ravel()])
    true = POTENTIALS["parabola"](G)[0].reshape(G1.shape)
    learnt = model.potential(G).reshape(G1.shape)
    learnt -= learnt.min() - true.min()  # the potential is defined up to a constant

    fig = plt.figure(figsize=(16, 7.5))
    ax = fig.add_subplot(2, 3, 1)
    ax.contour(G1, G2, true, levels=12, colors="0.75", linewidths=0.8)
    for k, traj in enumerate(data.trajectories):
        style = dict(color="C0", lw=1.0) if k in kept else dict(color="C3", lw=1.0, ls="--")
        ax.plot(traj.positions[:, 0], traj.positions[:, 1], **style)
    ax.set(title="(a) trajectories (red dashed: outside the aligned set)", xlabel="x1",
           ylabel="x2",
           aspect="equal")

    panels = [
        (2, "(b) Euler potentials before alignment", [euler_potential(t.positions)
                                                      for t in data.trajectories]),
        (3, "(c) after alignment", model.aligned_potentials_),
    ]
    for index, title, potentials in panels:
        ax = fig.add_subplot(2, 3, index, projection="3d")
        for k, (traj, phi) in enumerate(zip(data.trajectories, potentials, strict=True)):
            x1, x2 = traj.positions.T
            if k in kept:
                ax.plot(x1, x2, phi, color="C0", lw=0.9)
            else:
                ax.scatter(x1, x2, phi, color="C3", marker="x", s=6, alpha=0.35)
        ax.set(title=title, xlabel="x1", ylabel="x2")

    for index, title, surface in [(4, "(d) learnt potential", learnt),
                                  (5, "(e) true potential", true)]:
        ax = fig.add_subplot(2, 3, index, projection="3d")
        ax.plot_surface(G1, G2, surface, cmap="viridis", linewidth=0, antialiased=True)
        ax.set(title=title, xlabel="x1", ylabel="x2")

    ax = fig.add_subplot(2, 3, 6)
    coarse = np.linspace(-2.0, 2.0, 13)
    sub = np.column_stack([c.ravel() for c in np.meshgrid(coarse, coarse)])
    pi_true = POTENTIALS["parabola"](sub)[1]
    pi_hat = model.policy(sub)
    ax.quiver(sub[:, 0], sub[:, 1], pi_true[:, 0], pi_true[:, 1], color="0.3",
              label="true policy")
    ax.quiver(sub[:, 0], sub[:, 1], pi_hat[:, 0], pi_hat[:, 1], color="C3", alpha=0.7,
              label="learnt -grad f")
    ax.set(title="unconstrained policy", xlabel="x1", ylabel="x2", aspect="equal")
    ax.legend(loc="upper right", fontsize=8)

    fig.suptitle(
        f"Toy data (parabola, K=N=40, sigma {sigma}): {len(kept)} of "
        f"{len(data.trajectories)} trajectories aligned, {len(model.inliers_) - len(kept)} "
        f"levelled by the global model, sigma^2 = {model.sigma2_:.2g}"
    )
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
