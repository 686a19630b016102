"""The ``executor`` node with a model learnt on hand positions (``frames`` state; domain ids
206, 207, 209).

Assertions count control ticks and messages, never wall-clock speed: waits are "until a
condition holds, or fail after a generous timeout".
"""

from pathlib import Path

import numpy as np
import pytest
from executor_rig import JOINTS, PERIOD, _assert_ramped
from rclpy.parameter import Parameter
from std_msgs.msg import String

from policy_align_ros.learning import PolicyAlign

HAND = "gripper_left_base_link"
_FRAMES: dict[str, object] = {}


def _frames_model():
    """A PolicyAlign model learnt on left-hand positions of task-space expert demos.

    Six demonstrations of a hand-space expert (``xdot = pi_x = -grad phi_x``, driven through
    the arm), mapped to hand states as ``policy-align learn --state frames:...`` does.
    Returns (model, state definition dict, target (3,), robot, state map).
    """
    from policy_align_ros.kinematics import LearningStateMap, Robot, TaskSpaceMap
    from policy_align_ros.sim.demonstrations import sample_start_states, task_space_rollout
    from policy_align_ros.sim.experts import TaskSpaceExpert

    if not _FRAMES:
        robot = Robot.load("talos", joints=JOINTS)
        smap = TaskSpaceMap(robot, [HAND])
        q0 = robot.neutral()
        target = smap.states(q0) + np.array([0.1, 0.05, 0.08])
        expert = TaskSpaceExpert(smap, target, 1.0)
        starts = sample_start_states(np.random.default_rng(0), q0, 6, 0.05, robot.lower,
                                     robot.upper)
        demos = [task_space_rollout(q, expert, None, 60, 0.05, name=f"demo_{k}")
                 for k, q in enumerate(starts)]
        learn_map = LearningStateMap(robot, [HAND])
        model = PolicyAlign().fit([learn_map(d.joints) for d in demos])
        _FRAMES.update(model=model, state=learn_map.definition(), target=target,
                       robot=robot, smap=smap)
    return (_FRAMES["model"], _FRAMES["state"], _FRAMES["target"], _FRAMES["robot"],
            _FRAMES["smap"])


def _save_frames_model(path: Path, state: dict) -> Path:
    model = _frames_model()[0]
    model.state_definition_ = state
    try:
        model.save(path)
    finally:
        model.state_definition_ = _FRAMES["state"]
    return path


def test_frames_model_moves_the_hand_along_the_projected_policy(rig, tmp_path):
    """A model learnt on hand positions drives the arm through J under A(q)."""
    from policy_align_ros.control import policy_for_state
    from policy_align_ros.kinematics import constraint_from_spec

    model, state, target, robot, smap = _frames_model()
    path = _save_frames_model(tmp_path / "hand.npz", state)
    plane = f"[{{type: plane, frame: {HAND}, normal: [0, 0, 1]}}]"
    r = rig(206, model_path=str(path), constraints=plane)
    assert r.node.model_state == f"frames {HAND}"
    # Phase 1, the robot held still: after the ramp the command is the task-space map
    # of the learnt pi_x under the hand plane, scaled by the speed limit only.
    r.q = robot.clip(robot.neutral() + np.array([0.1, 0.15, -0.1, 0.2, 0.0, 0.1, 0.0]))
    r.enable_when_fresh()
    r.spin_until(lambda: len(r.commands) >= 3 and np.array_equal(r.commands[-1],
                                                                 r.commands[-2]),
                 what="a steady command")
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))
    c = r.commands[-1]
    A = constraint_from_spec({"type": "plane", "frame": HAND, "normal": [0, 0, 1]},
                             robot).matrix(r.q)
    assert np.abs(A @ c).max() < 1e-9  # A(q) qdot = 0
    x, J = smap.kinematics(r.q)
    pi_x = model.policy(x[None])[0]
    N_x = np.diag([1.0, 1.0, 0.0])
    xdot = J @ c  # the hand's velocity to first order
    s = float(xdot @ (N_x @ pi_x)) / float(np.linalg.norm(N_x @ pi_x)) ** 2
    assert 0.05 < s <= 1.0 + 1e-9
    np.testing.assert_allclose(xdot, s * N_x @ pi_x, atol=1e-9)
    expect = policy_for_state(model, state, robot, r.node._constraint_matrix).command(r.q)
    np.testing.assert_allclose(c, s * expect, atol=1e-9)
    # Phase 2, closed loop: the arm integrates each command; the hand slides in its
    # plane towards the target's projection.
    start = x.copy()
    count = len(r.commands)
    for _ in range(300):
        r.spin_until(lambda n=count: len(r.commands) > n, what="the next command")
        count = len(r.commands)
        r.q = robot.clip(r.q + PERIOD * r.commands[-1])
    end = smap.states(r.q)
    # Held in its plane: exact to first order per step; 300 Euler steps of the arm
    # drift at second order.
    assert abs(end[2] - start[2]) < 2e-3
    before = np.linalg.norm((start - target)[:2])
    assert np.linalg.norm((end - target)[:2]) < 0.3 * before, (before, end - target)


