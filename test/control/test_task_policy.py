"""Tests of policy_align_ros.control.task_policy (task-space policies on joints)."""

import json

import numpy as np
import pytest
from task_space_rigs import ARM, ELBOW, HAND, _joint_trajectory

from policy_align_ros.control import (
    ArmedController,
    ControlStep,
    TaskSpacePolicy,
    ZeroCause,
    joint_velocity_bounds,
    joint_velocity_within_limits,
    task_to_joint_velocity,
)
from policy_align_ros.kinematics import (
    FrameStateDefinition,
    Robot,
    TaskSpaceMap,
    constraint_from_spec,
    nullspace_projector,
)


class Attractor:
    """``pi_x(x) = -2 w (x - c)``, the policy of ``phi_x = w ||x - c||^2``, for tests."""

    def __init__(self, center: np.ndarray, w: float = 0.5) -> None:
        self.center, self.w = np.asarray(center, dtype=float), w

    def policy(self, X: np.ndarray) -> np.ndarray:
        return -2.0 * self.w * (np.asarray(X) - self.center)


def _step_velocity(smap: TaskSpaceMap, q: np.ndarray, qdot: np.ndarray, h: float = 1e-6
                   ) -> np.ndarray:
    return (smap.states(q + h * qdot) - smap.states(q - h * qdot)) / (2 * h)


def _circle_rollout(robot: Robot, smap: TaskSpaceMap, steps: int, **gains: float
                    ) -> tuple[np.ndarray, float, float]:
    """Hand tracks a 6 cm circle (period 2 s) for ``steps`` Euler steps of 10 ms."""
    q0 = robot.neutral()
    x0 = smap.states(q0)
    clock = {"t": 0.0}
    w = 2 * np.pi / 2.0

    def circle(X: np.ndarray) -> np.ndarray:
        t = clock["t"]
        target = x0 + 0.06 * np.array([np.cos(w * t) - 1.0, 0.0, np.sin(w * t)])
        feed = 0.06 * w * np.array([-np.sin(w * t), 0.0, np.cos(w * t)])
        return (feed + 5.0 * (target - X[0]))[None]

    tsp = TaskSpacePolicy(circle, smap, **gains)
    q, dt, span = q0.copy(), 0.01, robot.upper - robot.lower
    dist, margin, err = [], 1.0, 0.0
    for k in range(steps):
        clock["t"] = k * dt
        q = q + dt * tsp.command(q)
        margin = min(margin, float(np.min(np.minimum(q - robot.lower, robot.upper - q) / span)))
        if k % 200 == 199:  # once per period, at the same point of the circle
            dist.append(np.linalg.norm(q - q0))
            err = max(err, float(np.linalg.norm(smap.states(q) - x0)))
    return np.array(dist), margin, err


def test_command_moves_frames_along_policy_unconstrained(robot: Robot,
                                                         hand_map: TaskSpaceMap) -> None:
    q = robot.neutral()
    x = hand_map.states(q)
    pol = Attractor(x + np.array([0.1, -0.05, 0.08]))
    tsp = TaskSpacePolicy(pol, hand_map)
    qdot = tsp.command(q)
    pi_x = pol.policy(x[None])[0]
    np.testing.assert_allclose(_step_velocity(hand_map, q, qdot), pi_x, atol=1e-6)
    # An Euler step moves the hand along pi_x to first order: the error is O(dt^2).
    errs = [np.linalg.norm(hand_map.states(q + dt * qdot) - x - dt * pi_x)
            for dt in (1e-2, 1e-3)]
    assert errs[0] < 0.02 * 1e-2 * np.linalg.norm(pi_x)
    assert 50.0 < errs[0] / errs[1] < 200.0
    out = tsp(np.stack([q, q]))
    assert out.shape == (2, robot.nq)
    np.testing.assert_allclose(out[1], qdot)


def test_command_under_a_plane_constraint_moves_along_projected_policy(
        robot: Robot, hand_map: TaskSpaceMap) -> None:
    normal = np.array([0.0, 0.6, 0.8])
    plane = constraint_from_spec({"type": "plane", "frame": HAND, "normal": normal.tolist()},
                                 robot)
    for q in _joint_trajectory(robot, 3, seed=4):
        x = hand_map.states(q)
        pol = Attractor(x + np.array([0.1, 0.1, -0.1]))
        qdot = TaskSpacePolicy(pol, hand_map, plane).command(q)
        A = plane.matrix(q)
        assert np.abs(A @ qdot).max() < 1e-10
        N_x = np.eye(3) - np.outer(normal, normal)
        expect = N_x @ pol.policy(x[None])[0]
        np.testing.assert_allclose(_step_velocity(hand_map, q, qdot), expect, atol=1e-6)


