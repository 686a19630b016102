"""The paper's ball-grasp experiment (section IV-C, Table II, Fig. 5) on Talos.

State ``x = (p_left, p_right)`` (6,): world positions (m) of the two hand frames
(``gripper_left_base_link``, ``gripper_right_base_link``) of Talos (example-robot-data
``talos_reduced.urdf``, fixed base, world = ``base_link``, x forward, y left, z up).
Start states are the forward kinematics of ``q ~ N(q_0, 0.1 I)`` (variance 0.1 rad^2)
over both arms and the torso (16 joints, clipped to the joint limits; ``q_0`` = SRDF
``half_sitting``). As in the
paper the policy acts in this task space (the paper's whole-body controller realises it
on the joints; here it is assumed to track exactly), with the paper's potential
``phi = (x - x_c)^T W (x - x_c)``, ``W = 0.05 I`` (eq. 20), sampled every ``DT = 0.5 s``.
With the toy's ``dt = 1`` the unconstrained hands reach the target within a few percent
in 30 samples, so the 100-sample demonstrations that grasp end in one point and the
narrow sigma heuristic (median closest approach) collapses to ~1e-10 m^2 (30-40 % of
the demonstrations discarded); at 0.5 s they are still closing in at the end.

Scene: a ball of diameter 0.15 m at ``BALL``; the target ``x_c`` puts the hands either
side of it. Two barrier panels in the plane ``x = BARRIER_X`` between robot and ball
leave a central gap of width ``d_gap ~ N(0.25, 0.1)`` m (one draw per demonstration). A
panel blocks a hand's motion along its normal while the hand is within ``ACTIVATION``
m of it and moving towards it (see :func:`policy_align_ros.kinematics.constraints.
barrier_rows`), so constraints switch on and off and change dimension during a
demonstration. The unseen test constraint is one central panel ``|y| <= 0.15`` m in the
same plane, which the hands must go around.

Protocol: K = 100 demonstrations of N = 100 samples, narrow sigma, 50 data sets; errors
on a held-out random 20 % of the samples of the kept demonstrations (excluded from the
global regression and the naive baseline's training).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from policy_align_ros.experiments.bench import run_robot_bench
from policy_align_ros.experiments.figures import save_figure
from policy_align_ros.experiments.pool import parallel_map
from policy_align_ros.kinematics import Robot, nullspace_projector
from policy_align_ros.kinematics.constraints import barrier_rows
from policy_align_ros.learning import Trajectory
from policy_align_ros.learning.outliers import largest_group
from policy_align_ros.sim.demonstrations import (
    ConstraintFn,
    Demonstration,
    generate_demonstrations,
    held_out_masks,
    stack_ground_truth,
)
from policy_align_ros.sim.experts import QuadraticPotential

__all__ = [
    "Panel",
    "GraspScene",
    "hand_start_states",
    "panel_constraint",
    "make_grasp_dataset",
    "evaluate_dataset",
    "main",
]

HANDS = ("gripper_left_base_link", "gripper_right_base_link")
UPPER_BODY = (
    [f"arm_left_{i}_joint" for i in range(1, 8)]
    + [f"arm_right_{i}_joint" for i in range(1, 8)]
    + ["torso_1_joint", "torso_2_joint"]
)
BALL = np.array([0.45, 0.0, -0.10])  # m, base_link frame
BALL_DIAMETER = 0.15  # m
GRASP_HALF_WIDTH = 0.085  # m: hand frame to ball centre along y (1 cm off the ball)
BARRIER_X = 0.30  # m: plane of the barriers, between robot and ball
PANEL_REACH = 1.0  # m: outer |y| of the panels
GAP_MEAN, GAP_STD = 0.25, 0.10  # m
ACTIVATION = 0.05  # m
UNSEEN_HALF_WIDTH = 0.15  # m
DT = 0.5  # s
WEIGHT = 0.05
START_VARIANCE = 0.1  # rad^2
REACHED = 0.05  # m: a demonstration "reached the ball" if it ends this close to x_c (6-D)
REACHES = 5  # unconstrained reaches from new starts per data set

#: Paper's Table II (mean, std over 50 data sets) and the other quoted numbers.
PAPER_TABLE2 = {
    "training": ((0.1298, 0.0113), (0.1691, 0.0289)),
    "unseen barrier": ((0.5108, 0.0327), (0.2104, 0.0357)),
    "unconstrained": ((0.8766, 0.0589), (0.2277, 0.0386)),
}
PAPER_OTHER = {"alignment nMSE": (6.95e-4, 0.09e-4), "potential nMSE": (7.85e-4, 0.56e-4),
               "discarded (%)": (0.48, 0.84)}


@dataclass(frozen=True)
class Panel:
    """A finite planar barrier: plane through ``point`` with unit ``normal``, existing
    only inside the world box ``[lower, upper]`` (m; infinite entries allowed)."""

    point: np.ndarray
    normal: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


def _panel(y_lo: float, y_hi: float) -> Panel:
    return Panel(np.array([BARRIER_X, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]),
                 np.array([-np.inf, y_lo, -np.inf]), np.array([np.inf, y_hi, np.inf]))


def training_panels(gap: float) -> list[Panel]:
    """The two panels leaving a central gap of width ``gap`` (m)."""
    half = max(gap, 0.0) / 2.0
    return [_panel(half, PANEL_REACH), _panel(-PANEL_REACH, -half)]


def unseen_panels() -> list[Panel]:
    """The unseen test constraint: one central panel ``|y| <= UNSEEN_HALF_WIDTH``."""
    return [_panel(-UNSEEN_HALF_WIDTH, UNSEEN_HALF_WIDTH)]


def panel_constraint(panels: Sequence[Panel], distance: float = ACTIVATION,
                     lookahead: float | None = None) -> ConstraintFn:
    """Task-space constraint of barrier panels acting on both hands.

    Returns
    -------
    ConstraintFn
        ``(x (6,), t, pi (6,)) -> A (k, 6)``: one row ``n^T`` in the hand's three columns
        per (hand, panel) pair in contact; ``k = 0`` when no hand touches a panel.
        ``lookahead`` (s, default :data:`DT`) stops a step from tunnelling through.
    """
    ahead = DT if lookahead is None else lookahead

    def constraint(x: np.ndarray, t: float, pi: np.ndarray) -> np.ndarray:
        rows = []
        for h in range(2):
            cols = slice(3 * h, 3 * h + 3)
            for panel in panels:
                r = barrier_rows(x[cols], panel.point, panel.normal, distance, panel.lower,
                                 panel.upper, velocity=pi[cols], lookahead=ahead)
                if r.shape[0]:
                    row = np.zeros(6)
                    row[cols] = r[0]
                    rows.append(row)
        return np.array(rows).reshape(-1, 6)

    return constraint


@dataclass
class GraspScene:
    """Ground truth of one data set: demonstrations, their gap widths and the expert."""

    demos: list[Demonstration]
    gaps: np.ndarray
    expert: QuadraticPotential


def grasp_target() -> np.ndarray:
    """``x_c`` (6,): left hand at ``+y``, right hand at ``-y`` of the ball, m."""
    offset = np.array([0.0, GRASP_HALF_WIDTH, 0.0])
    return np.concatenate([BALL + offset, BALL - offset])


_ROBOT: Robot | None = None


def _robot() -> Robot:
    # One Pinocchio model per worker process, built once.
    global _ROBOT
    if _ROBOT is None:
        _ROBOT = Robot.load("talos", joints=UPPER_BODY)
    return _ROBOT


def hand_start_states(robot: Robot, rng: np.random.Generator, n: int,
                      variance: float = START_VARIANCE) -> np.ndarray:
    """Hand positions (n, 6), m, from FK of ``q ~ N(q_0, variance I)`` clipped to limits."""
    q0 = robot.neutral()
    Q = robot.clip(q0 + np.sqrt(variance) * rng.standard_normal((n, robot.nq)))
    return np.array([robot.frames_kinematics(q, HANDS)[0].reshape(-1) for q in Q])


def make_grasp_dataset(seed: int, n_traj: int = 100, n_samples: int = 100) -> GraspScene:
    """Simulate one data set of the ball-grasp experiment (seeded)."""
    rng = np.random.default_rng(seed)
    expert = QuadraticPotential(grasp_target(), WEIGHT)
    starts = hand_start_states(_robot(), rng, n_traj)
    gaps = np.maximum(rng.normal(GAP_MEAN, GAP_STD, size=n_traj), 0.0)
    demos = generate_demonstrations(
        expert, starts, lambda k, r: panel_constraint(training_panels(gaps[k])),
        n_samples, DT, rng,
    )
    return GraspScene(demos, gaps, expert)


def _projectors(X: np.ndarray, pi: np.ndarray, constraint: ConstraintFn) -> np.ndarray:
    return np.array([nullspace_projector(constraint(x, 0.0, p), n=6)
                     for x, p in zip(X, pi, strict=True)])


def _policy_rollout(policy, x0: np.ndarray, n_steps: int) -> np.ndarray:
    X = np.empty((n_steps, x0.size))
    x = x0.copy()
    for i in range(n_steps):
        X[i] = x
        x = x + DT * policy(x[None])[0]
    return X


def evaluate_dataset(seed: int, n_traj: int = 100, n_samples: int = 100,
                     figure_starts: int = 0) -> dict:
    """Generate, learn (PolicyAlign and the naive baseline) and score one data set.

    Returns
    -------
    dict
        Metric name -> float, plus ``"rollouts"`` (figure data) when ``figure_starts``.
    """
    from policy_align_ros.learning import PolicyAlign, metrics
    from policy_align_ros.learning.baselines import NaivePolicy

    t0 = time.perf_counter()
    scene = make_grasp_dataset(seed, n_traj, n_samples)
    demos = scene.demos
    rng = np.random.default_rng([seed, 1])
    train, test = held_out_masks(demos, 0.2, rng)
    trajs = [d.trajectory for d in demos]
    t1 = time.perf_counter()
    model = PolicyAlign(sigma="narrow", random_state=seed).fit(trajs, train_mask=train)
    t2 = time.perf_counter()
    naive = NaivePolicy(random_state=seed).fit(
        [_training_part(t, m) for t, m in zip(trajs, train, strict=True)])
    t3 = time.perf_counter()
    gt = stack_ground_truth(demos, test, keep=model.inliers_)
    X, pi = gt["X"], gt["pi"]
    pa_pi, nv_pi = model.policy(X), naive.policy(X)
    aligned = np.concatenate(
        [model.aligned_potentials_[k][test[k]] for k in model.inliers_])
    in_set = np.isin(gt["demo"], largest_group(model.groups_))
    N_unseen = _projectors(X, pi, panel_constraint(unseen_panels()))
    eye = np.broadcast_to(np.eye(6), N_unseen.shape)
    out = {
        # The alignment is scored on its own set; the global model levels the rest.
        "alignment nMSE": metrics.potential_nmse(aligned[in_set], gt["phi"][in_set]),
        "potential nMSE": metrics.potential_nmse(model.potential(X), gt["phi"]),
        "discarded (%)": metrics.percent_discarded(model),
        "unaligned (%)": metrics.percent_unaligned(model),
        "PA training": metrics.ncpe(pi, pa_pi, gt["N"]),
        "PA unseen barrier": metrics.ncpe(pi, pa_pi, N_unseen),
        "PA unconstrained": metrics.ncpe(pi, pa_pi, eye),
        "naive training": metrics.ncpe(pi, nv_pi, gt["N"]),
        "naive unseen barrier": metrics.ncpe(pi, nv_pi, N_unseen),
        "naive unconstrained": metrics.ncpe(pi, nv_pi, eye),
        "PA nUPE": metrics.nupe(pi, pa_pi),
        "reached ball (%)": 100.0 * float(np.mean(
            [np.linalg.norm(d.trajectory.positions[-1] - scene.expert.center) < REACHED
             for d in demos])),
        "constrained samples (%)": 100.0 * float(np.mean(
            np.concatenate([d.n_active > 0 for d in demos]))),
        "unseen active (%)": 100.0 * float(np.mean(
            np.trace(N_unseen, axis1=1, axis2=2) < 5.5)),
        "sigma2": float(model.sigma2_),
        "time generate (s)": t1 - t0,
        "time PolicyAlign (s)": t2 - t1,
        "time naive (s)": t3 - t2,
    }
    # Unconstrained reaches from new starts: each hand's final distance to its target.
    reach_starts = hand_start_states(_robot(), np.random.default_rng([seed, 3]), REACHES)
    for label, policy in (("PA", model.policy), ("expert", scene.expert.policy)):
        ends = np.array([_policy_rollout(policy, s, n_samples)[-1] for s in reach_starts])
        hands = np.linalg.norm((ends - scene.expert.center).reshape(-1, 2, 3), axis=2)
        out[f"{label} reach end, worst hand (mm)"] = 1e3 * float(hands.max())
    if figure_starts:
        starts = hand_start_states(_robot(), np.random.default_rng([seed, 2]), figure_starts)
        out["rollouts"] = {
            "expert": [_policy_rollout(scene.expert.policy, s, n_samples) for s in starts],
            "naive": [_policy_rollout(naive.policy, s, n_samples) for s in starts],
            "PolicyAlign": [_policy_rollout(model.policy, s, n_samples) for s in starts],
            "demos": [d.trajectory.positions for d in demos[:20]],
            "gap": float(scene.gaps[0]),
        }
    return out


def _training_part(traj: Trajectory, mask: np.ndarray) -> Trajectory:
    # The naive model regresses (x_i, xdot_i) pairs, so dropping held-out samples from a
    # trajectory (velocities are recorded, not differenced) removes exactly those pairs.
    return Trajectory(traj.positions[mask], traj.times[mask], traj.velocities[mask],
                      name=traj.name)


def _worker(job: tuple[int, int, int, int]) -> dict:
    seed, n_traj, n_samples, fig = job
    return evaluate_dataset(seed, n_traj, n_samples, figure_starts=fig)


def _fmt(values: Sequence[float], fixed: bool = True) -> str:
    arr = np.asarray(values, dtype=float)
    if fixed:
        return f"{arr.mean():.4f} ± {arr.std():.4f}"
    return f"{arr.mean():.3g} ± {arr.std():.2g}"


def format_table(results: Sequence[dict]) -> str:
    """Markdown tables of the measured numbers beside the paper's (Table II and text)."""
    n = len(results)
    lines = [
        f"### Ball grasp (paper Table II): nCPE, mean ± std over {n} data sets",
        "",
        "| Constraint | Naive (ours) | PolicyAlign (ours) | Naive (paper) "
        "| PolicyAlign (paper) |",
        "|---|---|---|---|---|",
    ]
    for key, label in (("training", "Training"), ("unseen barrier", "Unseen barrier"),
                       ("unconstrained", "Unconstrained")):
        (nm, ns), (pm, ps) = PAPER_TABLE2[key]
        lines.append(
            f"| {label} | {_fmt([r['naive ' + key] for r in results])} "
            f"| {_fmt([r['PA ' + key] for r in results])} "
            f"| {nm:.4f} ± {ns:.4f} | {pm:.4f} ± {ps:.4f} |"
        )
    lines += ["", "| Quantity | ours | paper |", "|---|---|---|"]
    for key, (pm, ps) in PAPER_OTHER.items():
        lines.append(
            f"| {key} | {_fmt([r[key] for r in results], False)} | {pm:.3g} ± {ps:.2g} |")
    for key in ("PA nUPE", "PA reach end, worst hand (mm)",
                "expert reach end, worst hand (mm)", "reached ball (%)",
                "constrained samples (%)", "unseen active (%)", "unaligned (%)",
                "sigma2", "time PolicyAlign (s)", "time naive (s)"):
        lines.append(f"| {key} | {_fmt([r[key] for r in results], False)} | — |")
    return "\n".join(lines) + "\n"


