"""The node processes of one demo run and their parameters file.

Every node runs as a separate process in its own session on the run's private ROS domain,
with ``--params-file OUT/params.yaml`` and its log in ``OUT/logs/<node>.log``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from policy_align_ros.client.demo.settings import DemoSettings, StageError
from policy_align_ros.client.demo.task import Task
from policy_align_ros.kinematics.robot_config import load_robot_config
from policy_align_ros.learning.model_io import atomic_write_text

__all__ = ["HANDS_EXPERT_MAX_VELOCITY", "Graph", "write_params"]

#: Demonstrator speed limit of the hands demo, rad/s; the URDF's lower limits apply.
HANDS_EXPERT_MAX_VELOCITY = 10.0


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
        """Start node ``name``'s process in its own session, logging to its log file."""
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
        """The last ``lines`` lines of node ``name``'s log, indented."""
        path = self.out / "logs" / f"{name}.log"
        text = path.read_text(errors="replace") if path.exists() else ""
        return "\n".join("    " + line for line in text.splitlines()[-lines:])

    def stop(self) -> None:
        """SIGINT to every running node's process group, SIGKILL after 5 s."""
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


class _NoAliasDumper(yaml.SafeDumper):
    """rcl's YAML parser refuses aliases, which PyYAML emits for shared lists."""

    def ignore_aliases(self, data) -> bool:
        return True


def write_params(path: Path, s: DemoSettings, task: Task, demonstrator_seed: int) -> None:
    """Write the parameters of every node of the graph to ``path`` (a ROS params file)."""
    # The nodes read robot and joints from the robot config when the demo has one.
    common: dict = {"robot": s.robot, "joints": s.joints}
    if s.robot_config:
        common = {"robot_config": s.robot_config}
        if s.joints != load_robot_config(s.robot_config).joints:
            common["joints"] = s.joints
    common["use_sim_time"] = True
    rate = float(s.rate_hz)
    learner = {"dataset_dir": str(s.out / "demos"), "model_path": str(s.out / "model.npz"),
               "plot_path": str(s.out / "demo_fit.png"),
               "sigma": str(s.sigma), "joints": s.joints, "seed": int(s.seed),
               "holdout_fraction": float(s.holdout_fraction), "use_sim_time": True,
               "robot": s.robot, "state": task.state_spec}
    demonstrator = {**common, "rate_hz": rate, "attractor": task.attractor.tolist(),
                    "gain": float(s.gain), "start_variance": float(s.start_variance),
                    "num_demos": int(s.demos), "demo_duration_s": float(s.demo_duration_s),
                    "constraint_frames": s.frames or [""], "seed": demonstrator_seed,
                    "expert": s.state, "step_on_joint_state": True}
    if s.state == "hands":
        # The joints' own (URDF) limits: scaled recordings bias the learnt potential.
        demonstrator.update(hand_frames=s.frames, hand_targets=task.goal.tolist(),
                            max_velocity=HANDS_EXPERT_MAX_VELOCITY)
    params = {
        "sim_robot": {**common, "rate_hz": rate, "initial_positions": task.attractor.tolist(),
                      "command_timeout_s": 0.2, "publish_clock": True,
                      "real_time_factor": float(s.real_time_factor)},
        "recorder": {"dataset_dir": str(s.out / "demos"), "joints": s.joints,
                     "use_sim_time": True},
        "learner": learner,
        "executor": {**common, "rate_hz": rate, "max_velocity": float(s.max_velocity),
                     "max_acceleration": float(s.max_acceleration),
                     "state_timeout_s": 0.2, "max_clock_skew_s": 0.1, "constraints": "[]",
                     # sim_robot stands in for the controller: ~/enable checks its joints.
                     "controller": "/sim_robot",
                     # One step per joint state, as the demonstrator, so that the
                     # executor's command is always made from the latest state.
                     "step_on_joint_state": True,
                     **s.executor_params},
        "demonstrator": demonstrator,
    }
    text = yaml.dump({k: {"ros__parameters": v} for k, v in params.items()},
                     Dumper=_NoAliasDumper, sort_keys=False)
    atomic_write_text(path, text)

