"""The learnt goal (policy_align_ros.learning.goal): rest points, minima, the summary."""

import numpy as np
import pytest

from policy_align_ros.learning import Trajectory
from policy_align_ros.learning.goal import (
    data_extent,
    goal_summary,
    learnt_minima,
    rest_points,
    sample_speeds,
    starts_elsewhere,
)


def _bowl(A, c):
    """The potential 0.5 (x - c)' A (x - c) and its gradient."""
    def potential(X):
        D = X - c
        return 0.5 * np.einsum("ij,jk,ik->i", D, A, D)

    def gradient(X):
        return (X - c) @ A

    return potential, gradient


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


def test_minimum_of_a_known_quadratic_is_found_where_it_is():
    rng = np.random.default_rng(3)
    n = 5
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    A = (Q * np.geomspace(1.0, 100.0, n)) @ Q.T
    c = rng.normal(size=n)
    potential, gradient = _bowl(A, c)
    starts = c + rng.normal(scale=2.0, size=(12, n))
    minima = learnt_minima(potential, gradient, starts, scale=4.0, speed=100.0)
    assert minima.points.shape == (1, n) and minima.n_escaped == 0
    np.testing.assert_allclose(minima.points[0], c, atol=1e-4)
    assert minima.values[0] == pytest.approx(0.0, abs=1e-8)


def test_a_model_descends_through_its_joint_evaluation_to_the_same_bits():
    # A model's predict and gradient are evaluated together at each step of a descent;
    # the descent must end where it does with the two called apart, to the last bit.
    from policy_align_ros.learning.regressors import TrendKernelRegression

    rng = np.random.default_rng(4)
    X = rng.uniform(-2.0, 2.0, size=(240, 2))
    y = np.sum((X - [0.3, -0.4]) ** 2, axis=1) + 0.2 * np.sin(2.0 * X[:, 0])
    model = TrendKernelRegression(trend_form="quadratic", length_scale=0.6,
                                  kernel_ridge=1e-4, random_state=0)
    model.fit(X, y, groups=np.repeat(np.arange(12), 20))
    starts = rng.uniform(-2.0, 2.0, size=(9, 2))
    joint = learnt_minima(model.predict, model.gradient, starts, scale=4.0)
    apart = learnt_minima(lambda Z: model.predict(Z), lambda Z: model.gradient(Z), starts,
                          scale=4.0)
    assert len(joint.points) and np.array_equal(joint.points, apart.points)
    t = np.linspace(0.0, 1.0, 30)[:, None]
    demos = [Trajectory(x0 + t * ([0.3, -0.4] - x0), times=t[:, 0]) for x0 in starts]
    assert starts_elsewhere(demos, model.predict, model.gradient, 4.0, 1.0) == \
        starts_elsewhere(demos, lambda Z: model.predict(Z), lambda Z: model.gradient(Z),
                         4.0, 1.0)


def test_a_capped_descent_up_a_concave_slope_raises_no_overflow_warning():
    # Where the potential bends down, every secant step grows the next by 4 until it
    # overflows; the cap must take such a step without a warning the fit would pass on.
    import warnings

    from policy_align_ros.learning.goal import _descend

    def potential(X):
        return -0.5 * np.sum(X**2, axis=1)

    def gradient(X):
        return -X

    lo, hi = np.full(1, -1e6), np.full(1, 1e6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        end = _descend(potential, gradient, np.array([[1.0]]), lo, hi, 1e-9, 1.0, 700,
                       max_step=0.01)
    assert end[0, 0] == pytest.approx(1.0 + 700 * 0.01, rel=1e-6)  # every step capped


def _two_wells():
    wells = np.array([[-1.0, 0.0], [1.0, 0.0]])

    def potential(X):
        d2 = np.sum((X[:, None, :] - wells[None]) ** 2, axis=2)
        return 0.05 * np.sum(X**2, axis=1) - np.exp(-d2 / 0.2).sum(axis=1)

    def gradient(X):
        D = X[:, None, :] - wells[None]
        e = np.exp(-np.sum(D**2, axis=2) / 0.2)
        return 0.1 * X + np.einsum("mk,mkn->mn", e, D) / 0.1

    return potential, gradient


def test_two_wells_give_two_minima_and_a_falling_plane_gives_none():
    potential, gradient = _two_wells()
    starts = np.array([[-1.2, 0.3], [-0.8, -0.2], [1.1, 0.2], [0.9, -0.3]])
    minima = learnt_minima(potential, gradient, starts, scale=2.0)
    assert len(minima.points) == 2
    np.testing.assert_allclose(np.sort(minima.points[:, 0]), [-1.0, 1.0], atol=0.02)
    plane = learnt_minima(lambda X: X[:, 0], lambda X: np.tile([1.0, 0.0], (len(X), 1)),
                          starts, scale=2.0)
    assert len(plane.points) == 0 and plane.n_escaped == len(starts)


def test_a_start_whose_well_no_end_reaches_is_counted():
    potential, gradient = _two_wells()
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
    potential, gradient = _bowl(np.eye(2), np.array([1.0, 0.0]))
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
    potential, gradient = _bowl(A, c)
    free = [_flow(A, c, x0) for x0 in ([-1.0, 1.0], [-1.5, -1.0], [2.5, 1.0])]
    # Stopped by a wall at x1 = 0, where the policy still pushes at speed 1.
    blocked = [_flow(A, c, x0, wall=0.0) for x0 in ([-2.0, 1.0], [-1.0, -1.5])]
    summary = goal_summary(free + blocked, potential, gradient)
    assert summary["n_rests"] == 5 and summary["n_constrained_rests"] == 2
    assert summary["extent"] == pytest.approx(data_extent(free + blocked))
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
