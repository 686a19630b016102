"""Validation of demonstrations (policy_align_ros.learning.trajectory)."""

import numpy as np
import pytest

from policy_align_ros.learning import Trajectory, as_trajectories


def test_plain_arrays_become_untimed_trajectories():
    trajs = as_trajectories([np.zeros((3, 2)), np.ones((4, 2))])
    assert [t.n_samples for t in trajs] == [3, 4]
    assert trajs[0].times is None
    np.testing.assert_array_equal(trajs[1].dt, np.ones(3))
    assert trajs[1].duration == 3.0  # steps without times


def test_times_give_real_time_steps():
    traj = Trajectory(np.zeros((3, 1)), times=[0.0, 0.1, 0.3])
    np.testing.assert_allclose(traj.dt, [0.1, 0.2])
    assert traj.duration == pytest.approx(0.3)


@pytest.mark.parametrize(
    ("positions", "times", "message"),
    [
        # The array and the numbers at fault: its shape, sample count or sample index.
        (np.zeros(5), None, r"\bpositions\b.*\(5,\)"),
        (np.zeros((1, 2)), None, r"\b2\b.*\b1\b"),
        (np.array([[0.0, 1.0], [np.nan, 0.0]]), None, r"\bpositions\b.*\bsample 1\b"),
        (np.array([[0.0], [np.inf]]), None, r"\bpositions\b.*\bsample 1\b"),
        (np.zeros((3, 2)), [0.0, 0.2, 0.2], r"\btimes\b.*t\[2\] <= t\[1\]"),
        (np.zeros((3, 2)), [0.0, 0.2], r"\btimes\b.*\(3,\).*\(2,\)"),
    ],
)
def test_bad_trajectory_names_index_and_problem(positions, times, message):
    good = np.zeros((4, np.shape(positions)[-1] if np.ndim(positions) == 2 else 2))
    items = [Trajectory(good)] if times is None else [Trajectory(good, times=np.arange(4.0))]
    with pytest.raises(ValueError, match=message) as err:
        if times is None:
            as_trajectories(items + [positions])
        else:
            as_trajectories(items + [Trajectory(positions, times=times, name="1")])
    assert "trajectory 1" in str(err.value)


def test_dimension_mismatch_names_the_trajectory():
    with pytest.raises(ValueError, match=r"^trajectory 2: .*\b3\b.*\btrajectory 0\b.*\b2\b"):
        as_trajectories([np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((3, 3))])


def test_velocities_must_match_positions():
    with pytest.raises(ValueError, match="velocities"):
        Trajectory(np.zeros((3, 2)), velocities=np.zeros((3, 1)))


def test_empty_and_single_array_inputs_are_rejected():
    with pytest.raises(ValueError):
        as_trajectories([])
    with pytest.raises(ValueError, match=r"\bndarray\b"):
        as_trajectories(np.zeros((3, 2)))


def test_mixing_timed_and_untimed_is_rejected():
    with pytest.raises(ValueError, match=r"^trajectory 1: .*\btrajectory 0\b.*\btimes\b"):
        as_trajectories([Trajectory(np.zeros((2, 1)), times=[0, 1]), np.zeros((2, 1))])


def test_unnamed_trajectories_are_named_by_their_index_without_mutating_the_input():
    named = Trajectory(np.zeros((3, 2)), name="left")
    unnamed = Trajectory(np.ones((3, 2)))
    out = as_trajectories([named, unnamed, np.zeros((3, 2))])
    assert [t.name for t in out] == ["left", "1", "2"]
    assert out[0] is named  # named ones are returned as given
    assert unnamed.name is None and out[1] is not unnamed
    assert out[1].positions is unnamed.positions  # a shallow copy: no data copied


def test_velocity_estimate_is_the_recorded_velocity_or_central_differences():
    t = np.array([0.0, 0.5, 1.5, 2.0])
    X = np.stack([t**2, 3.0 * t], axis=1)
    v = Trajectory(X, t).velocity_estimate()
    assert np.allclose(v[:, 1], 3.0)  # exact for a line, on uneven steps
    assert np.allclose(v[1:-1, 0], 2.0 * t[1:-1])  # exact for a parabola inside
    per_step = Trajectory(X).velocity_estimate()
    assert np.allclose(per_step, np.gradient(X, axis=0))
    recorded = np.ones_like(X)
    assert np.array_equal(Trajectory(X, t, recorded).velocity_estimate(), recorded)