def test_held_elbow_height_keeps_still_while_hand_follows_policy(robot: Robot,
                                                          hand_map: TaskSpaceMap) -> None:
    hold = constraint_from_spec({"type": "position", "frame": ELBOW, "axes": ["z"]}, robot)
    elbow = TaskSpaceMap(robot, [ELBOW])
    q = robot.neutral()
    x = hand_map.states(q)
    pol = Attractor(x + np.array([0.05, 0.05, 0.05]))
    qdot = TaskSpacePolicy(pol, hand_map, hold).command(q)
    A = hold.matrix(q)
    assert np.abs(A @ qdot).max() < 1e-10
    assert abs(_step_velocity(elbow, q, qdot)[2]) < 1e-8
    # Hand and elbow height leave J N_A well conditioned here, so the hand is exact.
    J = hand_map.jacobian(q)
    assert np.linalg.svd(J @ nullspace_projector(A), compute_uv=False).min() > 0.05
    np.testing.assert_allclose(_step_velocity(hand_map, q, qdot), pol.policy(x[None])[0],
                               atol=1e-6)


def test_locked_joint_is_a_constraint_row_not_a_zeroed_component(robot: Robot,
                                                                 hand_map: TaskSpaceMap
                                                                 ) -> None:
    locked = ["arm_left_4_joint", "torso_1_joint"]
    lock = constraint_from_spec({"type": "joints", "joints": locked}, robot)
    q = robot.neutral()
    x = hand_map.states(q)
    pol = Attractor(x + np.array([0.05, -0.05, 0.05]))
    qdot = TaskSpacePolicy(pol, hand_map, lock).command(q)
    idx = [robot.joint_names.index(j) for j in locked]
    assert np.abs(qdot[idx]).max() < 1e-12
    # The other joints take over the task: the hand still follows pi_x exactly, which
    # zeroing the locked components of the unconstrained command would not give.
    np.testing.assert_allclose(_step_velocity(hand_map, q, qdot), pol.policy(x[None])[0],
                               atol=1e-6)
    free = TaskSpacePolicy(pol, hand_map).command(q)
    zeroed = free.copy()
    zeroed[idx] = 0.0
    assert np.linalg.norm(_step_velocity(hand_map, q, zeroed) - pol.policy(x[None])[0]) > 1e-3


def test_joint_at_a_limit_is_not_pushed_out(robot: Robot, hand_map: TaskSpaceMap) -> None:
    q = robot.neutral()
    j = robot.joint_names.index("arm_left_4_joint")
    q[j] = robot.upper[j]
    x = hand_map.states(q)
    # Ask for motion the unconstrained map does with that joint going up past its limit.
    for d in np.eye(3).tolist() + (-np.eye(3)).tolist():
        pol = Attractor(x + 0.1 * np.array(d))
        free = task_to_joint_velocity(hand_map.jacobian(q), pol.policy(x[None])[0],
                                      np.zeros((0, robot.nq)))
        if free[j] > 1e-3:
            break
    else:
        pytest.fail("no direction pushes the elbow out of its limit")
    qdot = TaskSpacePolicy(pol, hand_map, limit_gain=0.0).command(q)
    assert qdot[j] <= 1e-12


def test_speed_limits_keep_the_task_where_other_joints_can_take_over(
        robot: Robot, hand_map: TaskSpaceMap) -> None:
    q = robot.neutral()
    x, J = hand_map.kinematics(q)
    xdot = np.array([0.3, -0.2, 0.25])  # m/s; the least-norm command exceeds 1 rad/s
    hold = constraint_from_spec({"type": "joints", "joints": ["torso_2_joint"]}, robot)
    A = hold.matrix(q)
    exact = {"threshold": 0.0, "damping": 0.0}  # damping is tested on its own below
    free = task_to_joint_velocity(J, xdot, A, **exact)
    vmax = 0.9 * np.abs(free).max()  # still feasible (a linear program finds a qdot)
    qdot = joint_velocity_within_limits(q, J, xdot, A, None, robot.lower, robot.upper,
                                        max_velocity=vmax, dt=0.01, **exact)
    assert np.abs(qdot).max() <= vmax + 1e-9
    # The hand moves exactly as asked and A qdot = 0 holds: saturating joints are held
    # at their bound, not the whole command scaled (which would slow the hand to 90 %).
    np.testing.assert_allclose(J @ qdot, xdot, atol=1e-9)
    np.testing.assert_allclose(A @ qdot, 0.0, atol=1e-12)
    saturated = np.isclose(np.abs(qdot), vmax)
    assert saturated.any()
    # Without speed limits only joints at a position limit are held: the free solution.
    np.testing.assert_allclose(
        joint_velocity_within_limits(q, J, xdot, A, None, robot.lower, robot.upper, **exact),
        free)


