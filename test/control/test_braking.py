"""Braking before joint limits (with a margin) and barriers, and blending new constraints.

Closed loop on Talos's 18 executor joints: an :class:`ArmedController` and a perfect
velocity-controlled robot (``q += qdot dt``), on a counted clock. Every step's change of
every joint's command must stay within ``max_acceleration * dt``; no forced change.
"""

import numpy as np
import pytest
from control_rigs import ACC, DT_NS, EXECUTOR_JOINTS, LEFT_HAND, _Run

from policy_align_ros.control import ControlStep
from policy_align_ros.control.limits import inner_limits
from policy_align_ros.kinematics import Robot, constraint_from_spec

DT = DT_NS / 1e9
MARGIN = 0.05
MAX_DELTA = ACC * DT
#: Relative tolerance of the acceleration bound (round-off of the projections).
REL = 1e-6


@pytest.fixture(scope="module")
def talos():
    return Robot.load("talos", EXECUTOR_JOINTS)


def _run(robot, policy, q0, constraints=(), margin=MARGIN):
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 0.5), DT,
                       constraints=constraints, policy=policy, min_singular_value=0.0,
                       joint_limit_margin=margin)
    run = _Run(step, q0)
    run.state()
    assert run.arm() == (True, None)
    return run


def _steps(run, start=None):
    """Largest change of any joint's command between consecutive commands."""
    sent = np.array(([] if start is None else [start]) + run.sent)
    return float(np.abs(np.diff(sent, axis=0)).max())


def _wrong_model(robot, kind, seed):
    """A policy that drives most joints out of their limits."""
    rng = np.random.default_rng(seed)
    out = np.where(rng.random(robot.nq) < 0.5, 1.0, -1.0)
    if kind == "goal beyond the limits":
        goal = np.where(out > 0, robot.upper + 0.5, robot.lower - 0.5)
        return lambda X: -2.0 * (X - goal)
    push = out * rng.uniform(0.1, 1.0, robot.nq)
    return lambda X: np.tile(push, (len(X), 1))


@pytest.mark.parametrize("held", [False, True], ids=["free", "left hand held"])
@pytest.mark.parametrize("kind", ["goal beyond the limits", "constant push outwards"])
def test_a_wrong_model_stops_joints_margin_inside_their_limits_within_max_acceleration(
        talos, kind, held):
    robot = talos
    lower, upper = inner_limits(robot.lower, robot.upper, MARGIN)
    holds = ([constraint_from_spec({"type": "position", "frame": LEFT_HAND}, robot)]
             if held else [])
    rng = np.random.default_rng(3)
    q0 = np.clip(robot.neutral() + rng.normal(0.0, 0.3, robot.nq), lower, upper)
    run = _run(robot, _wrong_model(robot, kind, 1), q0, holds)
    p0 = robot.frame_position(q0, LEFT_HAND)
    inside = np.inf
    for _ in range(400):
        run.tick()
        inside = min(inside, float(np.min(np.minimum(run.q - robot.lower,
                                                     robot.upper - run.q))))
    assert inside >= MARGIN - 1e-6
    assert _steps(run, np.zeros(robot.nq)) <= MAX_DELTA * (1.0 + REL)
    assert not [e for e in run.events if e[0] == "warning"]  # no forced change reported
    at_limit = np.minimum(run.q - lower, upper - run.q) < 1e-6
    assert np.count_nonzero(at_limit) >= 3  # the model did drive joints to their limits
    if held:
        assert np.linalg.norm(robot.frame_position(run.q, LEFT_HAND) - p0) < 1e-3


def test_a_joint_inside_the_margin_band_moves_only_inwards(talos):
    robot = talos
    q0 = robot.neutral().copy()
    # Two joints 1 cm inside their URDF limits, i.e. within the margin band; a model
    # pushing every joint towards its upper limit.
    j, k = 6, 13
    q0[j], q0[k] = robot.upper[j] - 0.01, robot.lower[k] + 0.01
    run = _run(robot, lambda X: np.full_like(X, 0.3), q0)
    for _ in range(100):
        before = run.q.copy()
        run.tick()
        assert run.q[j] <= before[j]  # at the upper side: never further out
    assert run.q[j] == q0[j]
    assert run.q[k] > robot.lower[k] + MARGIN  # pushed inwards: it leaves the band
    assert _steps(run, np.zeros(robot.nq)) <= MAX_DELTA * (1.0 + REL)


