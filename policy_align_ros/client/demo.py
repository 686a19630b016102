"""``policy-align demo``: the whole ROS 2 graph on a simulated robot, end to end.

Stages (each one failing makes the command exit non-zero):

1. start ``sim_robot``, ``recorder``, ``learner``, ``executor`` and ``demonstrator`` as
   separate processes (as a launch file would) on a private ROS domain, parameters in
   ``OUT/params.yaml``, logs in ``OUT/logs/``;
2. the demonstrator records ``demos`` demonstrations of the expert
   ``pi(q) = -gain (q - q_c)`` with both hands on planes of random orientation;
3. ``/learner/learn`` fits PolicyAlign on them and announces the model;
4. the executor drives the simulated robot from one start posture (a) unconstrained and
   (b) with the left hand held in place (3 rows, a constraint never seen in training);
5. a report (demonstrations, discarded, fit time, held-out nCPE, final distance to the
   attractor) is printed and written with the plots to ``OUT``; the exit status is also 1
   when the learnt policy did not bring the robot closer to the attractor in run (a).

Distances are joint-space norms ``||q - q_c||`` in rad. For reference the same runs are
integrated offline with the true expert policy (``expert``), and the learnt policy is
scored with the paper's nCPE on fresh demonstrations whose projectors ``N`` are known.
Every child process is stopped (SIGINT, then SIGKILL) whatever happens.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rclpy
import yaml
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from policy_align_ros.data import load_dataset
from policy_align_ros.experiments.demonstrators import (
    QuadraticPotential,
    from_constraint,
    rollout,
    sample_start_states,
)
from policy_align_ros.kinematics import Robot, constraint_from_spec
from policy_align_ros.kinematics.control import constrained_command
from policy_align_ros.learning import PolicyAlign
from policy_align_ros.learning.metrics import ncpe
from policy_align_ros.learning.model_io import atomic_write_text
from policy_align_ros.nodes._common import DEFAULT_JOINTS, LATCHED_QOS, joint_positions
from policy_align_ros.nodes.demonstrator import DEFAULT_FRAMES, random_plane_specs
from policy_align_ros.nodes.learner import holdout_split

__all__ = ["DemoSettings", "run_demo"]

NODES = ("sim_robot", "recorder", "learner", "executor", "demonstrator")
HOLDOUT_FRACTION = 0.2  # share of the demonstrations the learner scores instead of fitting


class StageError(RuntimeError):
    """A demo stage failed; the message says which and why."""


@dataclass
class DemoSettings:
    """Knobs of the demo (the CLI exposes ``robot`` and ``out``; tests shrink the rest)."""

    robot: str = "talos"
    out: Path = Path("demo_out")
    demos: int = 20
    demo_duration_s: float = 3.0
    run_duration_s: float = 6.0
    rate_hz: float = 50.0
    gain: float = 1.0
    start_variance: float = 0.1
    max_velocity: float = 1.0
    sigma: str = "medium"
    seed: int = 0
    domain_id: int | None = None
    joints: list[str] = field(default_factory=list)
    frames: list[str] = field(default_factory=list)
    plots: bool = True
    require_progress: bool = True


def _settings(args: argparse.Namespace) -> DemoSettings:
    s = DemoSettings()
    for name in s.__dataclass_fields__:
        if getattr(args, name, None) is not None:
            setattr(s, name, getattr(args, name))
    s.out = Path(s.out)
    if s.demos < 3:
        raise ValueError(f"demos: need at least 3 demonstrations, got {s.demos}")
    if not s.joints:
        s.joints = list(DEFAULT_JOINTS) if s.robot == "talos" else []
    if not s.frames:
        s.frames = list(DEFAULT_FRAMES) if s.robot == "talos" else []
    return s


def _domain_id(requested: int | None) -> int:
    if requested is not None:
        return int(requested)
    # A private domain per run so that two demos (or a demo and the tests) never mix.
    return 1 + os.getpid() % 100


# -- offline references ---------------------------------------------------------------
def expert_run(robot: Robot, q0: np.ndarray, potential: QuadraticPotential, constraints,
               s: DemoSettings) -> np.ndarray:
    """The true policy from ``q0`` under ``constraints`` as the executor would run it.

    Returns
    -------
    ndarray, shape (T, n)
        Joint positions every control period (rad).
    """
    dt = 1.0 / s.rate_hz
    vmax = np.full(robot.nq, s.max_velocity)
    q = q0.copy()
    out = [q.copy()]
    for _ in range(int(round(s.run_duration_s * s.rate_hz))):
        pi = potential.policy(q[None])[0]
        A = (np.vstack([c.matrix(q, pi) for c in constraints]) if constraints
             else np.zeros((0, q.size)))
        q = np.clip(q + dt * constrained_command(q, pi, A, robot.lower, robot.upper, vmax, dt),
                    robot.lower, robot.upper)
        out.append(q.copy())
    return np.array(out)


def fresh_ncpe(model, robot: Robot, potential: QuadraticPotential, s: DemoSettings,
               n_demos: int = 10) -> float:
    """The paper's nCPE of ``model`` on new demonstrations with known projectors."""
    rng = np.random.default_rng(s.seed + 1000)
    starts = sample_start_states(rng, potential.center, n_demos, s.start_variance,
                                 robot.lower, robot.upper)
    X, P, Ns = [], [], []
    for x0 in starts:
        specs = random_plane_specs(s.frames, rng)
        constraint = constraint_from_spec(specs, robot) if specs else None
        gen = (from_constraint(constraint) if constraint is not None
               else (lambda x, t, pi: np.zeros((0, x.size))))
        demo = rollout(x0, potential, gen, int(s.demo_duration_s * s.rate_hz), 1 / s.rate_hz)
        X.append(demo.trajectory.positions)
        P.append(demo.policy)
        Ns.append(demo.projectors)
    X = np.concatenate(X)
    return float(ncpe(np.concatenate(P), model.policy(X), np.concatenate(Ns)))


