"""The learnt goal (policy_align_ros.learning.goal): rest points, the demonstrated goal, the
summary, the learnt goal among the minima, starts that stop elsewhere."""

import numpy as np
import pytest
from flows import bowl, two_wells

from policy_align_ros.learning import Trajectory
from policy_align_ros.learning.goal import (
    data_extent,
    goal_summary,
    learnt_goal_index,
    rest_points,
    sample_speeds,
    starts_elsewhere,
)


def test_rest_point_is_the_mean_of_the_final_run_below_two_percent_of_peak_speed():
    moving = np.linspace([0.0, 0.0], [1.0, 1.0], 11)            # 10 steps of 0.1 * sqrt 2
    resting = np.array([[1.0, 1.0], [1.001, 1.0], [1.001, 1.001], [1.0, 1.001]])
    # A pause half way (speed 0) is not the end: only the final run counts.
    paused = np.concatenate([moving[:5], moving[4:5], moving[5:], resting])
    times = 0.1 * np.arange(len(paused))
    (point,) = rest_points([Trajectory(paused, times=times)])
    np.testing.assert_allclose(point, resting.mean(axis=0))
    # Ending in motion: no rest.
    assert rest_points([moving]) == [None]
    # A last step that is slow but not below 2 % of the peak does not rest either.
    slow = np.concatenate([moving, moving[-1:] + [0.01, 0.0]])
    assert rest_points([slow]) == [None]
    assert rest_points([slow], fraction=0.1)[0] is not None


def test_recorded_velocities_decide_the_speed_when_given():
    X = np.linspace([0.0], [1.0], 6)
    V = np.array([[1.0], [1.0], [1.0], [1.0], [0.0], [0.0]])
    traj = Trajectory(X, times=np.arange(6.0), velocities=V)
    np.testing.assert_allclose(sample_speeds(traj), V[:, 0])
    np.testing.assert_allclose(rest_points([traj])[0], [0.9])
    # Finite differences instead: every step moves, no rest.
    assert rest_points([Trajectory(X, times=np.arange(6.0))]) == [None]


def test_bad_rest_fraction_is_named():
    with pytest.raises(ValueError, match="fraction"):
        rest_points([np.zeros((3, 2))], fraction=1.5)


def test_a_start_whose_well_no_end_reaches_is_counted():
    potential, gradient = two_wells()
    t = np.linspace(0.0, 1.0, 50)
    line = lambda a, b: Trajectory(a + t[:, None] * (np.asarray(b) - a), times=t)  # noqa: E731
    across = line(np.array([-1.1, 0.2]), [0.95, 0.05])  # from the left well to the right
    within = line(np.array([1.3, -0.3]), [1.02, 0.0])   # inside the right well
    report = starts_elsewhere([across, within], potential, gradient, extent=2.5, speed=1.0)
    assert report["n_starts_elsewhere"] == 1 and report["n_starts_escaped"] == 0
    assert report["starts_elsewhere_fraction"] == pytest.approx(2.0 / 2.5, abs=0.02)
    left = line(np.array([-1.3, 0.3]), [-1.0, 0.02])  # another goal, its own well
    for trajs in ([within], [within, left]):
        assert starts_elsewhere(trajs, potential, gradient, extent=2.5,
                                speed=1.0)["n_starts_elsewhere"] == 0
    # Two of three end together (3 % of the extent apart, as a teacher stops): that is
    # the goal, and both starts whose runs stop in the other well count.
    assert starts_elsewhere([across, within, left], potential, gradient, extent=2.5,
                            speed=1.0)["n_starts_elsewhere"] == 2


def test_where_demonstrations_end_together_runs_must_stop_there():
    # A bowl whose minimum is not where all the demonstrations end: every end slides to
    # the bowl's minimum, and so does every start, but none stops at the goal.
    potential, gradient = bowl(np.eye(2), np.array([1.0, 0.0]))
    t = np.linspace(0.0, 1.0, 40)
    demos = [Trajectory(np.outer(1.0 - t, start), times=t)
             for start in ([-1.0, 1.0], [-1.0, -1.0], [-1.5, 0.2])]
    report = starts_elsewhere(demos, potential, gradient, extent=2.0, speed=1.0)
    assert report["n_starts_elsewhere"] == 3
    assert report["starts_elsewhere_fraction"] == pytest.approx(0.5, abs=1e-3)


def _flow(A, c, x0, steps=120, dt=0.05, wall=None):
    """Euler steps of xdot = -A (x - c); ``wall`` (x1 <= wall) blocks the first coordinate."""
    x, X = np.array(x0, dtype=float), []
    for _ in range(steps):
        X.append(x.copy())
        v = -A @ (x - c)
        if wall is not None and x[0] + dt * v[0] > wall:
            v[0] = (wall - x[0]) / dt
        x = x + dt * v
    return Trajectory(np.array(X), times=dt * np.arange(steps))


