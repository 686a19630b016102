"""``learner``: learn a PolicyAlign model from the demonstrations in ``dataset_dir``.

``~/learn`` (std_srvs/Trigger) reads every rosbag2 bag of ``dataset_dir`` (joint states
matched by name, split at gaps of ``gap_s`` s, malformed messages skipped), holds out a
fraction of the demonstrations, fits PolicyAlign on the others, writes the model
atomically to ``model_path``, publishes that path on ``~/model`` (std_msgs/String,
transient local) and answers with a one-line summary. The fit runs in its own callback
group on a multi-threaded executor, so the node keeps serving its other callbacks; a
second ``~/learn`` while one runs is refused. Bad or missing data gives
``success=false`` with the reason, never a crash.

Held-out error: the constraints of recorded demonstrations are unknown, so the nCPE of
the paper (which needs ``N``) is computed with ``N_i`` replaced by the projector onto the
observed velocity ``u_i = N_i pi_i``. Because ``N_i`` is an orthogonal projection,
``u_i^T pi_i = ||u_i||^2``, so this projection of the true policy is exactly ``u_i`` and the
measure needs the data only; it scores the policy along the observed motion (the part of
``N_i`` that the data reveal).
"""

from __future__ import annotations

import threading
import time
import traceback
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import Trigger

from policy_align_ros.data import load_dataset
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.nodes._common import (
    LATCHED_QOS,
    accept,
    descriptor,
    optional_parameter,
    reject,
    run_node,
)

__all__ = [
    "Learner",
    "LearnResult",
    "holdout_split",
    "learn_dataset",
    "main",
    "observed_ncpe",
    "parse_sigma",
]

SIGMA_RULES = ("narrow", "medium", "wide")


def parse_sigma(text: str) -> str | float:
    """``"narrow" | "medium" | "wide"`` or a positive sigma^2 given as text.

    Raises
    ------
    ValueError
        For anything else.
    """
    value = str(text).strip().lower()
    if value in SIGMA_RULES:
        return value
    try:
        sigma2 = float(value)
    except ValueError:
        raise ValueError(
            f"sigma: must be narrow, medium, wide or a positive number, got {text!r}"
        ) from None
    if not (np.isfinite(sigma2) and sigma2 > 0.0):
        raise ValueError(f"sigma: sigma^2 must be positive and finite, got {text!r}")
    return sigma2


def observed_ncpe(policy, trajectories: Sequence) -> float:
    """nCPE with each ``N_i`` replaced by the projector onto the observed velocity.

    Parameters
    ----------
    policy : callable
        ``policy(X)`` (m, n) -> (m, n) in state units per second.
    trajectories : sequence of Trajectory
        Held-out demonstrations with times (s).

    Returns
    -------
    float
        ``mean_i ||u_i - P_i pi_hat_i||^2 / sum_d var(u[:, d])`` over samples with
        non-zero velocity, where ``u_i`` is the forward-difference velocity and
        ``P_i = u_i u_i^T / ||u_i||^2``; NaN when no sample moves.
    """
    us, xs = [], []
    for traj in trajectories:
        dt = traj.dt[:, None]
        us.append(np.diff(traj.positions, axis=0) / dt)
        xs.append(traj.positions[:-1])
    u = np.concatenate(us)
    x = np.concatenate(xs)
    norm2 = np.einsum("ij,ij->i", u, u)
    moving = norm2 > 1e-12 * max(float(norm2.max(initial=0.0)), 1e-300)
    if not np.any(moving):
        return float("nan")
    u, x, norm2 = u[moving], x[moving], norm2[moving]
    pi_hat = policy(x)
    along = np.einsum("ij,ij->i", u, pi_hat) / norm2
    err = u - along[:, None] * u
    scale = float(np.sum(np.var(u, axis=0)))
    return float(np.mean(np.einsum("ij,ij->i", err, err)) / scale) if scale > 0 else float("nan")


