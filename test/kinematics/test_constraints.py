"""Tests of policy_align_ros.kinematics.constraints (A(q) from frame Jacobians, specs)."""

import numpy as np
import pytest

from policy_align_ros.kinematics import (
    BarrierConstraint,
    Robot,
    StackedConstraint,
    constraint_from_spec,
    nullspace_projector,
)
from policy_align_ros.kinematics.constraints import barrier_active

TALOS_ARMS = (
    [f"arm_left_{i}_joint" for i in range(1, 8)]
    + [f"arm_right_{i}_joint" for i in range(1, 8)]
    + ["torso_1_joint", "torso_2_joint"]
)


@pytest.fixture(scope="module")
def talos() -> Robot:
    return Robot.load("talos", joints=TALOS_ARMS)


@pytest.fixture(scope="module")
def panda() -> Robot:
    return Robot.load("panda", joints=[f"panda_joint{i}" for i in range(1, 8)])


@pytest.fixture(scope="module")
def ur5() -> Robot:
    return Robot.load("ur5")


def _specs(frame: str, other: str, robot: Robot) -> list:
    return [
        {"type": "plane", "frame": frame, "normal": [0.3, -0.2, 1.0]},
        {"type": "position", "frame": frame, "axes": ["x", "z"]},
        {"type": "position", "frame": other},
        [
            {"type": "plane", "frame": frame, "normal": [0, 0, 1]},
            {"type": "joints", "joints": robot.joint_names[:2]},
        ],
    ]


@pytest.mark.parametrize(
    ("fixture", "frame", "other"),
    [("talos", "gripper_left_base_link", "gripper_right_base_link"),
     ("panda", "panda_hand", "panda_link4"),
     ("ur5", "tool0", "forearm_link")],
)
def test_projector_kills_constraint_on_random_configurations(fixture, frame, other, request):
    robot: Robot = request.getfixturevalue(fixture)
    rng = np.random.default_rng(4)
    for spec in _specs(frame, other, robot):
        c = constraint_from_spec(spec, robot)
        for _ in range(5):
            q = robot.random_configuration(rng, std=0.5)
            A = c.matrix(q)
            assert A.shape[1] == robot.nq
            N = nullspace_projector(A)
            np.testing.assert_allclose(A @ N, 0.0, atol=1e-10)
            np.testing.assert_allclose(N @ N, N, atol=1e-10)


def test_plane_constraint_is_normal_times_jacobian(talos: Robot) -> None:
    c = constraint_from_spec(
        {"type": "plane", "frame": "arm_left_7_link", "normal": [0, 0, 2]}, talos)
    q = talos.neutral() + 0.1
    np.testing.assert_allclose(c.matrix(q), talos.frame_jacobian(q, "arm_left_7_link")[2:3])


def test_motion_in_nullspace_keeps_frame_on_plane(ur5: Robot) -> None:
    c = constraint_from_spec({"type": "plane", "frame": "tool0", "normal": [1, 1, 0]}, ur5)
    rng = np.random.default_rng(5)
    q = ur5.neutral() + 0.3 * rng.standard_normal(ur5.nq)
    v = rng.standard_normal(ur5.nq)
    dq = 1e-6 * nullspace_projector(c.matrix(q)) @ v
    p0 = ur5.frame_position(q, "tool0")
    p1 = ur5.frame_position(q + dq, "tool0")
    n = np.array([1, 1, 0]) / np.sqrt(2)
    assert abs(n @ (p1 - p0)) < 1e-10  # second order only
    assert np.linalg.norm(p1 - p0) > 1e-8  # but it did move


def test_joint_lock_rows(ur5: Robot) -> None:
    c = constraint_from_spec({"type": "joints", "joints": ["elbow_joint"]}, ur5)
    N = nullspace_projector(c.matrix(ur5.neutral()))
    assert N[2, 2] == 0.0 and np.trace(N) == pytest.approx(5.0)


def test_a_joint_locked_twice_is_refused(ur5: Robot) -> None:
    # Two equal rows: a constraint matrix that is singular wherever the robot is.
    with pytest.raises(ValueError, match=r"\bjoints\b.*'elbow_joint'"):
        constraint_from_spec({"type": "joints", "joints": ["elbow_joint", "elbow_joint"]},
                             ur5)


def test_barrier_switches_with_distance_and_direction(ur5: Robot) -> None:
    q = ur5.neutral() + 0.2
    p = ur5.frame_position(q, "tool0")
    normal = np.array([0.0, 0.0, 1.0])
    # Plane 3 cm below the tool, normal pointing towards the tool side.
    close = BarrierConstraint(ur5, "tool0", p - 0.03 * normal, normal, distance=0.05)
    far = BarrierConstraint(ur5, "tool0", p - 0.10 * normal, normal, distance=0.05)
    assert close.matrix(q).shape == (1, ur5.nq)
    assert far.matrix(q).shape == (0, ur5.nq)
    np.testing.assert_array_equal(nullspace_projector(far.matrix(q), n=ur5.nq), np.eye(6))
    jac = ur5.frame_jacobian(q, "tool0")
    down = np.linalg.pinv(jac) @ -normal  # joint motion moving the tool towards the plane
    assert close.active(q, down)
    assert not close.active(q, -down)  # receding is never blocked
    bilateral = BarrierConstraint(ur5, "tool0", p - 0.03 * normal, normal, 0.05,
                                  unilateral=False)
    assert bilateral.active(q, -down)
    # Outside the panel's extent the barrier does not exist (the gap).
    panel = BarrierConstraint(ur5, "tool0", p - 0.03 * normal, normal, 0.05,
                              lower=[p[0] + 0.01, None, None])
    assert not panel.active(q, down)
    # The blocked direction is exactly the normal one.
    N = nullspace_projector(close.matrix(q, down))
    assert abs(normal @ jac @ N @ down) < 1e-10