# -- processes ------------------------------------------------------------------------
class Graph:
    """The node processes of one demo run, always stopped on exit."""

    def __init__(self, out: Path, params: Path, domain_id: int) -> None:
        self.out = out
        self.params = params
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED="1",
                        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        self.procs: dict[str, subprocess.Popen] = {}
        (out / "logs").mkdir(parents=True, exist_ok=True)

    def start(self, name: str) -> None:
        code = f"import sys; from policy_align_ros.nodes.{name} import main; sys.exit(main())"
        # The child inherits a copy of the descriptor, so the file can be closed here.
        with open(self.out / "logs" / f"{name}.log", "wb") as log:
            self.procs[name] = subprocess.Popen(
                [sys.executable, "-c", code, "--ros-args", "--params-file", str(self.params)],
                env=self.env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)

    def check(self, allow_exit: tuple[str, ...] = ()) -> None:
        """Raise StageError if a node died (``allow_exit`` may have ended with status 0)."""
        for name, proc in self.procs.items():
            code = proc.poll()
            if code is None or (name in allow_exit and code == 0):
                continue
            raise StageError(f"node {name} exited with status {code}:\n{self.tail(name)}")

    def tail(self, name: str, lines: int = 15) -> str:
        path = self.out / "logs" / f"{name}.log"
        text = path.read_text(errors="replace") if path.exists() else ""
        return "\n".join("    " + line for line in text.splitlines()[-lines:])

    def stop(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        deadline = time.monotonic() + 5.0
        for proc in self.procs.values():
            try:
                proc.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


# -- the orchestrating node -----------------------------------------------------------
class Conductor:
    """A node in this process that watches the graph and calls its services."""

    def __init__(self, context: rclpy.Context, joints: list[str]) -> None:
        self.node = Node("policy_align_demo", context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.index = {name: i for i, name in enumerate(joints)}
        self.q: np.ndarray | None = None
        self.trace: list[np.ndarray] | None = None
        self.progress = ""
        self.node.create_subscription(JointState, "/joint_states", self._on_state, 10)
        self.node.create_subscription(String, "/demonstrator/progress", self._on_progress,
                                      LATCHED_QOS)

    def _on_state(self, msg: JointState) -> None:
        q = joint_positions(msg, self.index)
        if q is not None:
            self.q = q
            if self.trace is not None:
                self.trace.append(q)

    def _on_progress(self, msg: String) -> None:
        self.progress = msg.data

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.05, max(end - time.monotonic(), 0)))

    def call(self, srv_type, name: str, request, timeout: float):
        client = self.node.create_client(srv_type, name)
        try:
            end = time.monotonic() + timeout
            while not client.service_is_ready():
                if time.monotonic() > end:
                    raise StageError(f"service {name} not available after {timeout:g} s")
                self.spin(0.05)
            future = client.call_async(request)
            self.executor.spin_until_future_complete(
                future, timeout_sec=max(end - time.monotonic(), 0.1))
            if not future.done() or future.result() is None:
                raise StageError(f"service {name} did not answer within {timeout:g} s")
            return future.result()
        finally:
            self.node.destroy_client(client)

    def trigger(self, name: str, timeout: float = 10.0) -> str:
        response = self.call(Trigger, name, Trigger.Request(), timeout)
        if not response.success:
            raise StageError(f"{name} failed: {response.message}")
        return response.message

    def set_parameter(self, node: str, name: str, value) -> None:
        request = SetParameters.Request(parameters=[Parameter(name, value=value)
                                                    .to_parameter_msg()])
        result = self.call(SetParameters, f"{node}/set_parameters", request, 10.0).results[0]
        if not result.successful:
            raise StageError(f"{node}: parameter {name} refused: {result.reason}")

    def enable(self, on: bool) -> str:
        response = self.call(SetBool, "/executor/enable", SetBool.Request(data=on), 10.0)
        return response.message