def test_inner_limits_keep_lower_below_upper_and_continuous_joints_free():
    lower = np.array([-1.0, 0.0, -np.inf, 0.5])
    upper = np.array([1.0, 0.06, np.inf, 0.5])
    lo, hi = inner_limits(lower, upper, 0.05)
    np.testing.assert_allclose(lo, [-0.95, 0.015, -np.inf, 0.5])
    np.testing.assert_allclose(hi, [0.95, 0.045, np.inf, 0.5])
    step = ControlStep(lower, upper, 0.5, DT, joint_limit_margin=0.05)
    np.testing.assert_array_equal(step.control_lower, lo)
    with pytest.raises(ValueError, match="joint_limit_margin"):
        step.joint_limit_margin = -0.1


def _push_hand_down(robot):
    """A wrong model: every joint helps lower the left hand, the fastest at 5 rad/s."""
    def policy(X):
        jz = robot.frame_jacobian(X[0], LEFT_HAND)[2]
        return (-5.0 * jz / np.abs(jz).max())[None]
    return policy


@pytest.mark.parametrize(("gap", "distance"), [(0.2, 0.05), (0.1, 0.02)])
def test_a_barrier_approached_at_full_speed_is_braked_before_it_within_max_acceleration(
        talos, gap, distance):
    robot = talos
    lower, upper = inner_limits(robot.lower, robot.upper, MARGIN)
    q0 = np.clip(robot.neutral(), lower, upper)
    floor = robot.frame_position(q0, LEFT_HAND)[2] - gap
    barrier = constraint_from_spec({"type": "barrier", "frame": LEFT_HAND,
                                    "point": [0.0, 0.0, floor], "normal": [0.0, 0.0, 1.0],
                                    "distance": distance}, robot)
    run = _run(robot, _push_hand_down(robot), q0, [barrier])
    heights, speeds = [], []
    for _ in range(450):  # the hand comes down in spurts while joints reach limits
        run.tick()
        heights.append(robot.frame_position(run.q, LEFT_HAND)[2] - floor)
        speeds.append(-float(robot.frame_jacobian(run.q, LEFT_HAND)[2] @ run.sent[-1]))
    assert min(heights) >= -1e-6  # never crossed
    assert min(heights) >= distance - 1e-4  # stopped where the barrier starts to act
    assert max(speeds) > 0.05  # the hand did come down fast
    assert abs(speeds[-1]) < 1e-3
    assert _steps(run, np.zeros(robot.nq)) <= MAX_DELTA * (1.0 + REL)
    assert not [e for e in run.events if e[0] == "warning"]  # no forced change reported


def test_a_hold_added_while_moving_is_blended_in_within_max_acceleration(talos):
    robot = talos
    lower, upper = inner_limits(robot.lower, robot.upper, MARGIN)
    center = np.clip(robot.neutral(), lower, upper)
    rng = np.random.default_rng(5)
    q0 = np.clip(center + rng.normal(0.0, 0.3, robot.nq), lower, upper)
    run = _run(robot, lambda X: -3.0 * (X - center), q0)
    for _ in range(30):
        run.tick()
    hand = robot.frame_jacobian(run.q, LEFT_HAND) @ run.sent[-1]
    assert np.linalg.norm(hand) > 0.1  # the hand moves fast when the hold comes
    hold = constraint_from_spec({"type": "position", "frame": LEFT_HAND}, robot)
    run.control.step.constraints = [hold]
    errors = []
    for _ in range(300):
        q = run.q.copy()
        run.tick()
        errors.append(np.linalg.norm(hold.matrix(q) @ run.sent[-1]))
    assert _steps(run, np.zeros(robot.nq)) <= MAX_DELTA * (1.0 + REL)
    assert not [e for e in run.events if e[0] == "warning"]  # no forced change reported
    assert errors[0] > 0.05  # the first steps are a blend, not A qdot = 0 ...
    assert max(errors[100:]) < 1e-3  # ... then the hand is held (the drift correction
    assert errors[-1] < 1e-5  # pulling it back to where the hold began decays)


def test_barrier_clearance_and_its_gradient(talos):
    robot = talos
    q = robot.neutral()
    p = robot.frame_position(q, LEFT_HAND)
    spec = {"type": "barrier", "frame": LEFT_HAND, "point": [0.0, 0.0, p[2] - 0.2],
            "normal": [0.0, 0.0, 1.0], "distance": 0.05}
    barrier = constraint_from_spec(spec, robot)
    c, g = barrier.clearance(q)
    assert c == pytest.approx(0.15)
    eps = 1e-6
    numeric = [(barrier.clearance(q + eps * e)[0] - barrier.clearance(q - eps * e)[0])
               / (2 * eps) for e in np.eye(robot.nq)]
    np.testing.assert_allclose(g, numeric, atol=1e-6)
    boxed = constraint_from_spec({**spec, "lower": [p[0] + 1.0, None, None]}, robot)
    assert boxed.clearance(q) == (float("inf"), None)  # outside its box: no barrier