def plot_figure(rollouts: dict, path: Path) -> None:
    """Figure like the paper's Fig. 5: unconstrained reaches of expert, naive, PolicyAlign."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8))
    styles = {"expert": ("k", "expert"), "naive": ("g", "naive"),
              "PolicyAlign": ("r", "PolicyAlign")}
    for ax, (i, j, xl, yl) in zip(axes, [(0, 1, "x [m]", "y [m]"), (0, 2, "x [m]", "z [m]")],
                                  strict=True):
        for X in rollouts["demos"]:
            for h in range(2):
                ax.plot(X[:, 3 * h + i], X[:, 3 * h + j], color="0.8", lw=0.6, zorder=1)
        for key, (color, label) in styles.items():
            for r, X in enumerate(rollouts[key]):
                for h in range(2):
                    ax.plot(X[:, 3 * h + i], X[:, 3 * h + j], color=color, lw=1.6,
                            label=label if (r == 0 and h == 0) else None, zorder=3)
        target = grasp_target()
        ax.plot(target[[i, 3 + i]], target[[j, 3 + j]], "b+", ms=12, mew=2,
                label="target", zorder=4)
        ax.add_patch(plt.Circle((BALL[i], BALL[j]), BALL_DIAMETER / 2, color="orange",
                                alpha=0.5, zorder=2))
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_aspect("equal")
    half = rollouts["gap"] / 2
    axes[0].plot([BARRIER_X] * 2, [half, PANEL_REACH], "k-", lw=4, alpha=0.4,
                 label="barriers (demo 0)")
    axes[0].plot([BARRIER_X] * 2, [-PANEL_REACH, -half], "k-", lw=4, alpha=0.4)
    axes[0].set_ylim(-0.8, 0.8)
    axes[0].legend(loc="lower right", fontsize=8)
    axes[0].set_title("top view (grey: constrained demonstrations)")
    axes[1].set_title("side view")
    fig.suptitle("Unconstrained reaching: expert (black), naive (green), PolicyAlign (red)")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def run(datasets: int, jobs: int, seed: int, n_traj: int = 100, n_samples: int = 100
        ) -> list[dict]:
    """Evaluate ``datasets`` data sets on ``jobs`` processes (data set 0 carries figure
    data). Returns one metrics dict per data set."""
    jobs_list = [(seed + i, n_traj, n_samples, 3 if i == 0 else 0) for i in range(datasets)]
    return parallel_map(_worker, jobs_list, jobs)


def main(args) -> int:
    """``policy-align bench grasp``: see :func:`~.bench.run_robot_bench`."""
    return run_robot_bench(
        args, "grasp", run, format_table,
        lambda k, n: (f"State: both Talos hand positions (6-D); K={k}, N={n}, dt={DT} s, "
                      f"narrow sigma"),
        plot_figure, "rollouts")
