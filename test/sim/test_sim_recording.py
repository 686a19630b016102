"""Recording distortions (policy_align_ros.sim.recording) do what they say."""

import numpy as np
import pytest

from policy_align_ros.sim.demonstrations import no_constraint, rollout
from policy_align_ros.sim.experts import QuadraticPotential
from policy_align_ros.sim.recording import (
    encoder_noise,
    friction_slowdown,
    hesitate,
    minimum_jerk,
    pad_with_rest,
    retime_path,
    stamp_jitter,
    track_velocity,
)


def _expert():
    return QuadraticPotential(np.zeros(2), 0.5)


def test_the_lagged_robot_lags_the_expert_and_respects_its_limits():
    potential, x0, dt = _expert(), np.array([1.0, -0.5]), 0.02
    exact = rollout(x0, potential, no_constraint(2), 150, dt).trajectory.positions
    X, V, times = track_velocity(x0, lambda x, t: potential.policy(x[None])[0], 150, dt,
                                 tau=0.1, max_speed=0.6, max_accel=4.0)
    assert np.allclose(times, dt * np.arange(150))
    assert np.all(np.abs(V) <= 0.6 + 1e-12)
    assert np.all(np.abs(np.diff(V, axis=0)) <= 4.0 * dt + 1e-9)
    # Starting at rest and tracking late, the robot stays farther from the goal early on
    # than the exact expert, and still gets there.
    dist_lag, dist_exact = np.linalg.norm(X, axis=1), np.linalg.norm(exact, axis=1)
    assert np.all(dist_lag[1:40] > dist_exact[1:40])
    assert dist_lag[-1] < 0.05 * dist_lag[0]


def test_a_longer_lag_lags_more():
    potential, x0 = _expert(), np.array([1.0, 0.0])

    def run(tau):
        return track_velocity(x0, lambda x, t: potential.policy(x[None])[0], 50, 0.02,
                              tau=tau)[0]

    assert np.linalg.norm(run(0.15)[25]) > np.linalg.norm(run(0.05)[25])


def test_the_retimed_path_keeps_the_geometry_and_rests_at_both_ends():
    path = rollout(np.array([1.0, 0.4]), _expert(), no_constraint(2), 200, 0.02
                   ).trajectory.positions
    X, V, times, index = retime_path(path, 2.5, 0.01, rest_before=0.3, rest_after=0.4)
    assert times[-1] >= 0.3 + 2.5 + 0.4 - 1e-9
    # Every sample lies on the path, in order.
    assert np.all(np.diff(index) >= 0)
    lo = np.floor(index).astype(int).clip(0, len(path) - 2)
    w = (index - lo)[:, None]
    assert np.allclose(X, (1 - w) * path[lo] + w * path[lo + 1], atol=1e-12)
    assert np.allclose(X[0], path[0]) and np.allclose(X[-1], path[-1])
    # At rest before and after the motion.
    speed = np.linalg.norm(V, axis=1)
    assert np.all(speed[times <= 0.3] == 0) and np.all(speed[times >= 2.8] == 0)
    # The velocities are the positions' derivative.
    mid = (times > 0.5) & (times < 2.6)
    fd = np.gradient(X, times, axis=0)
    assert np.allclose(fd[mid], V[mid], atol=0.02 * speed.max())


def test_minimum_jerk_starts_and_ends_at_rest():
    value, slope = minimum_jerk(np.array([0.0, 0.5, 1.0]))
    assert np.allclose(value, [0.0, 0.5, 1.0]) and np.allclose(slope, [0.0, 1.875, 0.0])


@pytest.mark.parametrize("push", [0.0, 0.1, 0.5, 5.0])
def test_friction_slows_but_never_reverses_tangential_motion(push):
    v = np.array([0.3, -0.4])
    out = friction_slowdown(v, push, 0.4)
    assert np.linalg.norm(out) <= np.linalg.norm(v) + 1e-15
    assert out @ v >= 0 and abs(out[0] * v[1] - out[1] * v[0]) < 1e-15  # same direction
    assert np.linalg.norm(out) == pytest.approx(max(0.0, 0.5 - 0.4 * push))