def test_policy_keeps_the_task_when_one_joint_brakes_toward_a_limit(
        robot: Robot, hand_map: TaskSpaceMap) -> None:
    from policy_align_ros.control import velocity_scale

    q = robot.neutral()
    x = hand_map.states(q)
    # A task that the other joints can take over within 0.5 rad/s.
    pol = Attractor(x + np.array([0.03, -0.03, 0.03]))
    gains = {"limit_gain": 0.0, "rest_gain": 0.0}
    free = TaskSpacePolicy(pol, hand_map, **gains).command(q)
    # A limit 1e-5 rad ahead of the joint that moves most: braking at 2 rad/s^2 allows it
    # 40 urad/s (2 * 1e-5 / 0.5 with a 0.5 rad/s speed limit: the whole command is
    # braked by one factor), so scaling the whole command would all but stop the hand.
    j = int(np.argmax(np.abs(free)))
    lower, upper = robot.lower.copy(), robot.upper.copy()
    if free[j] > 0:
        upper[j] = q[j] + 1e-5
    else:
        lower[j] = q[j] - 1e-5
    vmax = np.full(robot.nq, 0.5)
    assert velocity_scale(q, free, 0.01, lower, upper, vmax, 2.0) < 0.05
    bounded = TaskSpacePolicy(
        pol, hand_map, **gains,
        bounds=lambda qq: joint_velocity_bounds(qq, lower, upper, vmax, 0.01, 2.0)
    ).command(q)
    assert velocity_scale(q, bounded, 0.01, lower, upper, vmax, 2.0) > 1.0 - 1e-9
    np.testing.assert_allclose(_step_velocity(hand_map, q, bounded),
                               pol.policy(x[None])[0], atol=1e-6)


def test_damping_bounds_qdot_with_the_elbow_held_on_talos(robot: Robot,
                                                         hand_map: TaskSpaceMap) -> None:
    # Holding the elbow leaves the hand about 1.6 mm/rad of motion along one direction:
    # a singularity of J N_A that neither J nor A has.
    hold = constraint_from_spec({"type": "position", "frame": ELBOW}, robot)
    q = robot.neutral()
    A, J = hold.matrix(q), hand_map.jacobian(q)
    assert np.linalg.svd(J, compute_uv=False).min() > 0.1
    assert np.linalg.svd(A, compute_uv=False).min() > 0.02
    assert np.linalg.svd(J @ nullspace_projector(A), compute_uv=False).min() < 0.002
    x = hand_map.states(q)
    for d in np.eye(3):
        pol = Attractor(x + 0.1 * d)
        qdot = TaskSpacePolicy(pol, hand_map, hold, rest_gain=0.0, limit_gain=0.0).command(q)
        assert np.abs(A @ qdot).max() < 1e-10
        assert np.linalg.norm(qdot) <= np.linalg.norm(pol.policy(x[None])) / 0.05 + 1e-9


def test_self_motion_does_not_drift_to_joint_limits(robot: Robot,
                                                    hand_map: TaskSpaceMap) -> None:
    dist, margin, err = _circle_rollout(robot, hand_map, 3000)
    # Over 15 periods the posture returns to the same place each period: no drift.
    assert np.ptp(dist[2:]) < 1e-3
    assert margin > 0.02
    assert err < 5e-3  # the secondary term does not disturb the task
    # Without the secondary term the same task drifts (so the check above can fail).
    free, _, err_free = _circle_rollout(robot, hand_map, 3000, rest_gain=0.0, limit_gain=0.0)
    assert free[-1] - free[0] > 0.3
    assert err_free < 5e-3


def test_policy_dimension_and_bad_gains_are_refused(hand_map: TaskSpaceMap) -> None:
    class Fitted:
        n_features_in_ = 6

        def policy(self, X: np.ndarray) -> np.ndarray:
            return np.zeros_like(X)

    with pytest.raises(ValueError, match=r"^policy\b.*\b6-D\b.*\b3-D\b"):
        TaskSpacePolicy(Fitted(), hand_map)
    with pytest.raises(ValueError, match=r"^damping\b.*-1\.0"):
        TaskSpacePolicy(Attractor(np.zeros(3)), hand_map, damping=-1.0)
    with pytest.raises(ValueError, match=r"^rest\b.*\(9,\).*\(3,\)"):
        TaskSpacePolicy(Attractor(np.zeros(3)), hand_map, rest=np.zeros(3))
    with pytest.raises(ValueError, match=r"^policy\b"):
        TaskSpacePolicy(3.0, hand_map)


