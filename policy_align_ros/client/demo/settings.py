"""The demo's settings, its random streams and its progress lines.

Durations are seconds of simulated time unless called wall time.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from policy_align_ros.kinematics.robot_config import RobotConfig, load_robot_config
from policy_align_ros.ros_env import DOMAIN_RANGE, fastdds_profiled

__all__ = [
    "DEFAULT_DEMOS",
    "MIN_START_SEPARATION",
    "NODES",
    "STATES",
    "DemoSettings",
    "StageError",
    "pick_domain_id",
    "random_streams",
    "say",
    "settings_from_args",
]

#: The node processes of the graph, in start order.
NODES = ("sim_robot", "recorder", "learner", "executor", "demonstrator")
STATES = ("joints", "hands")
#: Demonstrations recorded by default (a fifth is held out): fewer put the learnt minimum
#: measurably away from the attractor (hand space needs fewer: three coordinates a hand).
DEFAULT_DEMOS = {"joints": 30, "hands": 24}
#: A new start must be at least this far (state-space norm, rad) from every recorded start.
MIN_START_SEPARATION = 0.1


class StageError(RuntimeError):
    """A demo stage failed; the message says which and why."""


@dataclass
class DemoSettings:
    """Knobs of the demo (the CLI exposes robot, state, seed and out; tests shrink the rest).

    ``robot`` names a robot config (``config/robots/NAME.yaml`` or a .yaml path), which
    gives ``joints``, ``frames``, ``unseen_constraint`` and ``home`` when they are unset,
    or an example-robot-data name or URDF without one (all joints, no frames).

    Durations are simulated seconds; ``real_time_factor`` is simulated seconds per wall
    second (chosen so the graph keeps its control periods on 2 cores, see the report's
    ``sim`` block).
    """

    robot: str = "talos"
    #: The robot config named by ``robot`` (a shipped name or a .yaml path), if any.
    robot_config: str = ""
    out: Path = Path("demo_out")
    state: str = "joints"
    seed: int = 0
    demos: int | None = None
    demo_duration_s: float = 3.0
    run_duration_s: float = 8.0
    rate_hz: float = 25.0
    real_time_factor: float = 1.5
    gain: float = 1.0
    start_variance: float = 0.1
    max_velocity: float = 1.0
    max_acceleration: float = 2.0
    sigma: str = "medium"
    holdout_fraction: float = 0.2
    free_runs: int = 2
    held_runs: int = 1
    fresh_demos: int = 10
    hand_offset: tuple[float, ...] = (0.10, 0.05, 0.10, 0.10, -0.05, 0.10)
    domain_id: int | None = None
    executor_params: dict = field(default_factory=dict)
    joints: list[str] = field(default_factory=list)
    frames: list[str] = field(default_factory=list)
    #: Constraint specs of the run under a constraint never demonstrated (empty: hold the
    #: first frame in place, or lock the first joint when there is no frame).
    unseen_constraint: list[dict] = field(default_factory=list)
    #: The demonstrations' attractor (rad); empty = the robot's reference posture moved
    #: inside its limits (:func:`~policy_align_ros.sim.script.reachable_home`).
    home: list[float] = field(default_factory=list)
    plots: bool = True
    require_progress: bool = True


def settings_from_args(args: argparse.Namespace) -> DemoSettings:
    """The settings named in ``args`` (the others at their defaults), checked.

    Raises
    ------
    ValueError
        On an unknown state, fewer than 3 demonstrations, a seed outside [0, 2^31), no
        unconstrained run, or a hands state without two hand frames.
    """
    s = DemoSettings()
    for name in s.__dataclass_fields__:
        if getattr(args, name, None) is not None:
            setattr(s, name, getattr(args, name))
    s.out = Path(s.out)
    if s.state not in STATES:
        raise ValueError(f"state: must be one of {', '.join(STATES)}, got {s.state!r}")
    if s.demos is None:
        s.demos = DEFAULT_DEMOS[s.state]
    if s.demos < 3:
        raise ValueError(f"demos: need at least 3 demonstrations, got {s.demos}")
    if not 0 <= int(s.seed) < 2**31:
        raise ValueError(f"seed: must be in [0, 2^31), got {s.seed}")
    if s.free_runs < 1:
        raise ValueError(f"free_runs: need at least one unconstrained run, got {s.free_runs}")
    config = _robot_config(s.robot)
    if config is not None:
        _apply_config(s, config)
    if s.state == "hands" and len(s.frames) != 2:
        raise ValueError("state hands: needs two hand frames (the robot config's frames.hands;"
                         " known for robot talos only)")
    return s


def _robot_config(robot: str) -> RobotConfig | None:
    """The robot config ``robot`` names (a shipped name or a .yaml path), else None (an
    example-robot-data name or URDF without a config: all its joints, no frames)."""
    if str(robot).endswith((".yaml", ".yml")):
        return load_robot_config(robot)
    try:
        return load_robot_config(robot)
    except ValueError:
        return None


def _apply_config(s: DemoSettings, config: RobotConfig) -> None:
    """Fill the settings the robot config gives and that were not set."""
    s.robot_config, s.robot = str(config.path), config.robot
    s.joints = s.joints or list(config.joints)
    s.frames = s.frames or list(config.hands if s.state == "hands"
                                else config.constraint_frames)
    s.unseen_constraint = s.unseen_constraint or list(config.unseen_constraint)
    if s.joints == config.joints:  # the home posture is one value per config joint
        s.home = s.home or list(config.home or [])




def pick_domain_id(requested: int | None, environ: Mapping[str, str] | None = None) -> int:
    """The demo's ROS domain id.

    Parameters
    ----------
    requested : int or None
        An explicit id (the settings' ``domain_id``); it wins.
    environ : mapping of str to str, optional
        The environment (default ``os.environ``). A non-empty ``ROS_DOMAIN_ID`` in it is
        the user's choice of domain and is honoured.

    Returns
    -------
    int
        ``requested``, else ``ROS_DOMAIN_ID``, else a private domain per process
        (``1 + pid % 100``) so two demos started without either never mix.

    Raises
    ------
    ValueError
        When the chosen id is no integer in Fast DDS's range 0-232.
    """
    environ = os.environ if environ is None else environ
    if requested is not None:
        name, value = "domain_id", str(requested)
    elif environ.get("ROS_DOMAIN_ID", "").strip():
        name, value = "ROS_DOMAIN_ID", environ["ROS_DOMAIN_ID"].strip()
    else:
        return 1 + os.getpid() % 100
    low, high = DOMAIN_RANGE
    try:
        domain = int(value)
    except ValueError:
        domain = None
    # A Fast DDS profile may set ports that allow other ids: then the nodes will say.
    profiled = name == "ROS_DOMAIN_ID" and fastdds_profiled(environ)
    if domain is None or not (profiled and domain >= 0 or low <= domain <= high):
        raise ValueError(f"{name}: must be an integer ROS domain id in {low}-{high}, "
                         f"got {value!r}")
    return domain


def random_streams(seed: int) -> dict[str, np.random.Generator | int]:
    """Independent random streams, all from ``seed``.

    ``demonstrator`` is the node's integer seed (its starts and planes); ``fresh`` draws the
    offline scoring demonstrations and ``starts`` the executor's new start states.
    """
    demo_ss, fresh_ss, start_ss = np.random.SeedSequence(int(seed)).spawn(3)
    return {"demonstrator": int(demo_ss.generate_state(1)[0] & 0x7FFFFFFF),
            "fresh": np.random.default_rng(fresh_ss),
            "starts": np.random.default_rng(start_ss)}


def say(t0: float, text: str) -> None:
    """Print a progress line stamped with the wall time since ``t0`` (monotonic s)."""
    print(f"[demo {time.monotonic() - t0:6.1f} s] {text}", flush=True)