def test_a_rest_under_an_active_constraint_is_not_a_demonstrated_goal():
    A, c = np.diag([1.0, 2.0]), np.array([1.0, 0.0])
    potential, gradient = bowl(A, c)
    free = [_flow(A, c, x0) for x0 in ([-1.0, 1.0], [-1.5, -1.0], [2.5, 1.0])]
    # Stopped by a wall at x1 = 0, where the policy still pushes at speed 1.
    blocked = [_flow(A, c, x0, wall=0.0) for x0 in ([-2.0, 1.0], [-1.0, -1.5])]
    summary = goal_summary(free + blocked, potential, gradient)
    assert summary["n_rests"] == 5 and summary["n_constrained_rests"] == 2
    assert summary["extent"] == pytest.approx(data_extent(free + blocked))
    # Where the teacher stopped, whatever the learnt speed: the goal, and the wall's two
    # rests, which meet at (0, 0) as the second coordinate settles.
    assert summary["n_rest_places"] == 2
    rests = np.array([t.positions[-1] for t in free + blocked])
    far = np.max(np.linalg.norm(rests[:, None] - rests[None], axis=2))
    assert summary["rest_spread_fraction"] == pytest.approx(far / summary["extent"],
                                                            rel=0.05)
    (goal,) = summary["demonstrated_goals"]
    assert goal["n_rests"] == 3
    (minimum,) = summary["minima"]
    np.testing.assert_allclose(minimum["point"], c, atol=1e-5)
    # The free demonstrations end within 2 % of their peak speed, so near the goal.
    assert minimum["goal_fraction"] < 0.01
    X = np.concatenate([t.positions for t in free + blocked])
    nearest = np.min(np.linalg.norm(X - np.array(minimum["point"]), axis=1))
    assert minimum["data_distance"] == pytest.approx(nearest, rel=1e-6, abs=1e-9)
    assert minimum["data_fraction"] == pytest.approx(nearest / summary["extent"])
    assert summary["goal_error"] == pytest.approx(goal["nearest_minimum"])
    ratios = summary["rest_speed_ratio"]
    assert sum(r > 0.1 for r in ratios) == 2


def test_demonstrated_goal_is_where_most_demonstrations_end():
    from policy_align_ros.learning.goal import demonstrated_goal

    rng = np.random.default_rng(5)
    goal = np.array([1.0, -2.0])
    # Demonstrations cut as they reach the goal (still moving), one cut short elsewhere.
    demos = [np.linspace(goal + rng.uniform(-3, 3, 2), goal, 30) for _ in range(5)]
    demos.append(np.linspace([3.0, 3.0], [2.0, 2.0], 30))
    assert np.allclose(demonstrated_goal(demos), goal)


def test_no_demonstrated_goal_when_the_ends_differ():
    from policy_align_ros.learning.goal import demonstrated_goal

    rng = np.random.default_rng(6)
    # Each demonstration held by its own constraint: it ends somewhere of its own.
    demos = [np.linspace(rng.uniform(-3, 3, 2), rng.uniform(-3, 3, 2), 30) for _ in range(6)]
    assert demonstrated_goal(demos) is None
    assert demonstrated_goal(demos[:1]) is None


def test_ends_a_teacher_scatters_around_one_place_are_one_goal():
    from policy_align_ros.learning.goal import GOAL_MERGE, demonstrated_goal, goal_ends

    rng = np.random.default_rng(7)
    goal = np.array([1.0, -2.0])
    # Six demonstrations of extent about 6 that stop 0.5-2 % of it from the goal: a
    # teacher never stops twice at the same point.
    offsets = 0.06 * rng.uniform(0.5, 2.0, 6)[:, None] * np.stack(
        [np.cos(np.arange(6)), np.sin(np.arange(6))], axis=1)
    demos = [np.linspace(goal + rng.uniform(-3, 3, 2), goal + d, 30) for d in offsets]
    ends = goal_ends(demos)
    assert ends is not None and len(ends) == 6
    np.testing.assert_allclose(demonstrated_goal(demos), (goal + offsets).mean(axis=0))
    # Twice as far apart as GOAL_MERGE allows, they are not one place.
    extent = np.ptp(np.concatenate(demos), axis=0).max()
    spread = [np.linspace(goal + rng.uniform(-3, 3, 2), goal + 2 * GOAL_MERGE * extent
                          * np.array([np.cos(a), np.sin(a)]), 30)
              for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)]
    assert goal_ends(spread) is None


def test_recordings_cut_while_moving_do_not_move_the_goal_the_rests_show():
    from policy_align_ros.learning.goal import demonstrated_goal, goal_ends

    # Six demonstrations come to rest at the goal; three more are cut 4.6 % of the extent
    # short, still moving. Within 5 % of the rests, they would pull the goal toward them.
    goal = np.array([0.5, -1.0])
    t = np.linspace(0.0, 4.0, 200)
    rng = np.random.default_rng(8)
    resting = [Trajectory(goal + (s - goal) * np.exp(-3.0 * t)[:, None], times=t)
               for s in goal + rng.uniform(-2.0, 2.0, (6, 2))]
    cut = []
    for s in goal + rng.uniform(-2.0, 2.0, (3, 2)):
        path = goal + (s - goal) * np.exp(-3.0 * t)[:, None]
        stop = int(np.argmax(np.linalg.norm(path - goal, axis=1) < 0.14))
        cut.append(Trajectory(path[:stop + 1], times=t[:stop + 1]))
    ends = goal_ends(resting + cut)
    assert ends is not None and len(ends) == 6
    np.testing.assert_allclose(demonstrated_goal(resting + cut), goal, atol=1e-4)


