"""Shared fixtures of the ROS 2 tests.

Every ROS test owns an ``rclpy.Context`` on its own DDS domain, so tests (and a demo running
beside them) never see each other's topics. Domain ids are given per module (see each
module's docstring; all within Fast DDS's valid range 0-232); ``ros_context`` refuses an id
that another test module already used in this session: two modules sharing an id is the
mistake that makes a test see another's nodes when test runs overlap.

* ``ros_context(domain_id)`` -> an initialised context, shut down after the test.
* ``spun(context, *nodes)`` -> the nodes spinning in a background executor, stopped after
  the test (a context manager, for rigs that build their own nodes).
* ``node_process(name, domain_id, *params)`` -> a node's console script run to its end with
  ``-p`` parameters (for start-up refusals: exit status and stderr).
* ``wait_for(predicate, timeout)`` -> poll until true; the timeout only bounds a failure, it
  never decides a pass, so no assertion depends on the machine's speed.
* ``jaco_wrist`` -> Kinova's Jaco with its continuous wrist roll across the wrap from its
  rest posture (for the rest terms that must turn it the short way).

Hypothesis runs derandomized: its examples follow from each test, so every run of the suite
draws the same ones, as every other random draw of the tests is seeded.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

import pytest
from hypothesis import settings

from policy_align_ros.polling import wait_for

settings.register_profile("seeded", derandomize=True)
settings.load_profile("seeded")

_USED_DOMAINS: dict[int, str] = {}


@pytest.fixture
def ros_context(request):
    """Factory: ``ros_context(domain_id)`` returns a fresh, initialised ``rclpy.Context``."""
    import rclpy

    made = []

    def make(domain_id: int):
        if not 0 <= domain_id <= 232:
            raise ValueError(f"domain_id {domain_id} outside Fast DDS's range 0-232")
        owner = _USED_DOMAINS.setdefault(domain_id, request.module.__name__)
        if owner != request.module.__name__:
            raise ValueError(f"domain_id {domain_id} already used by {owner}")
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain_id)
        made.append(context)
        return context

    yield make
    for context in made:
        rclpy.try_shutdown(context=context)


@contextlib.contextmanager
def spun(context, *nodes) -> Iterator[None]:
    """Spin ``nodes`` in a background executor of ``context`` until the block ends."""
    from rclpy.executors import MultiThreadedExecutor

    executor = MultiThreadedExecutor(context=context)
    for node in nodes:
        executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield
    finally:
        executor.shutdown()
        thread.join(timeout=5.0)
        for node in nodes:
            node.destroy_node()


@pytest.fixture
def ros_spin():
    """The ``spun`` context manager, as a fixture."""
    return spun


@pytest.fixture
def node_process():
    """``node_process(name, domain_id, *params)``: the node's console script run to its end
    (``main()`` of ``policy_align_ros.nodes.<name>`` with ``--ros-args -p`` each of
    ``params``); its ``subprocess.CompletedProcess``, output as text."""
    import os
    import subprocess
    import sys

    def run(name: str, domain_id: int, *params: str) -> subprocess.CompletedProcess:
        code = f"import sys; from policy_align_ros.nodes.{name} import main; sys.exit(main())"
        args = [arg for param in params for arg in ("-p", param)]
        return subprocess.run([sys.executable, "-c", code, "--ros-args", *args],
                              env=dict(os.environ, ROS_DOMAIN_ID=str(domain_id)),
                              capture_output=True, text=True, timeout=60)

    return run


@pytest.fixture
def wait():
    """The ``wait_for`` poller, as a fixture."""
    return wait_for


# -- Talos left arm and torso, for the task-space tests (kinematics/ and control/) --------
@pytest.fixture(scope="module")
def robot():
    """``Robot`` of Talos's left arm and torso (``task_space_rigs.ARM``)."""
    from task_space_rigs import ARM

    from policy_align_ros.kinematics import Robot

    return Robot.load("talos", joints=ARM)


@pytest.fixture(scope="module")
def hand_map(robot):
    """``TaskSpaceMap`` of ``robot``'s left gripper (``task_space_rigs.HAND``)."""
    from task_space_rigs import HAND

    from policy_align_ros.kinematics import TaskSpaceMap

    return TaskSpaceMap(robot, [HAND])


@pytest.fixture
def jaco_wrist():
    """Kinova's Jaco, whose joint 6 (the wrist's roll) is continuous and which a driver
    reports in [-pi, pi): ``(smap, six, rest, q)``, the end effector's state map, the
    joint's index, a rest posture with it at -3.0 rad and ``q`` with it at 2.83 rad, 0.45
    rad from the rest across the wrap (5.83 rad the long way)."""
    import numpy as np

    from policy_align_ros.kinematics import Robot, TaskSpaceMap
    from policy_align_ros.kinematics.robot import robots_dir

    robot = Robot.load(str(robots_dir() / "kinova_description" / "robots" / "kinova.urdf"))
    smap = TaskSpaceMap(robot, ["j2s6s200_end_effector"])
    six = robot.joint_names.index("j2s6s200_joint_6")
    assert robot.continuous[six]
    rest = robot.neutral()
    rest[six] = -3.0
    q = rest.copy()
    q[six] = -3.0 + 2 * np.pi - 0.45
    return smap, six, rest, q