def test_non_finite_task_policy_faults_the_controller_until_enabled_again(
        hand_map: TaskSpaceMap) -> None:
    # A silent zero would keep the controller armed, and it would move again by itself
    # once the output is finite: the fault must reach the controller.
    broken = {"now": False}

    def task(X: np.ndarray) -> np.ndarray:
        out = np.tile([0.05, 0.0, 0.0], (len(X), 1))
        return out * np.nan if broken["now"] else out

    robot = hand_map.robot
    tsp = TaskSpacePolicy(task, hand_map)
    q = robot.neutral()
    assert np.all(np.isfinite(tsp.command(q)))
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 0.5), 0.01, policy=tsp)
    controller = ArmedController(step, 2.0, 0.1)
    t = 1_000_000_000
    controller.joint_state(q, t, t)
    assert controller.arm(t)[0]

    def run(ticks: int) -> None:
        nonlocal t
        for _ in range(ticks):
            t += 10_000_000
            controller.joint_state(q, t, t)
            controller.tick(t)

    run(20)
    assert np.abs(controller.command).max() > 0.01
    broken["now"] = True
    assert np.all(np.isnan(tsp.command(q)))
    run(100)
    assert controller.faulted and not controller.armed
    assert controller.zero_cause == ZeroCause.POLICY_NOT_FINITE
    broken["now"] = False
    run(50)
    assert not controller.armed
    np.testing.assert_array_equal(controller.command, 0.0)


def test_policy_learnt_in_hand_space_reaches_targets_from_new_starts() -> None:
    from policy_align_ros.control import policy_for_state
    from policy_align_ros.kinematics import LearningStateMap
    from policy_align_ros.learning import PolicyAlign
    from policy_align_ros.sim.demonstrations import sample_start_states, task_space_rollout
    from policy_align_ros.sim.experts import TaskSpaceExpert

    hands = ["gripper_left_base_link", "gripper_right_base_link"]
    joints = ([f"arm_left_{i}_joint" for i in range(1, 8)]
              + [f"arm_right_{i}_joint" for i in range(1, 8)] + ["torso_1_joint"])
    robot = Robot.load("talos", joints=joints)
    smap = TaskSpaceMap(robot, hands)
    q0 = robot.neutral()
    target = smap.states(q0) + np.array([0.15, 0.05, 0.1, 0.15, -0.05, 0.1])
    expert = TaskSpaceExpert(smap, target, 1.0)
    rng = np.random.default_rng(0)

    def one_plane(k: int):  # a random plane through one hand per demonstration
        normal = rng.standard_normal(3)
        row = np.zeros((1, 6))
        row[0, 3 * (k % 2):3 * (k % 2) + 3] = normal / np.linalg.norm(normal)
        return lambda x, t, pi: row

    starts = sample_start_states(rng, q0, 20, 0.05, robot.lower, robot.upper)
    demos = [task_space_rollout(s, expert, one_plane(k), 150, 0.02, name=str(k))
             for k, s in enumerate(starts)]
    # What `policy-align learn --state frames:...` does: map the recorded joint
    # trajectories to hand states, fit, and store the state definition for the executor.
    learn_map = LearningStateMap(robot, hands)
    trajs = [learn_map(d.joints) for d in demos]
    np.testing.assert_allclose(trajs[0].positions, demos[0].trajectory.positions, atol=1e-12)
    model = PolicyAlign().fit(trajs)
    state = json.loads(json.dumps(learn_map.definition()))
    policy = policy_for_state(model, state, robot)
    np.testing.assert_allclose(policy.rest, np.mean([d.joints.positions[-1] for d in demos],
                                                    axis=0))
    new = sample_start_states(np.random.default_rng(99), q0, 2, 0.05, robot.lower, robot.upper)
    for q in new:
        assert not np.any(np.all(np.isclose(starts, q), axis=1))
        start = np.linalg.norm((smap.states(q) - target).reshape(2, 3), axis=1)
        for _ in range(300):
            q = robot.clip(q + 0.02 * policy.command(q))
        final = np.linalg.norm((smap.states(q) - target).reshape(2, 3), axis=1)
        assert np.all(start > 0.1)
        assert np.all(final < 0.03), final