def _say(t0: float, text: str) -> None:
    print(f"[demo {time.monotonic() - t0:6.1f} s] {text}", flush=True)


def _parse_summary(text: str) -> dict:
    pattern = (r"learnt from (\d+) of (\d+) training demonstrations \((\d+) discarded, "
               r"(\d+) held out\); sigma\^2=(\S+); fit (\S+) s; held-out nCPE (\S+)")
    match = re.search(pattern, text)
    if match is None:
        raise StageError(f"unexpected learner answer: {text}")
    used, train, discarded, held, sigma2, fit_s, ncpe = match.groups()
    return {"train": int(train), "used": int(used), "discarded": int(discarded),
            "held_out": int(held), "sigma2": float(sigma2), "fit_s": float(fit_s),
            "ncpe_observed": float(ncpe) if ncpe != "n/a" else float("nan")}


class _NoAliasDumper(yaml.SafeDumper):
    """rcl's YAML parser refuses aliases, which PyYAML emits for shared lists."""

    def ignore_aliases(self, data) -> bool:
        return True


def _write_params(path: Path, s: DemoSettings, q_start: np.ndarray, attractor: np.ndarray
                  ) -> None:
    common = {"robot": s.robot, "joints": s.joints}
    rate = float(s.rate_hz)
    params = {
        "sim_robot": {**common, "rate_hz": rate, "initial_positions": q_start.tolist(),
                      "command_timeout_s": 0.2},
        "recorder": {"dataset_dir": str(s.out / "demos"), "joints": s.joints},
        "learner": {"dataset_dir": str(s.out / "demos"),
                    "model_path": str(s.out / "model.npz"), "sigma": str(s.sigma),
                    "joints": s.joints, "seed": s.seed,
                    "holdout_fraction": HOLDOUT_FRACTION},
        "executor": {**common, "rate_hz": rate, "max_velocity": float(s.max_velocity),
                     "state_timeout_s": 0.2, "constraints": "[]"},
        "demonstrator": {**common, "rate_hz": rate, "attractor": attractor.tolist(),
                         "gain": float(s.gain), "start_variance": float(s.start_variance),
                         "num_demos": int(s.demos),
                         "demo_duration_s": float(s.demo_duration_s),
                         "constraint_frames": s.frames or [""], "seed": int(s.seed)},
    }
    text = yaml.dump({k: {"ros__parameters": v} for k, v in params.items()},
                     Dumper=_NoAliasDumper, sort_keys=False)
    atomic_write_text(path, text)


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    tmp = path.with_name(path.name + ".tmp")
    fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    os.replace(tmp, path)
    return path