def test_barrier_active_from_behind() -> None:
    point, normal = np.zeros(3), np.array([1.0, 0.0, 0.0])
    p = np.array([-0.02, 0.0, 0.0])  # behind the plane
    assert barrier_active(p, point, normal, 0.05, velocity=np.array([1.0, 0, 0]))
    assert not barrier_active(p, point, normal, 0.05, velocity=np.array([-1.0, 0, 0]))
    assert not barrier_active(p, point, normal, 0.01)
    # A step longer than the activation distance would tunnel through without lookahead.
    far = np.array([-0.2, 0.0, 0.0])
    assert not barrier_active(far, point, normal, 0.05, velocity=np.array([0.3, 0, 0]))
    assert barrier_active(far, point, normal, 0.05, velocity=np.array([0.3, 0, 0]),
                          lookahead=1.0)
    assert not barrier_active(far, point, normal, 0.05, velocity=np.array([0.1, 0, 0]),
                              lookahead=1.0)


def test_stacking(talos: Robot) -> None:
    a = constraint_from_spec({"type": "position", "frame": "arm_left_7_link"}, talos)
    b = constraint_from_spec({"type": "plane", "frame": "arm_right_7_link",
                              "normal": [0, 1, 0]}, talos)
    both = a + b
    assert isinstance(both, StackedConstraint)
    q = talos.neutral()
    assert both.matrix(q).shape == (4, talos.nq)


@pytest.mark.parametrize(
    ("spec", "match"),
    [  # each names the field and the value it refuses (or the field that is missing)
        ({"frame": "tool0"}, "'type'"),
        ({"type": "plnae", "frame": "tool0", "normal": [0, 0, 1]}, r"'plnae'.*\bplane\b"),
        ({"type": "plane", "normal": [0, 0, 1]}, "'frame'"),
        ({"type": "plane", "frame": "tool0", "normal": [0, 0]}, r"\bnormal\b.*\(2,\)"),
        ({"type": "plane", "frame": "tool0", "normal": [0, 0, 0]},
         r"\bnormal\b.*\[0, 0, 0\]"),
        ({"type": "plane", "frame": "tool", "normal": [0, 0, 1]}, r"\bframe\b.*'tool'"),
        ({"type": "plane", "frame": "tool0", "normal": [0, 0, 1], "nrm": 1}, "'nrm'"),
        ({"type": "position", "frame": "tool0", "axes": ["w"]}, r"\baxes\b.*'w'"),
        ({"type": "barrier", "frame": "tool0", "point": [0, 0, 0], "normal": [1, 0, 0],
          "distance": -1}, r"\bdistance\b.*-1\.0"),
        ({"type": "barrier", "frame": "tool0", "point": [0, 0, 0], "normal": [1, 0, 0],
          "distance": 0.1, "lower": [0, 0]}, r"\blower\b.*\[0, 0\]"),
        ({"type": "joints", "joints": ["elbow"]}, r"\bjoints\b.*'elbow'"),
        ([{"type": "joints", "joints": ["elbow_joint"]}, {"type": "x"}], r"spec \[1\].*'x'"),
        ("plane", r"\bspec\b.*\bstr\b"),
        # Wrong types, as a YAML parameter can carry them: a ValueError, never a TypeError.
        ({"type": "joints", "joints": 3}, r"\bjoints\b.*\b3$"),
        ({"type": ["plane"], "frame": "tool0", "normal": [0, 0, 1]}, r"'type'.*\['plane'\]"),
        ({"type": "position", "frame": "tool0", "axes": [["x"]]}, r"\baxes\b.*\['x'\]"),
        ({"type": "barrier", "frame": "tool0", "point": [0, 0, 0], "normal": [1, 0, 0],
          "distance": 0.1, "upper": [[1], 0, 0]}, r"\bupper\b.*\[\[1\], 0, 0\]"),
    ],
)
def test_spec_validation_names_the_field(spec, match, ur5: Robot) -> None:
    with pytest.raises(ValueError, match=match):
        constraint_from_spec(spec, ur5)


def test_position_hold_coordinates_have_the_constraint_rows_as_jacobian(talos: Robot) -> None:
    hold = constraint_from_spec({"type": "position", "frame": "arm_left_7_link",
                                 "axes": ["x", "z"]}, talos)
    rng = np.random.default_rng(8)
    q = talos.random_configuration(rng, std=0.3)
    p = hold.hold_position(q)
    np.testing.assert_allclose(p, talos.frame_position(q, "arm_left_7_link")[[0, 2]])
    eps = 1e-6
    numeric = np.column_stack([
        (hold.hold_position(q + eps * e) - hold.hold_position(q - eps * e)) / (2 * eps)
        for e in np.eye(talos.nq)])
    np.testing.assert_allclose(hold.matrix(q), numeric, atol=1e-7)
    # Planes, barriers and joint locks hold nothing: the controller latches positions only.
    plane = constraint_from_spec({"type": "plane", "frame": "arm_left_7_link",
                                  "normal": [0, 0, 1]}, talos)
    assert not hasattr(plane, "hold_position")
