"""The physical arm (policy_align_ros.sim.dynamics): servos through the arm's dynamics, a
plane that pushes back and rubs."""

import numpy as np
import pinocchio as pin
import pytest

from policy_align_ros.kinematics import Robot
from policy_align_ros.sim.dynamics import ContactPlane, ServoArm, contact_force, servo_gains

FRAME = "panda_hand_tcp"


@pytest.fixture(scope="module")
def panda():
    return Robot.load("panda", joints=[f"panda_joint{i}" for i in range(1, 8)])


def test_a_plane_pushes_only_when_touched_never_pulls_and_its_friction_opposes_sliding():
    plane = ContactPlane((0.0, 0.0, 2.0), 0.5, mu=0.4)
    assert plane.normal == (0.0, 0.0, 1.0)
    np.testing.assert_array_equal(contact_force(np.array([0, 0, 0.51]), np.zeros(3), plane),
                                  np.zeros(3))
    # 1 mm into it and sliding along x at 0.2 m/s (above the regularising slip speed).
    force = contact_force(np.array([0, 0, 0.499]), np.array([0.2, 0, 0]), plane)
    assert force[2] == pytest.approx(plane.stiffness * 1e-3)
    assert force[0] == pytest.approx(-0.4 * force[2]) and force[1] == 0.0
    # Leaving it fast: the damper would pull, the plane does not.
    leaving = contact_force(np.array([0, 0, 0.499]), np.array([0, 0, 1.0]), plane)
    np.testing.assert_array_equal(leaving, np.zeros(3))


def test_bad_planes_are_named():
    with pytest.raises(ValueError, match="normal"):
        ContactPlane((0.0, 0.0, 0.0), 0.0)
    with pytest.raises(ValueError, match="mu"):
        ContactPlane((0.0, 0.0, 1.0), 0.0, mu=-0.1)
    with pytest.raises(ValueError, match="slip"):
        ContactPlane((0.0, 0.0, 1.0), 0.0, slip=0.0)


def test_the_motors_saturate_on_gravity_and_servo_together(panda):
    arm = ServoArm(panda, FRAME, tau=0.05)
    q = panda.neutral()
    # Asked for far more than the motors give: the torque is the effort limit, whatever
    # share gravity compensation takes of it.
    u = np.full(7, 100.0)
    expected = pin.aba(panda.model, pin.Data(panda.model), q, np.zeros(7),
                       arm.effort)
    np.testing.assert_allclose(arm._accelerate(q, np.zeros(7), u), expected)


def test_servo_gains_give_each_joint_its_time_constant_at_the_reference(panda):
    gains = servo_gains(panda.model, panda.neutral(), 0.05)
    inertia = np.diag(pin.crba(panda.model, panda.model.createData(), panda.neutral()))
    np.testing.assert_allclose(gains * 0.05, inertia)
    assert gains[0] > 10 * gains[-1]  # the shoulder carries the arm, the wrist a hand


def test_the_servos_track_a_command_through_the_coupled_dynamics(panda):
    arm = ServoArm(panda, FRAME, tau=0.05)
    q0 = panda.neutral()
    u = np.array([0.3, -0.2, 0.2, 0.3, -0.3, 0.2, 0.4])
    Q, V, times, touching = arm.run(q0, lambda q, t: u, 26, 0.02)
    np.testing.assert_array_equal(Q[0], q0)
    np.testing.assert_array_equal(V[0], np.zeros(7))
    assert not touching.any()
    # Not there at once: the heavy joints lag by about a time constant (the first sample
    # is 0.4 tau on), each joint by its own, the wrist's dragged by the others.
    error = np.abs(V[1] - u) / np.abs(u)
    assert np.all(error[:4] > 0.2) and np.ptp(error) > 0.5
    # Close after ten time constants, gravity compensated: a proportional servo leaves
    # the share of the velocity-dependent (Coriolis, damping) torques.
    np.testing.assert_allclose(V[-1], u, rtol=0.15)
    assert np.linalg.norm(V[-1] - u) < 0.2 * np.linalg.norm(V[1] - u)
    # The positions are the velocities' integral.
    np.testing.assert_allclose(np.diff(Q, axis=0), 0.01 * (V[1:] + V[:-1]), atol=2e-3)


def test_the_hand_pressed_into_a_plane_stays_on_it_and_rubs(panda):
    q0 = panda.neutral()
    hand = panda.frame_position(q0, FRAME)
    J = panda.frame_jacobian(q0, FRAME)
    # Down and along x at once, 0.1 m/s each, through the pseudo-inverse at the start.
    u = np.linalg.pinv(J) @ np.array([0.1, 0.0, -0.1])
    ends = {}
    for mu in (0.0, 0.6):
        plane = ContactPlane((0.0, 0.0, 1.0), hand[2] - 0.02, mu=mu)
        arm = ServoArm(panda, FRAME, [plane], tau=0.05)
        Q, _, _, touching = arm.run(q0, lambda q, t: u, 60, 0.02)
        z = np.array([panda.frame_position(q, FRAME)[2] for q in Q])
        assert touching.any() and z.min() > plane.offset - 0.005  # a stiff plane
        ends[mu] = panda.frame_position(Q[-1], FRAME)
    # Friction slows the slide along the plane.
    assert ends[0.6][0] - hand[0] < 0.8 * (ends[0.0][0] - hand[0])


def test_the_arm_stops_at_its_joint_limits(panda):
    arm = ServoArm(panda, FRAME, tau=0.05)
    q0 = panda.neutral()
    q0[3] = panda.upper[3] - 0.01
    Q, _, _, _ = arm.run(q0, lambda q, t: np.eye(7)[3], 20, 0.02)
    assert Q[:, 3].max() <= panda.upper[3]
    assert Q[-1, 3] == pytest.approx(panda.upper[3])


def test_an_arm_out_of_tree_order_is_refused(panda):
    shuffled = Robot.load("panda", joints=[f"panda_joint{i}" for i in (2, 1, 3, 4, 5, 6, 7)])
    with pytest.raises(ValueError, match="robot"):
        ServoArm(shuffled, FRAME)


def test_a_sample_period_off_the_control_period_is_refused(panda):
    arm = ServoArm(panda, FRAME)
    with pytest.raises(ValueError, match="dt"):
        arm.run(panda.neutral(), lambda q, t: np.zeros(7), 10, 0.0105)
