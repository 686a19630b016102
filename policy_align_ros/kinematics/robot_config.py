"""Robot configs: one YAML file per robot that every node reads (ROS-free).

A robot config names the robot (example-robot-data name or URDF path), its controlled
joints in the controller's command order, the controller, the frames constraints act on
and the demo's constraints. Configs for ``talos``, ``panda`` and ``ur5`` ship in
``config/robots/`` (installed to ``share/policy_align_ros/config/robots``); the nodes'
``robot_config`` parameter takes one of those names or the path of a file of the same
form::

    robot: panda                      # example-robot-data name or URDF path
    joints: [panda_joint1, ...]       # controller command order
    controller: /velocity_controller  # optional (this default)
    home: [...]                       # optional, rad, one per joint
    frames: {tool: panda_hand_tcp, hands: [], constraint: [panda_hand_tcp]}
    unseen_constraint: [{type: position, frame: panda_hand_tcp}]

:func:`resolve_robot_setup` applies the nodes' precedence for ``robot`` and ``joints``:
an explicit parameter, then the model file, then the robot config, then an error naming
the fix. A model file whose robot or joints contradict a robot config given explicitly is
left out (:attr:`RobotSetup.model_refused` says why): the config's robot and joints apply.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from policy_align_ros.kinematics.robot import _resolve as _resolve_robot

__all__ = [
    "DEFAULT_ROBOT_CONFIG",
    "RobotConfig",
    "RobotSetup",
    "learning_robot",
    "load_robot_config",
    "resolve_robot_setup",
    "robot_config_dirs",
    "shipped_robot_configs",
]

#: The config used when no robot is named anywhere (the nodes' historical default).
DEFAULT_ROBOT_CONFIG = "talos"
_PACKAGE = "policy_align_ros"
_KEYS = {"robot", "joints", "controller", "home", "frames", "unseen_constraint"}
_FRAME_KEYS = {"tool", "hands", "constraint"}


@dataclass(frozen=True)
class RobotConfig:
    """One robot config file, checked.

    Attributes
    ----------
    name : str
        The file's stem (``panda`` for ``config/robots/panda.yaml``).
    path : Path
    robot : str
        example-robot-data name or URDF path (a relative path is made absolute against
        the config file's directory).
    joints : list of str
        Controlled joints, in the controller's command order.
    controller : str
        Node name of the ros2_control controller taking the commands, whose ``joints``
        parameter the executor checks its command order against (the commands go to
        ``/velocity_controller/commands``; remap it for another controller).
    home : list of float or None
        Home posture (rad, one per joint); None = the robot's reference posture.
    tool : str or None
        The frame constraints usually act on (the end effector).
    hands : list of str
        Frames of a hand-space state (the demo's ``--state hands``).
    constraint_frames : list of str
        Frames the demonstrator restricts to random planes.
    unseen_constraint : list of dict
        Constraint specs of the demo's run under a constraint never demonstrated.
    """

    name: str
    path: Path
    robot: str
    joints: list[str]
    controller: str = "/velocity_controller"
    home: list[float] | None = None
    tool: str | None = None
    hands: list[str] = field(default_factory=list)
    constraint_frames: list[str] = field(default_factory=list)
    unseen_constraint: list[dict] = field(default_factory=list)


@dataclass(frozen=True)
class RobotSetup:
    """A node's resolved robot: ``robot``, ``joints`` (command order), ``controller``,
    the config used (or None), and where ``robot`` and ``joints`` came from (``sources``:
    ``"parameter"``, ``"model file"`` or ``"robot config NAME"``). ``model_refused`` is
    why the model file was left out (its robot or joints contradict the ``robot_config``
    given; the node must not load it), empty otherwise."""

    robot: str
    joints: list[str]
    controller: str
    config: RobotConfig | None
    sources: dict[str, str]
    model_refused: str = ""

    @property
    def home(self) -> list[float] | None:
        """The config's home posture (rad) when the joints are the config's, else None."""
        if self.config is None or self.joints != self.config.joints:
            return None
        return self.config.home

    def hint(self) -> str:
        """Where ``robot`` and ``joints`` came from and how to set them (error messages)."""
        return (f"robot {self.robot!r} from the {self.sources['robot']}, joints from the "
                f"{self.sources['joints']}; "
                + _FIX.format(names=", ".join(shipped_robot_configs())))


_FIX = ("set -p robot:=NAME -p joints:=[...] or -p robot_config:=NAME (shipped: "
        "{names}) or the path of a robot config file")


def robot_config_dirs() -> list[Path]:
    """Directories searched for shipped configs, first match wins.

    The source tree's ``config/robots`` (a checkout or an editable install), then
    ``share/policy_align_ros/config/robots`` under the Python prefix and under every
    ``AMENT_PREFIX_PATH`` entry (a colcon install), then the one next to an installed
    package's ``lib/pythonX.Y/site-packages``.
    """
    here = Path(__file__).resolve()
    share = Path("share") / _PACKAGE / "config" / "robots"
    dirs = [here.parents[2] / "config" / "robots", Path(sys.prefix) / share]
    dirs += [Path(p) / share for p in os.environ.get("AMENT_PREFIX_PATH", "").split(
        os.pathsep) if p]
    if len(here.parents) > 5:
        dirs.append(here.parents[5] / share)
    out: list[Path] = []
    for d in dirs:
        if d not in out:
            out.append(d)
    return out


def shipped_robot_configs() -> list[str]:
    """Names of the shipped robot configs (sorted)."""
    names: set[str] = set()
    for d in robot_config_dirs():
        if d.is_dir():
            names.update(p.stem for p in d.glob("*.yaml"))
    return sorted(names)


def _find(name: str) -> Path | None:
    for d in robot_config_dirs():
        path = d / f"{name}.yaml"
        if path.is_file():
            return path
    return None


def load_robot_config(name_or_path: str | os.PathLike) -> RobotConfig:
    """Load a shipped robot config by name, or a robot config file by path.

    Raises
    ------
    ValueError
        For an unknown name (listing the shipped ones), an unreadable or malformed file
        (naming the field), or a missing file.
    """
    text = str(name_or_path).strip()
    if not text:
        raise ValueError("robot_config: empty name")
    is_path = text.endswith((".yaml", ".yml")) or os.sep in text
    path = Path(text).expanduser() if is_path else _find(text)
    if path is None:
        raise ValueError(f"robot_config: no shipped robot config {text!r}; shipped: "
                         f"{', '.join(shipped_robot_configs()) or 'none found'} (or give "
                         "the path of a .yaml file)")
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as err:
        raise ValueError(f"robot_config: cannot read {str(path)!r}: {err}") from None
    except yaml.YAMLError as err:
        raise ValueError(f"robot_config: {str(path)!r} is not YAML: {err}") from None
    try:
        return _parse(data, path)
    except ValueError as err:
        raise ValueError(f"robot_config {str(path)!r}: {err}") from None


def _names(value, key: str) -> list[str]:
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        raise ValueError(f"{key} must be a list of names")
    if len(set(value)) != len(value):
        raise ValueError(f"{key} lists a name twice")
    return list(value)


def _parse(data, path: Path) -> RobotConfig:
    if not isinstance(data, dict):
        raise ValueError("must be a mapping with robot and joints")
    unknown = set(data) - _KEYS
    if unknown:
        raise ValueError(f"unknown keys {sorted(unknown)} (known: {sorted(_KEYS)})")
    robot = data.get("robot")
    if not isinstance(robot, str) or not robot:
        raise ValueError("robot must be an example-robot-data name or a URDF path")
    if robot.lower().endswith(".urdf") and not Path(robot).expanduser().is_absolute():
        robot = str((path.parent / robot).resolve())
    joints = _names(data.get("joints"), "joints")
    if not joints:
        raise ValueError("joints must not be empty")
    controller = data.get("controller", "/velocity_controller")
    if not isinstance(controller, str):
        raise ValueError("controller must be a node name")
    home = data.get("home")
    if home is not None:
        if (not isinstance(home, list) or len(home) != len(joints) or not all(
                isinstance(v, (int, float)) and math.isfinite(v) for v in home)):
            raise ValueError(f"home must be {len(joints)} finite numbers (rad), one a joint")
        home = [float(v) for v in home]
    frames = data.get("frames") or {}
    if not isinstance(frames, dict) or set(frames) - _FRAME_KEYS:
        raise ValueError(f"frames must be a mapping with keys {sorted(_FRAME_KEYS)}")
    tool = frames.get("tool")
    if tool is not None and not isinstance(tool, str):
        raise ValueError("frames.tool must be a frame name")
    unseen = data.get("unseen_constraint") or []
    if not isinstance(unseen, list) or not all(isinstance(s, dict) for s in unseen):
        raise ValueError("unseen_constraint must be a list of constraint specs")
    return RobotConfig(
        name=path.stem, path=path, robot=robot, joints=joints, controller=controller,
        home=home, tool=tool, hands=_names(frames.get("hands") or [], "frames.hands"),
        constraint_frames=_names(frames.get("constraint") or [], "frames.constraint"),
        unseen_constraint=unseen)


def resolve_robot_setup(robot: str | None = None, joints: Sequence[str] | None = None,
                        robot_config: str | None = None,
                        model: tuple[str | None, Sequence[str] | None] | None = None
                        ) -> RobotSetup:
    """A node's robot and joints by precedence: explicit, model file, robot config.

    Parameters
    ----------
    robot, joints : optional
        The node's explicit ``robot`` and ``joints`` parameters (None or empty: unset).
    robot_config : str, optional
        The node's ``robot_config`` (a shipped name or a path). Unset: the shipped config
        named like the robot (explicit or the model's) when there is one, else
        :data:`DEFAULT_ROBOT_CONFIG` when no robot is named anywhere.
    model : (robot, joints), optional
        The robot and joints a model file was learnt for (either may be None: a file
        written before the robot field, or a model of unnamed positions). Ignored, with
        :attr:`RobotSetup.model_refused` set, when they contradict ``robot_config``'s
        robot or joints where the explicit ``robot`` and ``joints`` leave them to it.

    Returns
    -------
    RobotSetup

    Raises
    ------
    ValueError
        When the joints cannot be known (a robot without a config, no model joints):
        names the fix; or for a bad ``robot_config``.
    """
    model_robot, model_joints = model or (None, None)
    robot = robot or None
    joints = list(joints) if joints else None
    config = None
    refused = ""
    if robot_config:
        config = load_robot_config(robot_config)
        refused = _model_conflict(robot, joints, config, model_robot, model_joints)
        if refused:
            model_robot = model_joints = None  # the config's robot and joints, no model
    else:
        named = robot or model_robot
        if named is None:
            config = load_robot_config(DEFAULT_ROBOT_CONFIG)
        elif _find(str(named)) is not None:
            config = load_robot_config(str(named))
    sources = {}
    if robot:
        sources["robot"] = "parameter"
    elif model_robot:
        robot, sources["robot"] = model_robot, "model file"
    elif config is not None:
        robot, sources["robot"] = config.robot, f"robot config {config.name}"
    same = config is not None and config.robot == robot
    # A model learnt for another robot has joints of that robot: not ours.
    model_fits = model_joints and (model_robot is None or model_robot == robot)
    if joints:
        sources["joints"] = "parameter"
    elif model_fits:
        joints, sources["joints"] = list(model_joints), "model file"
        if same and set(joints) == set(config.joints):
            joints = list(config.joints)  # the controller's order
    elif same:
        joints, sources["joints"] = list(config.joints), f"robot config {config.name}"
    else:
        _resolve_robot(str(robot))  # an unknown robot name says so first, with the closest
        where = (f"robot config {config.name} is for robot {config.robot!r}"
                 if config is not None else "no robot config names it")
        raise ValueError(
            f"joints: unknown for robot {robot!r} (not set, no model file naming them, "
            f"{where}); " + _FIX.format(names=", ".join(shipped_robot_configs())))
    controller = config.controller if same else "/velocity_controller"
    return RobotSetup(robot=str(robot), joints=[str(j) for j in joints],
                      controller=controller, config=config if same else None,
                      sources=sources, model_refused=refused)


def _model_conflict(robot: str | None, joints: list[str] | None, config: RobotConfig,
                    model_robot: str | None, model_joints: Sequence[str] | None) -> str:
    """Why a model file's robot or joints contradict the robot config given, for the
    fields the explicit ``robot`` and ``joints`` leave to them; empty when they agree.

    The model would give the robot when ``robot`` is unset, and the joints when ``joints``
    is unset and the config is that robot's: a model naming another robot, or other
    joints than the config's, is a conflict (the run-time load would refuse it too).
    """
    robot_differs = not robot and bool(model_robot) and model_robot != config.robot
    used = robot or model_robot or config.robot
    joints_differ = (not joints and bool(model_joints) and used == config.robot
                     and (model_robot is None or model_robot == used)
                     and set(model_joints) != set(config.joints))
    if not (robot_differs or joints_differ):
        return ""
    learnt = f"robot {model_robot!r}" if model_robot else "no robot"
    return (f"the model file was learnt for {learnt} and joints {list(model_joints or [])}, "
            f"but robot_config {config.name} names robot {config.robot!r} and joints "
            f"{config.joints}; give a model learnt for robot_config's robot and joints, or "
            f"leave robot_config unset (the model then sets robot and joints), or set robot "
            f"and joints explicitly (-p robot:=NAME -p joints:=[...])")


def learning_robot(robot: str | None, joints: Sequence[str] | None,
                   robot_config: str | None) -> tuple[str | None, list[str] | None]:
    """The learner's robot and joints: explicit values, else the robot config's.

    The config's joints apply only when it is the config of the robot learnt for (an
    explicit ``robot`` of another robot keeps its joints unset: those of the data).

    Returns
    -------
    (robot, joints)
        Either may be None (unknown robot: the model file names none; unset joints: the
        joints of the first message).
    """
    joints = list(joints) if joints else None
    if not robot_config:
        return robot or None, joints
    config = load_robot_config(robot_config)
    robot = robot or config.robot
    if joints is None and robot == config.robot:
        joints = list(config.joints)
    return robot, joints