def test_the_learnt_goal_is_the_minimum_where_most_rest_else_where_they_end():
    minima = [{"point": [5.0, 5.0], "end_distance": 6.0},   # lowest, far from the data
              {"point": [0.1, 0.0], "end_distance": 0.2}]
    rests = [{"point": [0.0, 0.0], "n_rests": 4}]
    assert learnt_goal_index({"minima": minima, "demonstrated_goals": rests}) == 1
    assert learnt_goal_index({"minima": minima, "demonstrated_goals": []}) == 1
    assert learnt_goal_index({"minima": [], "demonstrated_goals": rests}) is None
    # A report without the distances to the ends (an older model file): the lowest.
    bare = [{"point": m["point"]} for m in minima]
    assert learnt_goal_index({"minima": bare, "demonstrated_goals": []}) == 0


def test_an_end_that_still_creeps_toward_its_goal_ends_at_the_limit_of_its_creep():
    from policy_align_ros.learning.goal import demonstrated_goal, goal_ends

    # A servo's approach x = g + (s - g) exp(-t / c), recorded until its speed is 1 % of
    # its peak: every end is still 1 % of its start distance short of the goal.
    goal, c = np.array([0.5, -1.0]), 0.8
    t = np.arange(0.0, c * np.log(100.0), 0.02)
    rng = np.random.default_rng(9)
    demos = [Trajectory(goal + (s - goal) * np.exp(-t / c)[:, None], times=t)
             for s in goal + rng.uniform(-2.0, 2.0, (6, 2))]
    shortfall = np.linalg.norm(np.mean([d.positions[-1] for d in demos], axis=0) - goal)
    assert shortfall > 1e-3 and len(goal_ends(demos)) == 6
    # Velocities differenced from the positions: within a hundredth of the shortfall.
    assert np.linalg.norm(demonstrated_goal(demos) - goal) < 0.01 * shortfall
    # With recorded velocities, anisotropic rates (the slow one left by the end): within
    # a tenth of the shortfall.
    rates = np.array([1.0 / c, 3.0 / c])
    aniso = [Trajectory(goal + (s - goal) * np.exp(-t[:, None] * rates), times=t,
                        velocities=-(s - goal) * rates * np.exp(-t[:, None] * rates))
             for s in goal + rng.uniform(-2.0, 2.0, (6, 2))]
    shortfall = np.linalg.norm(np.mean([d.positions[-1] for d in aniso], axis=0) - goal)
    assert np.linalg.norm(demonstrated_goal(aniso) - goal) < 0.1 * shortfall


def test_a_rest_that_is_noise_or_a_drift_is_not_extrapolated():
    from policy_align_ros.learning.goal import creep_limit

    rng = np.random.default_rng(10)
    times = 0.01 * np.arange(100)
    still = np.array([0.3, 0.2]) + 1e-4 * rng.standard_normal((100, 2))
    drift = still + 2e-3 * times[:, None] * np.array([1.0, 0.0])   # no slowing down
    for X in (still, drift):
        for V in (np.gradient(X, times, axis=0),                   # central differences
                  np.vstack([np.zeros((1, 2)), np.diff(X, axis=0) / 0.01])):  # backward
            tail = X[-10:].mean(axis=0)
            assert np.linalg.norm(creep_limit(X, V, 10) - tail) < 1e-4
    # Short runs whose positions and recorded velocities are independent noise: the
    # confidence bound extrapolates about as often as its level allows, not half the time.
    moved = 0
    for m, n in ((3, 1), (5, 1), (2, 7), (20, 2)) * 50:
        X, V = 1e-3 * rng.standard_normal((m, n)), 1e-2 * rng.standard_normal((m, n))
        moved += bool(np.any(creep_limit(X, V, 1) != X[-1]))
    assert moved < 0.06 * 200
    # A run at rest exactly: its position.
    np.testing.assert_array_equal(creep_limit(np.ones((5, 2)), np.zeros((5, 2)), 2),
                                  np.ones(2))


def test_a_creeping_end_moves_no_farther_than_allowed_and_a_bad_tail_is_named():
    from policy_align_ros.learning.goal import creep_limit

    t = np.arange(0.0, 1.0, 0.02)
    X = (np.exp(-t) + 1.0)[:, None] * np.array([[1.0, 0.0]])       # creeping toward (1, 0)
    V = -np.exp(-t)[:, None] * np.array([[1.0, 0.0]])
    np.testing.assert_allclose(creep_limit(X, V, 1), [1.0, 0.0], atol=1e-9)
    assert np.linalg.norm(creep_limit(X, V, 1, max_step=0.01) - X[-1]) == pytest.approx(0.01)
    with pytest.raises(ValueError, match="tail"):
        creep_limit(X, V, 0)
