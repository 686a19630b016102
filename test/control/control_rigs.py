"""Shared rigs of the control tests (ROS-free): limits, policies, constraints, runs."""

import numpy as np

from policy_align_ros.control import ArmedController
from policy_align_ros.kinematics import Robot, constraint_from_spec

#: Talos arms and torso (ROS-free test: the nodes' default list is not imported).
TALOS_JOINTS = (
    ["torso_1_joint", "torso_2_joint"]
    + [f"arm_left_{i}_joint" for i in range(1, 8)]
    + [f"arm_right_{i}_joint" for i in range(1, 8)]
)
N = 6
LOWER = -np.ones(N)
UPPER = np.ones(N)
VMAX = np.full(N, 0.5)
DT = 0.01


class _Linear:
    """pi(x) = -(x - c) in model order."""

    def __init__(self, center):
        self.center = np.asarray(center, dtype=float)

    def __call__(self, X):
        return -(X - self.center)


class _Constant:
    def __init__(self, v: np.ndarray):
        self.v = v

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return np.tile(self.v, (len(X), 1))


def _lift_that_a_lock_turns_towards_a_floor(robot: Robot, q: np.ndarray):
    """A floor 2 cm below the left hand, acting within 5 cm; a policy ``pi`` that lifts the
    hand; a lock on the joint that lifts it most, which leaves only the part that lowers
    it; and the hand's z Jacobian."""
    frame = "arm_left_7_link"
    p = robot.frame_position(q, frame)
    spec = {"type": "barrier", "frame": frame, "point": [p[0], p[1], p[2] - 0.02],
            "normal": [0.0, 0.0, 1.0], "distance": 0.05}
    jz = robot.frame_jacobian(q, frame)[2]
    up, down = int(np.argmax(jz)), int(np.argmin(jz))
    pi = np.zeros(robot.nq)
    pi[up], pi[down] = 0.3, 0.2
    lock = constraint_from_spec({"type": "joints", "joints": [TALOS_JOINTS[up]]}, robot)
    return constraint_from_spec(spec, robot), lock, pi, jz


# -- ramps and arming (ArmedController), driven by an injected clock ---------------------
DT_NS = 10_000_000  # 10 ms period
ACC = 2.0  # rad/s^2
STEP_TOL = 1e-12


class _Row:
    """A fixed constraint row, switchable on and off."""

    def __init__(self, row, active=True):
        self.row = np.asarray(row, dtype=float)[None, :]
        self.active = active

    def matrix(self, q, qdot=None):
        return self.row if self.active else np.zeros((0, self.row.shape[1]))


class _Run:
    """An ArmedController and a perfect velocity-controlled robot, on a counted clock."""

    def __init__(self, step, q0, max_acceleration=ACC, timeout_s=0.05, skew_s=0.0):
        self.control = ArmedController(step, max_acceleration, timeout_s, skew_s)
        self.q = np.asarray(q0, dtype=float).copy()
        self.k = 1000  # tick count; the clock is k * DT_NS
        self.sent: list[np.ndarray] = []
        self.events: list[tuple[str, str]] = []

    @property
    def now(self):
        return self.k * DT_NS

    def keep(self, out):
        self.events += out.events
        if out.command is not None:
            self.sent.append(out.command)
        return out

    def state(self, stamp_ns=None):
        return self.keep(self.control.joint_state(
            self.q.copy(), self.now if stamp_ns is None else stamp_ns, self.now))

    def tick(self, states=True):
        """One period: a joint state, then the control step; the robot then moves."""
        if states:
            self.state()
        out = self.keep(self.control.tick(self.now))
        if out.command is not None:
            self.q += out.command * DT_NS / 1e9
        self.k += 1
        return out

    def arm(self):
        """``(accepted, cause)``: the cause of a refusal (the words are in
        ``control.arm_check(now)[1]``), None when armed."""
        accepted, _, out = self.control.arm(self.now)
        self.keep(out)
        # The check has no side effects: at the same time it gives the refusal's cause.
        return accepted, (None if accepted else self.control.arm_check(self.now)[0])


def _assert_ramped(commands, max_delta, start=None):
    """Every consecutive change of every joint within ``max_delta`` (from ``start``)."""
    seq = np.array(([start] if start is not None else []) + list(commands))
    steps = np.abs(np.diff(seq, axis=0))
    assert steps.max() <= max_delta + STEP_TOL, (steps.max(), int(steps.max(axis=1).argmax()))


# -- drift correction of held frames and near-singular constraints ----------------------
EXECUTOR_JOINTS = TALOS_JOINTS + ["head_1_joint", "head_2_joint"]
LEFT_HAND = "arm_left_7_link"


def _talos_hold_and_plane():
    robot = Robot.load("talos", EXECUTOR_JOINTS)
    hold = constraint_from_spec({"type": "position", "frame": LEFT_HAND}, robot)
    plane = constraint_from_spec({"type": "plane", "frame": "arm_right_7_link",
                                  "normal": [0.2, 0.5, 1.0]}, robot)
    return robot, hold, plane