def test_policy_for_state_accepts_reordered_joints_and_refuses_other_robots(
        robot: Robot, hand_map: TaskSpaceMap) -> None:
    from policy_align_ros.control import policy_for_state

    q = robot.neutral()
    x = hand_map.states(q)
    pol = Attractor(x + np.array([0.05, 0.0, 0.05]))
    state = hand_map.definition.to_dict()
    direct = TaskSpacePolicy(pol, hand_map).command(q)
    # The executor's robot lists the same joints in another order: same motion.
    order = ARM[::-1]
    other = Robot.load("talos", joints=order)
    perm = [ARM.index(j) for j in order]
    got = policy_for_state(pol, state, other)(q[perm][None])[0]
    np.testing.assert_allclose(got, direct[perm], atol=1e-12)
    # A rest posture recorded in the state definition is used (in the robot's order).
    rest = {j: float(v) + 0.1 for j, v in zip(ARM, q, strict=True)}
    tsp = policy_for_state(pol, {**state, "rest": rest}, other)
    np.testing.assert_allclose(tsp.rest, q[perm] + 0.1)
    with pytest.raises(ValueError, match="'rest'.*" + repr(order[0])):
        policy_for_state(pol, {**state, "rest": {}}, other)
    with pytest.raises(ValueError, match="'rest'"):
        policy_for_state(pol, {**state, "rest": dict.fromkeys(ARM)}, other)
    with pytest.raises(ValueError, match=r"\['torso_2_joint'\]"):
        policy_for_state(pol, state, Robot.load("talos", joints=ARM[:-1]))
    with pytest.raises(ValueError, match="'talos'.*'panda'"):
        policy_for_state(pol, state, Robot.load("panda"))
    with pytest.raises(ValueError):  # the same joints in another order
        FrameStateDefinition.from_dict(state).check(other)


def test_constraint_may_be_a_callable_such_as_the_executors(robot: Robot,
                                                            hand_map: TaskSpaceMap) -> None:
    from policy_align_ros.control import ControlStep

    plane = constraint_from_spec({"type": "plane", "frame": HAND, "normal": [0, 0, 1]}, robot)
    step = ControlStep(robot.lower, robot.upper, np.full(robot.nq, 10.0), 0.01, [plane])
    q = robot.neutral()
    pol = Attractor(hand_map.states(q) + np.array([0.05, 0.05, 0.05]))
    tsp = TaskSpacePolicy(pol, hand_map, step.constraint_matrix)
    qdot = tsp.command(q)
    np.testing.assert_allclose(qdot, TaskSpacePolicy(pol, hand_map, plane).command(q))
    assert abs((plane.matrix(q) @ qdot).item()) < 1e-12
    # The executor's step, given the task-space policy, leaves its command as it is.
    step.policy = tsp
    command, _, cause = step(q)
    assert cause is None
    np.testing.assert_allclose(command, qdot, atol=1e-12)
    step.constraints = []  # a parameter change is seen at the next call
    np.testing.assert_allclose(tsp.command(q), TaskSpacePolicy(pol, hand_map).command(q))
    with pytest.raises(ValueError, match=r"^constraint\b"):
        TaskSpacePolicy(pol, hand_map, 3)


def test_non_finite_constraint_rows_give_a_non_finite_command(hand_map: TaskSpaceMap
                                                               ) -> None:
    # Not zeros: a controller must see that no command can be trusted (see above).
    q = hand_map.robot.neutral()
    pol = Attractor(hand_map.states(q) + 0.05)
    tsp = TaskSpacePolicy(pol, hand_map, lambda q, qdot: np.full((1, q.size), np.inf))
    assert np.all(np.isnan(tsp.command(q)))


def test_a_continuous_joint_turns_to_its_rest_the_short_way(jaco_wrist) -> None:
    # The rest term must turn the wrist 0.45 rad across the wrap to its rest, not 5.83 rad
    # back the other way.
    smap, six, rest, q = jaco_wrist
    hold = Attractor(smap.states(q)[0], w=0.0)  # no task motion: the rest term alone
    qdot = TaskSpacePolicy(hold.policy, smap, rest=rest).command(q)
    assert qdot[six] > 0.0  # the short way round, up to rest + a turn
    # On the rest's own turn nothing changes: the same pull, toward the rest.
    q[six] = -3.0 - 0.45
    assert TaskSpacePolicy(hold.policy, smap, rest=rest).command(q)[six] > 0.0