def _plot(out: Path, runs: dict, dt: float, robot: Robot, frames: list[str]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fig, ax = plt.subplots(figsize=(7, 4))
    for (label, run), color in zip(runs.items(), ("tab:blue", "tab:red"), strict=False):
        for kind, style in (("learnt", "-"), ("expert", "--")):
            dist = run[f"{kind}_dist"]
            ax.plot(np.arange(dist.size) * dt, dist, style, color=color,
                    label=f"{label}: {kind}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("||q - q_c|| [rad]")
    ax.set_title("Distance to the attractor: learnt policy (executor) vs expert")
    ax.legend()
    fig.tight_layout()
    paths.append(_save(fig, out / "demo_distance.png"))

    if frames:
        fig, axes = plt.subplots(1, len(runs), figsize=(5 * len(runs), 4.5), squeeze=False)
        for ax, (label, run) in zip(axes[0], runs.items(), strict=True):
            for kind, style in (("learnt", "-"), ("expert", "--")):
                for frame, color in zip(frames, ("tab:green", "tab:purple"), strict=False):
                    path = np.array([robot.frame_position(q, frame) for q in run[kind]])
                    ax.plot(path[:, 0], path[:, 2], style, color=color,
                            label=f"{frame} ({kind})")
                    ax.plot(path[-1, 0], path[-1, 2], "o", color=color)
            ax.set_title(label)
            ax.set_xlabel("x [m]")
            ax.set_ylabel("z [m]")
            ax.axis("equal")
        axes[0][0].legend(fontsize=7)
        fig.tight_layout()
        paths.append(_save(fig, out / "demo_hands.png"))
    return paths


def run_demo(args: argparse.Namespace) -> int:
    """Entry of ``policy-align demo``; returns 0 when every stage succeeded."""
    s = _settings(args)
    t0 = time.monotonic()
    out = s.out.resolve()
    s.out = out
    out.mkdir(parents=True, exist_ok=True)
    if (out / "demos").exists():
        shutil.rmtree(out / "demos")  # this run's demonstrations only
    robot = Robot.load(s.robot, s.joints or None)
    s.joints = list(robot.joint_names)
    attractor = robot.neutral()
    potential = QuadraticPotential(attractor, weight=s.gain / 2.0)
    q_start = sample_start_states(np.random.default_rng(s.seed + 2000), attractor, 1,
                                  s.start_variance, robot.lower, robot.upper)[0]
    params = out / "params.yaml"
    _write_params(params, s, q_start, attractor)
    domain = _domain_id(s.domain_id)
    graph = Graph(out, params, domain)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        _say(t0, f"robot {s.robot}: {len(s.joints)} joints, ROS domain {domain}, "
                 f"output {out}")
        for name in NODES:
            graph.start(name)
        conductor = Conductor(context, s.joints)
        report = _stages(s, t0, graph, conductor, robot, potential, q_start)
        if s.plots:
            for path in _plot(out, report.pop("runs"), 1.0 / s.rate_hz, robot, s.frames):
                _say(t0, f"plot written: {path}")
        else:
            report.pop("runs")
        failure = report.pop("failure")
        text = _report_text(report, time.monotonic() - t0)
        if failure:
            text += f"\nFAILED: {failure}"
        print(text, flush=True)
        atomic_write_text(out / "report.txt", text + "\n")
        if failure:
            raise StageError(failure)
        return 0
    except StageError as err:
        print(f"[demo] FAILED: {err}", file=sys.stderr, flush=True)
        return 1
    finally:
        signal.signal(signal.SIGTERM, previous)
        graph.stop()
        rclpy.try_shutdown(context=context)


def _stages(s: DemoSettings, t0: float, graph: Graph, conductor: Conductor, robot: Robot,
            potential: QuadraticPotential, q_start: np.ndarray) -> dict:
    # Stage 1: the graph is up when the robot publishes and the services answer.
    deadline = time.monotonic() + 60.0
    while conductor.q is None:
        graph.check()
        if time.monotonic() > deadline:
            raise StageError("no /joint_states from sim_robot after 60 s")
        conductor.spin(0.1)
    _say(t0, "graph up: sim_robot, recorder, learner, executor, demonstrator")

    # Stage 2: demonstrations.
    per_demo = s.demo_duration_s + 6.0
    deadline = time.monotonic() + 30.0 + s.demos * per_demo
    shown = ""
    while graph.procs["demonstrator"].poll() is None:
        graph.check(allow_exit=("demonstrator",))
        if conductor.progress != shown:
            shown = conductor.progress
            _say(t0, f"demonstrations recorded: {shown}")
        if time.monotonic() > deadline:
            raise StageError(f"demonstrations not finished after {deadline:.0f} s "
                             f"(progress {shown or '0'}):\n{graph.tail('demonstrator')}")
        conductor.spin(0.1)
    graph.check(allow_exit=("demonstrator",))
    _say(t0, f"demonstrator finished: {s.demos} demonstrations recorded")

    # Stage 3: learning.
    _say(t0, "calling /learner/learn ...")
    answer = conductor.trigger("/learner/learn", timeout=150.0)
    learnt = _parse_summary(answer)
    _say(t0, f"learner: {answer}")
    if learnt["train"] + learnt["held_out"] != s.demos:
        raise StageError(f"the learner found {learnt['train'] + learnt['held_out']} "
                         f"demonstrations on disk, {s.demos} were recorded")
    model_path = s.out / "model.npz"
    deadline = time.monotonic() + 10.0
    while str(model_path) not in conductor.enable(False):
        if time.monotonic() > deadline:
            raise StageError(f"executor did not load the model:\n{graph.tail('executor')}")
        conductor.spin(0.2)

    model = PolicyAlign.load(model_path)
    learnt["ncpe_fresh"] = fresh_ncpe(model, robot, potential, s)

    # Stage 4: execution from a training demonstration's start, (a) unconstrained and
    # (b) left hand held in place: neither was ever demonstrated (the teacher always had
    # both hands on planes). A new random start in a 20-D joint space is far from every one
    # of a few dozen demonstrations, where the local potential model knows nothing.
    demos, _, _ = load_dataset([s.out / "demos"], joints=s.joints)
    # The first training demonstration that is complete: while the processes start up, the
    # first one can come out short (the simulator's first ticks are late).
    train = holdout_split(len(demos), HOLDOUT_FRACTION, s.seed)[0]
    full = 0.9 * np.median([d.n_samples for d in demos])
    first = next((k for k in train if demos[k].n_samples >= full), train[0])
    q_start = demos[first].positions[0]
    conductor.set_parameter("/sim_robot", "initial_positions", q_start.tolist())
    _say(t0, f"executor runs start where demonstration {first + 1} started, "
             f"{np.linalg.norm(q_start - potential.center):.3f} rad from the attractor")
    unseen = ([{"type": "position", "frame": s.frames[0]}] if s.frames
              else [{"type": "joints", "joints": s.joints[:1]}])
    runs = {}
    for label, specs in (("(a) unconstrained", []), ("(b) unseen constraint", unseen)):
        conductor.trigger("/sim_robot/reset")
        conductor.set_parameter("/executor", "constraints", yaml.safe_dump(
            specs, default_flow_style=True).strip())
        conductor.spin(0.3)
        conductor.trace = []
        conductor.enable(True)
        _say(t0, f"executor run {label} for {s.run_duration_s:g} s"
                 + (f": {specs}" if specs else ""))
        conductor.spin(s.run_duration_s)
        conductor.enable(False)
        trace = np.array(conductor.trace)
        conductor.trace = None
        graph.check(allow_exit=("demonstrator",))
        if trace.shape[0] < 2:
            raise StageError(f"no joint states during run {label}")
        constraints = [constraint_from_spec(spec, robot) for spec in specs]
        expert = expert_run(robot, q_start, potential, constraints, s)
        run = {"learnt": trace, "expert": expert,
               "learnt_dist": np.linalg.norm(trace - potential.center, axis=1),
               "expert_dist": np.linalg.norm(expert - potential.center, axis=1)}
        if specs and s.frames:
            held = np.array([robot.frame_position(q, s.frames[0]) for q in trace])
            run["violation"] = float(np.max(np.linalg.norm(held - held[0], axis=1)))
        runs[label] = run
        _say(t0, f"run {label}: distance to attractor {run['learnt_dist'][0]:.3f} -> "
                 f"{run['learnt_dist'][-1]:.3f} rad (expert {run['expert_dist'][-1]:.3f})")
    a = runs["(a) unconstrained"]
    failure = ""
    if s.require_progress and not a["learnt_dist"][-1] < a["learnt_dist"][0]:
        failure = "the learnt policy did not move the robot towards the attractor in run (a)"
    return {"settings": s, "learnt": learnt, "runs": runs, "failure": failure,
            "summary": {k: (float(v["learnt_dist"][0]), float(v["learnt_dist"][-1]),
                            float(v["expert_dist"][-1]), v.get("violation"))
                        for k, v in runs.items()}}


def _report_text(report: dict, elapsed: float) -> str:
    s, learnt = report["settings"], report["learnt"]
    lines = [
        "",
        "policy-align demo report",
        "========================",
        f"robot {s.robot}, {len(s.joints)} joints; expert pi = -{s.gain:g} (q - q_c) rad/s, "
        f"hands on random planes ({', '.join(s.frames) or 'none'})",
        f"demonstrations: {s.demos} recorded, {learnt['train']} for training "
        f"({learnt['discarded']} discarded as outliers), {learnt['held_out']} held out",
        f"sigma^2: {learnt['sigma2']:.4g}; fit time: {learnt['fit_s']:.2f} s",
        f"held-out nCPE (recorded demos, along observed motion): {learnt['ncpe_observed']:.4f}",
        f"held-out nCPE (10 fresh demos, true N, paper's measure): {learnt['ncpe_fresh']:.4f}",
        "final distance to the attractor ||q - q_c|| [rad] after "
        f"{s.run_duration_s:g} s (start -> learnt; expert):",
    ]
    for label, (start, final, expert, violation) in report["summary"].items():
        extra = "" if violation is None else f"; held hand moved {violation * 1000:.1f} mm"
        lines.append(f"  {label:24s} {start:.3f} -> {final:.3f}; expert {expert:.3f}{extra}")
    lines.append(f"total time: {elapsed:.1f} s")
    return "\n".join(lines)