def test_friction_rejects_a_negative_coefficient():
    with pytest.raises(ValueError, match="mu"):
        friction_slowdown(np.ones(2), 0.1, -0.1)


def test_encoder_noise_has_the_stated_rms():
    rng = np.random.default_rng(0)
    X = rng.uniform(-2, 2, size=(20000, 3))
    res, sd = 1e-3, 5e-4
    err = encoder_noise(X, res, sd, np.random.default_rng(1)) - X
    assert np.sqrt(np.mean(err**2)) == pytest.approx(np.sqrt(res**2 / 12 + sd**2), rel=0.02)
    exact = encoder_noise(X, res, 0.0, rng)
    assert np.allclose(exact / res, np.round(exact / res))


def test_stamp_jitter_has_the_stated_rms_and_keeps_order():
    times = 0.01 * np.arange(20000)
    out = stamp_jitter(times, 1e-3, np.random.default_rng(0))
    assert np.all(np.diff(out) > 0)
    assert np.sqrt(np.mean((out - times) ** 2)) == pytest.approx(1e-3, rel=0.05)
    with pytest.raises(ValueError, match="times"):
        stamp_jitter(times[::-1], 1e-3, np.random.default_rng(0))


def test_padding_holds_the_ends_for_the_rests_and_keeps_the_motion():
    t = 0.02 * np.arange(50) + 3.0
    X = np.stack([np.linspace(0, 1, 50), np.linspace(2, 0, 50)], axis=1)
    Xp, tp = pad_with_rest(X, t, 0.2, 0.5)
    assert len(Xp) == 50 + 10 + 25
    assert np.all(np.diff(tp) > 0)
    np.testing.assert_array_equal(Xp[10:60], X)
    np.testing.assert_array_equal(tp[10:60], t)
    assert np.all(Xp[:10] == X[0]) and np.all(Xp[60:] == X[-1])
    assert tp[0] == pytest.approx(2.8) and tp[-1] == pytest.approx(t[-1] + 0.5)
    with pytest.raises(ValueError, match="rest_before"):
        pad_with_rest(X, t, -0.1, 0.5)
    with pytest.raises(ValueError, match=r"^X, times\b.*\(1, 2\)"):
        pad_with_rest(X[:1], t[:1], 0.1, 0.5)


def test_a_hesitation_stops_once_on_the_same_path_and_lasts_the_pause_longer():
    t = 0.01 * np.arange(201) + 1.0  # 2 s at 100 Hz
    X = np.stack([(t - 1.0) ** 2, np.sin(t)], axis=1)
    Y, ty = hesitate(X, t, 0.5, 0.6, 0.3)
    np.testing.assert_allclose(np.diff(ty), 0.01)
    assert ty[0] == t[0] and ty[-1] == pytest.approx(t[-1] + 0.6 + 0.3)
    np.testing.assert_allclose(Y[[0, -1]], X[[0, -1]])
    # The same path: every sample on the motion's polyline, in order along it (x rises).
    np.testing.assert_allclose(Y[:, 1], np.sin(np.sqrt(Y[:, 0]) + 1.0), atol=1e-4)
    assert np.all(np.diff(Y[:, 0]) >= 0)
    # At rest for the pause, from 1 s into the motion, and moving before and after.
    speed = np.linalg.norm(np.diff(Y, axis=0), axis=1) / 0.01
    still = (ty[:-1] >= 2.0) & (ty[1:] <= 2.6)
    assert np.all(speed[still] < 1e-6) and still.sum() >= 59
    assert np.all(speed[ty[1:] < 1.6] > 0) and np.all(speed[ty[:-1] > 2.95] > 0)
    with pytest.raises(ValueError, match=r"^at\b.*\b1\.0$"):
        hesitate(X, t, 1.0, 0.6, 0.3)
    with pytest.raises(ValueError, match="pause"):
        hesitate(X, t, 0.5, -0.1, 0.3)
    with pytest.raises(ValueError, match="ramp"):
        hesitate(X, t, 0.5, 0.6, 0.0)