def holdout_split(n_demos: int, fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """Indices of the training and held-out demonstrations (both sorted).

    At least one demonstration is held out when there are 3 or more and ``fraction > 0``,
    and at least two are always kept for training.
    """
    n_out = int(round(fraction * n_demos)) if n_demos >= 3 else 0
    if fraction > 0 and n_demos >= 3:
        n_out = min(max(n_out, 1), n_demos - 2)
    order = np.random.default_rng(seed).permutation(n_demos)
    return sorted(order[n_out:].tolist()), sorted(order[:n_out].tolist())


@dataclass
class LearnResult:
    """Outcome of one learning run (``summary`` is the service answer)."""

    model_path: Path
    n_demos: int
    n_train: int
    n_discarded: int
    n_heldout: int
    sigma2: float
    fit_s: float
    heldout_ncpe: float
    data_summary: str

    @property
    def summary(self) -> str:
        """One line for humans and for the ``~/learn`` answer."""
        ncpe = "n/a" if not np.isfinite(self.heldout_ncpe) else f"{self.heldout_ncpe:.4f}"
        return (
            f"learnt from {self.n_train - self.n_discarded} of {self.n_train} training "
            f"demonstrations ({self.n_discarded} discarded, {self.n_heldout} held out); "
            f"sigma^2={self.sigma2:.4g}; fit {self.fit_s:.2f} s; held-out nCPE {ncpe} "
            f"(along observed motion); model {self.model_path}"
        )


def learn_dataset(
    dataset_dir: str | Path,
    model_path: str | Path,
    *,
    sigma: str | float = "medium",
    joints: Sequence[str] | None = None,
    holdout_fraction: float = 0.2,
    gap_s: float = 0.5,
    seed: int = 0,
) -> LearnResult:
    """Load demonstrations, fit PolicyAlign on a random part, score the rest, save.

    Parameters
    ----------
    dataset_dir : path
        Directory of rosbag2 bags (or one bag).
    model_path : path
        Model file to write (atomically); parent directories are created.
    sigma : str or float
        PolicyAlign's ``sigma``.
    joints : sequence of str, optional
        State joints and their order (default: those of the first message).
    holdout_fraction : float
        Fraction of demonstrations held out for the nCPE (at least one when there are 3+).
    gap_s : float
        Split recordings at time gaps longer than this (s).
    seed : int
        Seeds the hold-out choice and the fit.

    Raises
    ------
    ValueError
        When there is no usable data (the message says why) or the fit fails.
    """
    dataset = Path(dataset_dir).expanduser()
    if not dataset.exists():
        raise ValueError(f"dataset_dir: {dataset} does not exist (record demonstrations first)")
    trajs, names, report = load_dataset([dataset], joints=joints, gap_s=gap_s)
    trajs = [t for t in trajs if t.times is not None]
    n_demos = len(trajs)
    if n_demos < 2:
        raise ValueError(
            f"need at least 2 demonstrations, found {n_demos} in {dataset} "
            f"({report.summary()})")
    train_idx, test_idx = holdout_split(n_demos, holdout_fraction, seed)
    test = [trajs[k] for k in test_idx]
    train = [trajs[k] for k in train_idx]
    start = time.perf_counter()
    model = PolicyAlign(sigma=sigma, random_state=seed).fit(train, joint_names=names)
    fit_s = time.perf_counter() - start
    path = Path(model_path).expanduser().resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    ncpe = observed_ncpe(model.policy, test) if test else float("nan")
    return LearnResult(
        model_path=path, n_demos=n_demos, n_train=len(train),
        n_discarded=len(train) - len(model.inliers_), n_heldout=len(test),
        sigma2=float(model.sigma2_), fit_s=fit_s, heldout_ncpe=ncpe,
        data_summary=report.summary(),
    )


class Learner(Node):
    """The ``learner`` node (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__("learner", **kwargs)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.declare_parameter("dataset_dir", "demos", descriptor(
            "directory of rosbag2 demonstrations (one bag per demonstration)"))
        self.declare_parameter("model_path", "model.npz", descriptor(
            "where the learnt model is written (atomically)"))
        self.declare_parameter("sigma", "medium", descriptor(
            "kernel width: narrow, medium, wide (paper eqs. 17-19) or sigma^2 as a number"))
        self.declare_parameter("joints", Parameter.Type.STRING_ARRAY, descriptor(
            "state joints and their order; unset = the joints of the first message"))
        self.declare_parameter("holdout_fraction", 0.2, descriptor(
            "fraction of demonstrations held out to report the nCPE",
            float_range=(0.0, 0.5)))
        self.declare_parameter("gap_s", 0.5, descriptor(
            "split recordings into demonstrations at time gaps longer than this [s]",
            float_range=(0.0, 3600.0)))
        self.declare_parameter("seed", 0, descriptor(
            "random seed of the hold-out split and the fit", int_range=(0, 2**31 - 1)))
        self._busy = threading.Lock()
        self.last_result: LearnResult | None = None
        self._pub = self.create_publisher(String, "~/model", LATCHED_QOS)
        self.create_service(Trigger, "~/learn", self._on_learn,
                            callback_group=ReentrantCallbackGroup())

    def _on_set_parameters(self, params: Sequence[Parameter]):
        for param in params:
            if param.name == "sigma":
                try:
                    parse_sigma(param.value)
                except ValueError as err:
                    return reject(str(err))
            elif param.name in ("dataset_dir", "model_path") and not str(param.value).strip():
                return reject(f"{param.name}: must not be empty")
            elif param.name == "joints" and param.value is not None and (
                    len(set(param.value)) != len(param.value) or not param.value):
                return reject("joints: must be a non-empty list without repeats")
        return accept()

    def _on_learn(self, request: Trigger.Request, response: Trigger.Response):
        if not self._busy.acquire(blocking=False):
            response.success = False
            response.message = "a learning run is already in progress"
            return response
        try:
            self.get_logger().info("learning started")
            result = learn_dataset(
                self.get_parameter("dataset_dir").value,
                self.get_parameter("model_path").value,
                sigma=parse_sigma(self.get_parameter("sigma").value),
                joints=optional_parameter(self, "joints"),
                holdout_fraction=self.get_parameter("holdout_fraction").value,
                gap_s=self.get_parameter("gap_s").value,
                seed=self.get_parameter("seed").value,
            )
        except (ValueError, OSError) as err:
            response.success = False
            response.message = f"learning failed: {err}"
        except Exception as err:  # noqa: BLE001 - a service must answer, never crash
            self.get_logger().error(traceback.format_exc())
            response.success = False
            response.message = f"learning failed ({type(err).__name__}): {err}"
        else:
            self.last_result = result
            self._pub.publish(String(data=str(result.model_path)))
            response.success = True
            response.message = result.summary
        finally:
            self._busy.release()
        log = self.get_logger().info if response.success else self.get_logger().error
        log(response.message)
        return response


def main(args: Sequence[str] | None = None) -> int:
    """Console script ``learner``."""
    return run_node(Learner, args, executor_factory=lambda: MultiThreadedExecutor(2))


if __name__ == "__main__":
    raise SystemExit(main())