def test_frames_model_of_another_robot_or_frame_set_is_refused(rig, tmp_path):
    from policy_align_ros.kinematics import FrameStateDefinition, Robot

    _, state, _, _, _ = _frames_model()
    good = _save_frames_model(tmp_path / "hand.npz", state)
    panda = FrameStateDefinition.from_robot(Robot.load("panda"), ["panda_hand"]).to_dict()
    other_robot = _save_frames_model(tmp_path / "panda.npz", panda)
    two = _save_frames_model(tmp_path / "two.npz",
                             {**state, "frames": [HAND, "arm_left_4_link"]})
    unknown = _save_frames_model(tmp_path / "kind.npz", {**state, "type": "poses"})
    r = rig(207, model_path=str(good))
    result = r.node.set_parameters([Parameter("model_path", value=str(other_robot))])[0]
    assert not result.successful
    assert "panda.npz" in result.reason and "URDF" in result.reason  # the file, what differs
    result = r.node.set_parameters([Parameter("model_path", value=str(two))])[0]
    assert not result.successful
    assert "3-D" in result.reason and "6-D" in result.reason  # the model's, the map's
    result = r.node.set_parameters([Parameter("model_path", value=str(unknown))])[0]
    assert not result.successful and "'poses'" in result.reason
    # Announced by the learner: refused with the reason, the loaded model stays.
    r.models.publish(String(data=str(other_robot)))
    r.spin(0.3)
    assert r.node.model_path == str(good) and r.node.model_state == f"frames {HAND}"


def test_frame_support_distance_measures_the_hand_state_and_its_gradient():
    """The guard's distance for a frames model: in hand space, gradient through J."""
    from policy_align_ros.control import FrameSupportDistance

    model, _, _, robot, smap = _frames_model()
    distance = FrameSupportDistance(model, smap)
    q = robot.clip(robot.neutral() + np.array([0.4, 0.3, -0.3, 0.5, 0.2, 0.3, 0.1]))
    d, grad = distance(q)
    x = smap.states(q)
    expect, nearest = model.support_query(x[None])
    assert d == pytest.approx(expect[0]) and d > 2.0  # the hand is off the data
    assert d == pytest.approx(np.linalg.norm(x - nearest[0]) / model.support_spacing_)
    h = 1e-6
    fd = [(distance(q + h * e)[0] - distance(q - h * e)[0]) / (2 * h) for e in np.eye(q.size)]
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-6 * np.abs(grad).max())


def test_extrapolation_guard_of_a_frames_model_measures_in_hand_space(rig, tmp_path):
    """The guard scales hand motion leading away from the demonstrated hand states."""
    from policy_align_ros.control import FrameSupportDistance

    model, state, _, robot, smap = _frames_model()
    path = _save_frames_model(tmp_path / "hand.npz", state)
    q = robot.clip(robot.neutral() + np.array([0.4, 0.3, -0.3, 0.5, 0.2, 0.3, 0.1]))
    x = smap.states(q)
    d, nearest = model.support_query(x[None])
    u = (x - nearest[0]) / np.linalg.norm(x - nearest[0])  # outwards, in hand space
    p = model.policy(x[None])[0]
    a = float(p @ u)
    assert a < 0.0  # the learnt policy leads back to the data...
    w = (p - a * u) / np.linalg.norm(p - a * u)
    b = float(p @ w)
    # ...so hold the hand on a plane that turns it outwards: with n = cos(t) u + sin(t) w
    # and t = pi - delta, N_x p . u = sin(delta) (a sin(delta) + b cos(delta)) > 0.
    delta = 0.5 * np.arctan2(b, -a)
    n = -np.cos(delta) * u + np.sin(delta) * w
    plane = f"[{{type: plane, frame: {HAND}, normal: {n.tolist()}}}]"
    r = rig(209, model_path=str(path), constraints=plane, max_extrapolation=1000.0,
            max_extrapolation_rad=100.0)  # the joint-space cap off: spacings alone
    r.q = q
    guard = r.node.controller.step.guard
    assert isinstance(guard.distance, FrameSupportDistance)
    assert guard.max_extrapolation_rad == 100.0
    r.enable_when_fresh()

    def steady():
        r.spin_until(lambda: len(r.commands) >= 3 and np.array_equal(r.commands[-1],
                                                                     r.commands[-2]),
                     what="a steady command")
        return r.commands[-1]

    free = steady()
    d_q, grad = FrameSupportDistance(model, smap)(q)
    assert d_q == pytest.approx(d[0]) and float(grad @ free) > 0.0  # leads further out
    assert r.node.controller.extrapolation_scale == 1.0
    assert r.node.controller.step.extrapolation_distance == pytest.approx(d[0])
    # One spacing beyond max_extrapolation: scaled by 1 - 1 / band < 1, same direction.
    assert r.node.set_parameters([Parameter("max_extrapolation", value=d[0] - 1.0)]
                                 )[0].successful
    count = len(r.commands)
    r.spin_until(lambda: len(r.commands) > count + 2, what="commands after the change")
    scaled = steady()
    g = r.node.controller.extrapolation_scale
    assert 0.0 < g < 1.0
    np.testing.assert_allclose(scaled, g * free, atol=1e-9)
    _assert_ramped(r.commands, start=np.zeros(len(JOINTS)))
